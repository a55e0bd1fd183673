"""The weight check before the first arming (pure): is the rake the one the clamp models?

The clamp's bound rests on the configured rake mass and counterweight
(``clamp.rake_mass_kg``, ``counterweight_kg``, ``counterbalance_share``): a missing
counterweight doubles the weight the motors hold, and the every-direction budget is
then spent before any contact. Nothing on the robot measures them, so before the
first arming after start-up the daemon lifts the tip ``selftest.lift_m`` straight up
at ``selftest.speed_m_per_s``, holds, lowers it back and holds again. While a joint
moves steadily (the middle half of each ramp, once it is a few encoder counts from
where the ramp began, which tells its direction), the load its drive puts on it
follows from its current through the motor model's friction and efficiency band
(:func:`~rakectl.core.motor_model.joint_load_band`, the side the joint moves to):
that load holds the arm against gravity, G(r, θ) = W·(−sin θ, −(r − L/2)·cos θ) with
W the unbalanced weight. The least-squares W over both joints and every such tick is
compared with the configured one: outside ±``selftest.tolerance`` the check fails,
naming both weights. A pose where gravity has no lever on either joint cannot tell
the weight: the check fails and says so. An arm that does not follow the lift at
all fails too: the clamp bounds the upward push by the configured weight, so a rake
much heavier than configured (no counterweight) cannot be lifted within it.

The check trusts the motor model as the clamp does; the tine mount's stiffness is the
next check's (rakectl.core.mount_check, a press on the anvil).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from rakectl.config.service import SelfTestSettings
from rakectl.config.settings import ClampSettings
from rakectl.core.envelope import unbalanced_weight_n
from rakectl.core.motor_model import MotorParams, joint_load_band, joint_resolution

SETTLE_S = 0.3  # hold after each ramp
WINDOW = (0.25, 0.75)  # the part of each ramp whose ticks are used
MIN_LEVER = 0.005  # mean a² (m² or 1) below this: gravity has no lever on the weight


class Phase(enum.Enum):
    UP = "up"
    HOLD_UP = "hold_up"
    DOWN = "down"
    HOLD_DOWN = "hold_down"
    DONE = "done"


@dataclass(frozen=True)
class WeightResult:
    passed: bool
    weight_n: float  # the unbalanced weight measured (nan if no lever)
    expected_n: float  # the configured one
    samples: int
    message: str


class WeightCheck:
    """Drives the tip reference through the lift and judges the weight; see the module."""

    def __init__(self, settings: SelfTestSettings, clamp: ClampSettings, motor_r: MotorParams,
                 motor_theta: MotorParams, dt_s: float, reach_m: float, depth_m: float) -> None:
        self._settings = settings
        self.expected_n = unbalanced_weight_n(clamp)
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._motors = (motor_r, motor_theta)
        # a joint counts as moving once it is 5 encoder counts from where the ramp began
        self._min_travel = tuple(5.0 * joint_resolution(m) for m in self._motors)
        self._ramp_start = (math.nan, math.nan)
        self._dt_s = dt_s
        self._ramp_ticks = max(1, round(settings.lift_m / settings.speed_m_per_s / dt_s))
        self._settle_ticks = round(SETTLE_S / dt_s)
        self.start = (reach_m, depth_m)
        self.reach_m, self.depth_m = reach_m, depth_m
        self.phase = Phase.UP
        self._tick = 0
        self._sum_aq = self._sum_aa = 0.0
        self.samples = 0
        self._moved = False  # a joint left its ramp's start by a few counts at least once
        self.result: WeightResult | None = None

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    def step(self) -> None:
        """Advance the reference one tick (depth grows downward: up is − lift_m)."""
        if self.phase is Phase.DONE:
            return
        self._tick += 1
        lift_m, ramp = self._settings.lift_m, self._ramp_ticks
        top_m = self.start[1] - lift_m
        if self.phase is Phase.UP:
            self.depth_m = self.start[1] - lift_m * min(1.0, self._tick / ramp)
            self._next_phase_after(ramp, Phase.HOLD_UP)
        elif self.phase is Phase.HOLD_UP:
            self._next_phase_after(self._settle_ticks, Phase.DOWN)
        elif self.phase is Phase.DOWN:
            self.depth_m = top_m + lift_m * min(1.0, self._tick / ramp)
            self._next_phase_after(ramp, Phase.HOLD_DOWN)
        elif self.phase is Phase.HOLD_DOWN and self._tick >= self._settle_ticks:
            self.phase = Phase.DONE
            self.result = self._judge()

    def _next_phase_after(self, ticks: int, phase: Phase) -> None:
        if self._tick >= ticks:
            self.phase, self._tick = phase, 0

    def observe(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float,
                current_r_a: float, current_theta_a: float) -> None:
        """One tick's feedback; used while a ramp is in its middle half."""
        if self.phase not in (Phase.UP, Phase.DOWN):
            return
        if self._tick <= 1:
            self._ramp_start = (r_m, theta_rad)
        share = self._tick / self._ramp_ticks
        if not WINDOW[0] <= share <= WINDOW[1]:
            return
        lever = (-math.sin(theta_rad), -(r_m - self._half_length_m) * math.cos(theta_rad))
        joints = ((r_m, r_vel, current_r_a), (theta_rad, theta_vel, current_theta_a))
        for j, (position, vel, current) in enumerate(joints):
            moved = position - self._ramp_start[j]
            if abs(moved) < self._min_travel[j]:
                continue  # too little motion to tell which side of the band applies
            self._moved = True
            ahead, behind = joint_load_band(self._motors[j], current, vel)
            load = ahead if moved > 0.0 else behind
            self._sum_aq += lever[j] * load
            self._sum_aa += lever[j] * lever[j]
            self.samples += 1

    def _judge(self) -> WeightResult:
        expected, tolerance = self.expected_n, self._settings.tolerance
        if not self._moved:
            return WeightResult(False, math.nan, expected, self.samples,
                                f"weight check: the arm did not follow the "
                                f"{self._settings.lift_m * 1e3:.0f} mm lift within the clamp's "
                                f"bound: the rake may be heavier than the {expected:.1f} N "
                                "configured (clamp.rake_mass_kg, counterweight_kg, "
                                "counterbalance_share): check the counterweight before arming")
        if self.samples == 0 or self._sum_aa < MIN_LEVER * self.samples:
            return WeightResult(False, math.nan, expected, self.samples,
                                "weight check: gravity has no lever on the joints at this pose "
                                f"(reach {self.start[0]:.3f} m): arm from another pose")
        weight_n = self._sum_aq / self._sum_aa
        ratio = weight_n / expected if expected > 0.0 else math.inf
        passed = abs(ratio - 1.0) <= tolerance
        verdict = "matches" if passed else "does not match"
        message = (f"weight check: unbalanced weight {weight_n:.1f} N measured {verdict} "
                   f"{expected:.1f} N configured (clamp.rake_mass_kg, counterweight_kg, "
                   f"counterbalance_share; ratio {ratio:.2f}, tolerance ±{tolerance:g})")
        if not passed:
            message += ": check the counterweight and the rake before arming"
        return WeightResult(passed, weight_n, expected, self.samples, message)
