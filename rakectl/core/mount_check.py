"""The tine-mount check before the first arming (pure): is the mount as soft as the clamp
assumes?

The clamp's dynamic budget rests on ``clamp.contact_stiffness_n_per_m``: no contact is
stiffer than the tines' compliant mount. A mount whose springs were swapped for stiffer
ones, or blocked, makes every impact harder than the bound allows (rigid tines with the
clamp set for the mount: 279 N on a stone). Nothing on the robot measures the mount, so
with ``selftest.press`` on, after the weight check, the daemon presses the tines on the
anvil: a rigid block on the robot's frame whose flat top is at ``selftest.anvil_reach_m``,
``selftest.anvil_height_m`` (a hardware requirement, like the mount; its height known
within 5 mm). The tip goes up to the travel height (the start's, or ``CLEARANCE_M`` above
the anvil's top if that is higher), across, and down to ``CLEARANCE_M`` above the anvil,
at ``selftest.travel_speed_m_per_s``; then down at ``selftest.press_speed_m_per_s`` until
the vertical force read through the motor currents is ``selftest.press_force_n`` above
its reading in the press's first ``BASELINE_S`` (in free air); it holds ``HOLD_S`` and
goes back the same way to where it started. Each move waits for the measured tip to
arrive (``ARRIVED_M``, at most ``ARRIVE_TIMEOUT_S`` after its reference did).

On a rigid anvil the arm's descent past the first touch is the mount's compression, so
the slope of the force against the arm's height (its encoders, before the mount) is the
mount's stiffness; what stays constant during the press drops out of a slope: the
weight, friction at a steady speed, where exactly the anvil's top is. The force is the
joints' loads from their currents (the motor model's band, on the side the press moves
each joint to, as the weight check reads them), the configured weight taken off, through
J⁻ᵀ (:func:`rakectl.core.supervision.down_force_n`), low-passed (``FILTER_S``: a joint
creeping a few encoder counts per tick sticks and slips), and the height through the
same low-pass, so that each force is paired with its height. The slope is fitted by least
squares over the press's ticks whose force lies within ``FIT_WINDOW`` of
``press_force_n``. Above the configured stiffness by more than
``selftest.mount_stiffer_tolerance`` (0.2: the clamp takes that stiffness as the
stiffest contact), or below it by more than ``mount_softer_tolerance`` (0.5), the check
fails, naming both. A mount too stiff for the encoders to see it give is at least
ΔF/(``MIN_SPREAD_COUNTS`` counts of the tip's height) stiff, and fails the same way.
Only a press that reached its force is weighed: one whose reference ran ``STALL_LAG_M``
ahead of the arm was held by the clamp (its stalled ticks would read any mount as soft)
and fails naming it; one whose reference went ``press_depth_m`` below the anvil's
configured top without the force fails as nothing met, or (the force rose less than
``MIN_FORCE_SPAN`` of the press) as too little to weigh.

On the emulated arm (tests/core/test_mount_check.py) the press of 10 N reads the default
5000 N/m mount as 4951 N/m (5181 N/m at the robot's anvil, config/rakectl.yaml), 4000 as
3993, 2000 as 1978, 6500 as 6386, and the stiffest, whose press lasts a few filter
times, lower than they are but far above the tolerance: 50 000 as 31 000 and 10⁶ as
58 000; the true force on the anvil stayed under 19 N. The push is the clamp's to
bound, whatever the mount: a press asked for 15 N at that pose was held near 13 N (and
asked for 30 N, near 18 N true) by the clamp's worst-case model. The press is slow: met at
5 mm/s by a 10⁶ N/m mount and about 2 kg of arm, its kinetic energy adds v·√(k m) ≈ 7 N.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from rakectl.config.service import SelfTestSettings
from rakectl.config.settings import ClampSettings, press_depth_m
from rakectl.core import kinematics
from rakectl.core.envelope import unbalanced_weight_n
from rakectl.core.motor_model import MotorParams, joint_load_band, joint_resolution
from rakectl.core.supervision import down_force_n
from rakectl.errors import KinematicsError

CLEARANCE_M = 0.01  # above the anvil's top, where the press starts
SETTLE_S = 0.2  # held at the press's start before the baseline (the arm just arrived)
BASELINE_S = 0.5  # the press's first ticks, in free air: the force read there is its zero
FILTER_S = 0.05  # low-pass on the force read (a joint creeping at a few counts per tick
# sticks and slips: its current swings by amperes from one tick to the next)
ARRIVED_M = 0.002  # a move ends once the measured tip is this close to its end
ARRIVE_TIMEOUT_S = 3.0  # after the reference arrived
HOLD_S = 0.3  # at the press's end
FIT_WINDOW = (0.2, 1.0)  # of press_force_n: the ticks the slope is fitted over
MIN_FIT_SAMPLES = 20
MIN_SPREAD_COUNTS = 5.0  # least spread of the tip's height, in encoder counts, for a slope
MIN_FORCE_SPAN = 0.5  # of press_force_n: the least rise of the force over the fit's ticks
STALL_LAG_M = 0.003  # the reference this far below the arm: the clamp holds the press
PATH_STEP_M = 0.01  # the way to the anvil is checked against the joints' limits this often


class Phase(enum.Enum):
    RISE = "rise"
    ACROSS = "across"
    DOWN = "down"
    PRESS = "press"
    HOLD = "hold"
    UP = "up"
    BACK = "back"
    RETURN = "return"
    LOWER = "lower"
    DONE = "done"


@dataclass(frozen=True)
class MountResult:
    passed: bool
    stiffness_n_per_m: float  # measured (a lower bound when ``at_least``); nan if none
    expected_n_per_m: float  # configured (clamp.contact_stiffness_n_per_m)
    at_least: bool
    samples: int
    peak_force_n: float  # the press's largest force read through the currents, over free air
    message: str


class MountCheck:
    """Drives the tip reference to the anvil, through the press and back; see the module."""

    def __init__(self, settings: SelfTestSettings, clamp: ClampSettings, motor_r: MotorParams,
                 motor_theta: MotorParams, workspace: kinematics.Workspace, dt_s: float,
                 reach_m: float, depth_m: float) -> None:
        self._s, self._clamp = settings, clamp
        self.expected_n_per_m = clamp.contact_stiffness_n_per_m
        self._ws, self._dt_s = workspace, dt_s
        self._weight_n = unbalanced_weight_n(clamp)
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._motors = (motor_r, motor_theta)
        self.start = (reach_m, depth_m)
        anvil_depth_m = -settings.anvil_height_m
        self._approach_depth_m = anvil_depth_m - CLEARANCE_M
        travel_depth_m = min(depth_m, self._approach_depth_m)
        self._press_limit_m = anvil_depth_m + press_depth_m(settings, clamp)
        self._settle_ticks = round(SETTLE_S / dt_s)
        self._stalled = False
        reach = settings.anvil_reach_m
        self._legs = {
            Phase.RISE: ((reach_m, travel_depth_m), settings.travel_speed_m_per_s),
            Phase.ACROSS: ((reach, travel_depth_m), settings.travel_speed_m_per_s),
            Phase.DOWN: ((reach, self._approach_depth_m), settings.travel_speed_m_per_s),
            Phase.UP: ((reach, self._approach_depth_m), settings.travel_speed_m_per_s),
            Phase.BACK: ((reach, travel_depth_m), settings.travel_speed_m_per_s),
            Phase.RETURN: ((reach_m, travel_depth_m), settings.travel_speed_m_per_s),
            Phase.LOWER: ((reach_m, depth_m), settings.travel_speed_m_per_s),
        }
        # the side of each joint's load band: the way the press moves it (down, reach held)
        r_a, theta_a = kinematics.inverse(workspace, reach, settings.anvil_height_m)
        j11, j12, j21, j22 = kinematics.jacobian(r_a, theta_a)
        det = j11 * j22 - j12 * j21
        self._press_sign = (math.copysign(1.0, j12 / det), math.copysign(1.0, -j11 / det))
        self._height_resolution_m = max(
            abs(j21) * joint_resolution(motor_r), abs(j22) * joint_resolution(motor_theta))
        self.reach_m, self.depth_m = reach_m, depth_m
        self.phase = Phase.RISE
        self._ticks = 0  # in this phase, since its reference arrived for a move
        self._sums = [0.0] * 5  # n, Σz, ΣF, Σz², ΣzF over the fit's ticks
        self._spread = (math.inf, -math.inf, math.inf, -math.inf)  # z and F, min and max
        self.peak_force_n = 0.0  # above the baseline
        self._baseline = [0.0, 0.0]  # ticks, Σ force read
        self._baseline_ticks = max(1, round(BASELINE_S / dt_s))
        self._alpha = 1.0 - math.exp(-dt_s / FILTER_S)
        self._filtered_n = self._filtered_m = math.nan  # force, and height filtered alike
        self.result: MountResult | None = None
        self._failure = self._outside_workspace()
        if self._failure:
            self._finish()

    def _outside_workspace(self) -> str:
        """Why the path to the anvil and back leaves the joints' limits ("" if it does not):
        its legs, straight in (reach, height), checked every ``PATH_STEP_M``."""
        here = self.start
        for phase in (Phase.RISE, Phase.ACROSS, Phase.DOWN):
            there = self._legs[phase][0]
            parts = max(1, math.ceil(math.dist(here, there) / PATH_STEP_M))
            for i in range(parts + 1):
                reach_m = here[0] + (there[0] - here[0]) * i / parts
                depth_m = here[1] + (there[1] - here[1]) * i / parts
                try:
                    kinematics.inverse(self._ws, reach_m, -depth_m)
                except KinematicsError as error:
                    return (f"tine-mount check: the way to the anvil from reach "
                            f"{self.start[0]:.3f} m, height {-self.start[1]:.3f} m leaves the "
                            f"workspace ({phase.value}): {error}: arm from another pose")
            here = there
        return ""

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    def step(self, reach_m: float, depth_m: float) -> None:
        """Advance the reference one tick, given the measured tip (depth > 0 down)."""
        phase = self.phase
        if phase is Phase.DONE:
            return
        self._ticks += 1
        if phase is Phase.PRESS:
            if self.peak_force_n >= self._s.press_force_n:
                self._next(Phase.HOLD)
            elif self.depth_m - depth_m > STALL_LAG_M:
                self._stalled = True  # judged in the end: held short of the press
                self._next(Phase.UP)
            elif self.depth_m >= self._press_limit_m:
                self._next(Phase.UP)  # judged in the end: nothing met where configured
            elif self._ticks > self._settle_ticks:
                self.depth_m += self._s.press_speed_m_per_s * self._dt_s
        elif phase is Phase.HOLD:
            if self._ticks * self._dt_s >= HOLD_S:
                self._next(Phase.UP)
        else:
            self._move(phase, reach_m, depth_m)

    def _move(self, phase: Phase, reach_m: float, depth_m: float) -> None:
        (goal_reach_m, goal_depth_m), speed = self._legs[phase]
        step_m = speed * self._dt_s
        d_reach, d_depth = goal_reach_m - self.reach_m, goal_depth_m - self.depth_m
        distance = math.hypot(d_reach, d_depth)
        if distance > step_m:
            self.reach_m += d_reach * step_m / distance
            self.depth_m += d_depth * step_m / distance
            self._ticks = 0
            return
        self.reach_m, self.depth_m = goal_reach_m, goal_depth_m
        if math.hypot(reach_m - goal_reach_m, depth_m - goal_depth_m) <= ARRIVED_M:
            self._next(_AFTER[phase])
        elif self._ticks * self._dt_s > ARRIVE_TIMEOUT_S:
            away_mm = math.hypot(reach_m - goal_reach_m, depth_m - goal_depth_m) * 1e3
            self._failure = (f"tine-mount check: the arm did not reach reach "
                             f"{goal_reach_m:.3f} m, height {-goal_depth_m:.3f} m within "
                             f"{ARRIVE_TIMEOUT_S:g} s ({phase.value}): it is {away_mm:.0f} "
                             "mm away")
            self._finish()

    def _next(self, phase: Phase) -> None:
        self.phase, self._ticks = phase, 0
        if phase is Phase.DONE:
            self._finish()

    def observe(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float,
                current_r_a: float, current_theta_a: float) -> None:
        """One tick's feedback; read while pressing."""
        if self.phase is not Phase.PRESS or self._ticks < self._settle_ticks:
            return
        loads = [joint_load_band(m, i, v)[0 if sign > 0.0 else 1] for m, i, v, sign in zip(
            self._motors, (current_r_a, current_theta_a), (r_vel, theta_vel),
            self._press_sign, strict=True)]
        force_n = down_force_n(r_m, theta_rad, loads[0], loads[1], self._weight_n,
                               self._half_length_m)
        height_m = self._ws.pivot_height_m - r_m * math.sin(theta_rad)
        baseline = self._baseline
        if baseline[0] < self._baseline_ticks:
            baseline[0] += 1.0
            baseline[1] += force_n
            self._filtered_n = baseline[1] / baseline[0]
            self._filtered_m = height_m
            return
        alpha = self._alpha  # the same low-pass on both: each force is paired with its height
        self._filtered_n += alpha * (force_n - self._filtered_n)
        self._filtered_m += alpha * (height_m - self._filtered_m)
        force_n = self._filtered_n - baseline[1] / baseline[0]
        height_m = self._filtered_m
        self.peak_force_n = max(self.peak_force_n, force_n)
        low, high = FIT_WINDOW
        if not low * self._s.press_force_n <= force_n <= high * self._s.press_force_n:
            return
        sums = self._sums
        sums[0] += 1.0
        sums[1] += height_m
        sums[2] += force_n
        sums[3] += height_m * height_m
        sums[4] += height_m * force_n
        z_lo, z_hi, f_lo, f_hi = self._spread
        self._spread = (min(z_lo, height_m), max(z_hi, height_m), min(f_lo, force_n),
                        max(f_hi, force_n))

    def _finish(self) -> None:
        self.phase = Phase.DONE
        self.result = self._judge()

    def _judge(self) -> MountResult:
        expected = self.expected_n_per_m
        stiffer, softer = self._s.mount_stiffer_tolerance, self._s.mount_softer_tolerance
        n, sz, sf, szz, szf = self._sums
        peak = self.peak_force_n

        def result(passed: bool, k: float, at_least: bool, message: str) -> MountResult:
            return MountResult(passed, k, expected, at_least, int(n), peak, message)

        if self._failure:
            return result(False, math.nan, False, self._failure)
        anvil = (f"the anvil (selftest.anvil_reach_m {self._s.anvil_reach_m:g} m, "
                 f"anvil_height_m {self._s.anvil_height_m:g} m)")
        force_n, depth_mm = self._s.press_force_n, press_depth_m(self._s, self._clamp) * 1e3
        z_lo, z_hi, f_lo, f_hi = self._spread
        if self._stalled and peak < force_n:
            return result(False, math.nan, False,
                          f"tine-mount check: the press was held at {peak:.1f} N of the "
                          f"{force_n:g} N asked for (selftest.press_force_n) on {anvil}: the "
                          "clamp's bound at this pose; lower the press or put the anvil "
                          "where the arm pushes down harder")
        if peak < force_n and n < MIN_FIT_SAMPLES:
            return result(False, math.nan, False,
                          f"tine-mount check: the tines met nothing: pressed down to "
                          f"{depth_mm:.0f} mm below the top of {anvil}, the force read "
                          f"through the currents reached {peak:.1f} N of the {force_n:g} N "
                          "pressed for: check the anvil's position in the configuration")
        if peak < force_n or f_hi - f_lo < MIN_FORCE_SPAN * force_n:
            return result(False, math.nan, False,
                          f"tine-mount check: the press reached {peak:.1f} N of the "
                          f"{force_n:g} N pressed for, {depth_mm:.0f} mm below the top of "
                          f"{anvil}: too little to weigh the mount (the anvil lower than "
                          f"configured, or a mount much softer than {expected:.0f} N/m)")
        spread_m = z_hi - z_lo
        if n >= MIN_FIT_SAMPLES and spread_m >= MIN_SPREAD_COUNTS * self._height_resolution_m:
            k, at_least = -(n * szf - sz * sf) / (n * szz - sz * sz), False
        else:  # the arm did not give measurably: at least this stiff
            k = (f_hi - f_lo) / max(spread_m, MIN_SPREAD_COUNTS * self._height_resolution_m)
            at_least = True
        ratio = k / expected
        passed = not at_least and 1.0 - softer <= ratio <= 1.0 + stiffer
        bound = "at least " if at_least else ""
        verdict = "matches" if passed else "does not match"
        message = (f"tine-mount check: stiffness {bound}{k:.0f} N/m measured on {anvil} "
                   f"{verdict} {expected:.0f} N/m configured (clamp.contact_stiffness_n_per_m;"
                   f" ratio {bound}{ratio:.2f}, tolerance +{stiffer:g}/−{softer:g}, "
                   f"{int(n)} samples)")
        if not passed:
            message += (": the mount is stiffer than the clamp's bound assumes: check the "
                        "tines' springs before arming" if ratio > 1.0 else
                        ": check the tines' mount and the anvil before arming")
        return result(passed, k, at_least, message)


_AFTER = {Phase.RISE: Phase.ACROSS, Phase.ACROSS: Phase.DOWN, Phase.DOWN: Phase.PRESS,
          Phase.UP: Phase.BACK, Phase.BACK: Phase.RETURN, Phase.RETURN: Phase.LOWER,
          Phase.LOWER: Phase.DONE}
