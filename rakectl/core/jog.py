"""Operator jogging with a dead-man (pure).

The operator's client sends a velocity every 100 ms; each command is good for
``deadman_s``. The reference moves at the commanded velocity, limited in
speed and in acceleration (both ways: a commanded zero, and the dead-man's stop,
decelerate; the operator's ``stop`` holds the reference where it is at once, about
1 mm of overshoot at 0.1 m/s, and a change of space steps it), and never leaves the
workspace: near a joint limit (its end stop, where a drive
faults on the hit) it stops ``LIMIT_MARGIN`` inside it. It waits
for the tip: while the measured tip (:meth:`Jog.observe`) is more than
``max_lag_m`` from the reference, a step that would take it further is not
taken, so a tip blocked by something rigid is not pushed on through it. In
task space the velocity is of the tip (reach, height); in joint space of (r, θ).
Time comes in as the tick count, so this is pure and deterministic.
"""

from __future__ import annotations

import enum
import math

from rakectl.config.settings import JogSettings
from rakectl.core import kinematics
from rakectl.errors import KinematicsError

# The jog's reference stops this far inside each joint's limits (r in m, θ in rad), which
# are its end stops: a reference stopped there at full jog speed is overshot by about the
# joint's braking distance (0.1 m/s at 0.4 m/s²: 12.5 mm; 0.15 rad/s at 0.6 rad/s²:
# 0.019 rad), and a drive that hits its end stop faults (EMCY 0xFF01).
LIMIT_MARGIN = (0.02, 0.03)


class JogFrame(enum.Enum):
    TASK = "task"  # tip reach and height
    JOINT = "joint"  # r and θ


class Jog:
    """A jog reference advanced once per tick."""

    __slots__ = ("_accel", "_deadline_tick", "_target", "_tip", "_velocity", "dt_s", "q",
                 "settings", "space", "tick", "waiting", "workspace")

    def __init__(self, settings: JogSettings, workspace: kinematics.Workspace, dt_s: float,
                 r_m: float, theta_rad: float) -> None:
        self.settings = settings
        self.workspace = workspace
        self.dt_s = dt_s
        self.q = (r_m, theta_rad)  # the reference, in joint space
        self.space = JogFrame.TASK
        self._target = (0.0, 0.0)
        self._velocity = (0.0, 0.0)
        self._accel = (0.0, 0.0)
        self.tick = 0
        self._deadline_tick = -1
        self._tip: tuple[float, float] | None = None  # the measured tip (reach, height)
        self.waiting = 0  # steps not taken: the tip lagged (reported by the daemon)

    def _limits(self, space: JogFrame) -> tuple[float, float]:
        s = self.settings
        if space is JogFrame.TASK:
            return s.max_tip_speed_m_per_s, s.max_tip_speed_m_per_s
        return s.max_r_speed_m_per_s, s.max_theta_speed_rad_per_s

    def command(self, space: JogFrame, a: float, b: float) -> None:
        """A velocity (reach, height) or (r, θ) from the operator, good for ``deadman_s``.

        Changing space brings the reference to rest first (the new velocity
        starts from zero).
        """
        if space is not self.space:
            self.space, self._velocity = space, (0.0, 0.0)
        limit_a, limit_b = self._limits(space)
        self._target = (max(-limit_a, min(limit_a, a)), max(-limit_b, min(limit_b, b)))
        self._accel = (self.settings.accel_per_s * limit_a * self.dt_s,
                       self.settings.accel_per_s * limit_b * self.dt_s)
        self._deadline_tick = self.tick + round(self.settings.deadman_s / self.dt_s)

    @property
    def expired(self) -> bool:
        """True once the dead-man time has passed since the last command."""
        return self.tick > self._deadline_tick

    @property
    def moving(self) -> bool:
        return self._velocity != (0.0, 0.0)

    def observe(self, reach_m: float, depth_m: float) -> None:
        """The measured tip, each tick before :meth:`step`."""
        self._tip = (reach_m, -depth_m)

    def step(self, held: bool = False) -> None:
        """Advance the reference by one tick; ``held`` (the force supervisor's caution):
        the reference stays where it is and comes to rest, and the dead-man counts on."""
        self.tick += 1
        if held:
            self._velocity = (0.0, 0.0)
            return
        target = (0.0, 0.0) if self.expired else self._target
        self._velocity = (_toward(self._velocity[0], target[0], self._accel[0]),
                          _toward(self._velocity[1], target[1], self._accel[1]))
        if self.moving:
            self._move()

    def _move(self) -> None:
        va, vb = self._velocity
        if self.space is JogFrame.JOINT:
            q = (self.q[0] + va * self.dt_s, self.q[1] + vb * self.dt_s)
        else:
            reach, height = kinematics.forward(self.workspace, *self.q)
            try:
                q = kinematics.inverse(self.workspace, reach + va * self.dt_s,
                                       height + vb * self.dt_s)
            except KinematicsError:
                self._velocity = (0.0, 0.0)  # at the edge of the workspace: stop there
                return
        ws, (margin_r, margin_theta) = self.workspace, LIMIT_MARGIN
        clipped = (_within(self.q[0], q[0], ws.r_min_m + margin_r, ws.r_max_m - margin_r),
                   _within(self.q[1], q[1], ws.theta_min_rad + margin_theta,
                           ws.theta_max_rad - margin_theta))
        if clipped != q:
            self._velocity = (0.0, 0.0)
        tip = self._tip
        if tip is not None and self._lag_m(clipped, tip) > max(self.settings.max_lag_m,
                                                               self._lag_m(self.q, tip)):
            self.waiting += 1  # the tip cannot follow: wait for it
            return
        self.q = clipped

    def _lag_m(self, q: tuple[float, float], tip: tuple[float, float]) -> float:
        """Distance from the reference at ``q`` to the measured tip (reach, height)."""
        reach, height = kinematics.forward(self.workspace, *q)
        return math.hypot(reach - tip[0], height - tip[1])

    def tip(self) -> tuple[float, float]:
        """The reference as (reach_m, depth_m)."""
        reach, height = kinematics.forward(self.workspace, *self.q)
        return reach, -height

    @property
    def contact(self) -> bool:
        return self.tip()[1] > self.settings.contact_depth_m


def _toward(value: float, target: float, step: float) -> float:
    if math.isclose(value, target, abs_tol=step):
        return target
    return value + step if target > value else value - step


def _within(now: float, step: float, low: float, high: float) -> float:
    """A joint's next reference ``step`` from ``now``, kept within [low, high]; from a
    reference already outside (armed there), a step back in is taken as it is and one
    further out is not taken (never a jump to the bound)."""
    if step < low:
        return step if step >= now else (low if now >= low else now)
    if step > high:
        return step if step <= now else (high if now <= high else now)
    return step
