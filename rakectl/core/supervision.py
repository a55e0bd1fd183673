"""Force supervision from two independent estimates (pure).

1. F̂ of the delayed-position estimator (rakectl.core.impedance): sees vertical
   motion into the soil, reads ~0 on a flat stroke.
2. The motor currents, the paper's "indirect measurement" without a tip
   sensor: each motor's joint load k_t·i/k (k the joint motion per motor
   radian; friction and efficiency are not known, so this is the nominal
   load), the rake's weight removed with the clamp's arm model, and the tip
   force through J⁻ᵀ (rakectl.core.kinematics): at rest the tip presses down with
   F = J⁻ᵀ(Q_motor + G). Inertia is neglected, so the estimate is low-passed.
   Its vertical part is supervised; its horizontal part, the soil's cutting
   resistance (drag) a stroke works against, is read alongside, not supervised.

The larger of the two is compared with two levels, in the manner of a
collision-behaviour setting: CAUTION (the motion holds still) and HARD
(stop and back off upward), both below 90 N. CAUTION takes F̂ as it is; HARD
takes it low-passed like the currents: F̂ is a differentiated position, and a
tine dropping 0.6 mm into collapsed clay reads 78 N for ~10 ms while the
ground feels 20 N (the clamp, not supervision, bounds the true force). A
non-finite estimate is HARD.
"""

from __future__ import annotations

import enum
import math

from rakectl.config.settings import ClampSettings, GeometrySettings, SupervisionSettings
from rakectl.core import kinematics
from rakectl.core.motor_model import MotorParams, joint_per_motor_rad


class ForceLevel(enum.IntEnum):
    OK = 0
    CAUTION = 1
    HARD = 2


class ForceSupervisor:
    """Current-based tip force and the caution/hard levels, one tick at a time.

    ``f_current_n``: the low-passed vertical force of the tip on the ground (> 0
    pressing down). ``f_reach_current_n``: the low-passed force of the ground on the
    tip along the reach, > 0 pushing it toward the far end: the drag a stroke toward
    the robot (reach decreasing) works against. Both are nominal (friction and gear
    efficiency unknown): while the motors drive a stroke they read high.
    """

    __slots__ = ("_alpha", "_g", "_half_length_m", "_kt_r", "_kt_theta", "caution_n",
                 "drag_limit_n", "f_current_n", "f_hat_filtered_n", "f_max_n",
                 "f_reach_current_n", "hard_n", "level")

    def __init__(self, supervision: SupervisionSettings, clamp: ClampSettings,
                 motor_r: MotorParams, motor_theta: MotorParams, dt_s: float,
                 drag_limit_n: float = math.inf) -> None:
        """``drag_limit_n``: the drag (either way along the reach) above which the level is
        HARD (:func:`rakectl.core.descent.drag_limit_n`; none by default)."""
        self._alpha = 1.0 - math.exp(-dt_s / supervision.current_filter_s)
        self._kt_r = motor_r.torque_constant_nm_per_a / joint_per_motor_rad(motor_r)
        self._kt_theta = motor_theta.torque_constant_nm_per_a / joint_per_motor_rad(motor_theta)
        share = clamp.counterbalance_share if clamp.counterweight_kg > 0.0 else 0.0
        self._g = (1.0 - share) * clamp.rake_mass_kg * clamp.gravity_m_per_s2
        self._half_length_m = 0.5 * clamp.rake_length_m
        self.caution_n = supervision.caution_force_n
        self.hard_n = supervision.hard_force_n
        self.drag_limit_n = drag_limit_n
        self.f_current_n = 0.0
        self.f_reach_current_n = 0.0
        self.f_hat_filtered_n = 0.0
        self.f_max_n = 0.0
        self.level = ForceLevel.OK

    def reset(self) -> None:
        self.f_current_n = self.f_reach_current_n = self.f_hat_filtered_n = 0.0
        self.level = ForceLevel.OK

    def force_from_currents_n(self, r_m: float, theta_rad: float, current_r_a: float,
                              current_theta_a: float) -> float:
        """Vertical force of the tip on the ground (> 0 down) that balances the motors and
        the rake's weight at rest."""
        return down_force_n(r_m, theta_rad, self._kt_r * current_r_a,
                            self._kt_theta * current_theta_a, self._g, self._half_length_m)

    def step(self, f_hat_n: float, r_m: float, theta_rad: float, current_r_a: float,
             current_theta_a: float) -> ForceLevel:
        """Update the filtered current-based estimates and return this tick's level."""
        total = f_hat_n + r_m + theta_rad + current_r_a + current_theta_a
        if not math.isfinite(total) or r_m < kinematics.MIN_REACH_M:  # nan/inf poisons the sum
            self.level = ForceLevel.HARD
            return self.level
        reach_n, down_n = tip_force_from_loads_n(
            r_m, theta_rad, self._kt_r * current_r_a, self._kt_theta * current_theta_a,
            self._g, self._half_length_m)
        alpha = self._alpha
        self.f_current_n += alpha * (down_n - self.f_current_n)
        self.f_reach_current_n += alpha * (reach_n - self.f_reach_current_n)
        self.f_hat_filtered_n += alpha * (f_hat_n - self.f_hat_filtered_n)
        force = max(f_hat_n, self.f_current_n)
        if force > self.f_max_n:
            self.f_max_n = force
        sustained = max(self.f_hat_filtered_n, self.f_current_n)
        self.level = (ForceLevel.HARD if sustained > self.hard_n
                      or abs(self.f_reach_current_n) > self.drag_limit_n else
                      ForceLevel.CAUTION if force > self.caution_n else ForceLevel.OK)
        return self.level


def down_force_n(r_m: float, theta_rad: float, load_r_n: float, load_theta_nm: float,
                 weight_n: float, half_length_m: float) -> float:
    """Vertical force of the tip on the ground (> 0 down) that balances the joints' motor
    loads and an unbalanced weight ``weight_n`` (acting at half the rake's length) at rest:
    the second element of :func:`tip_force_from_loads_n`."""
    return tip_force_from_loads_n(r_m, theta_rad, load_r_n, load_theta_nm, weight_n,
                                  half_length_m)[1]


def tip_force_from_loads_n(r_m: float, theta_rad: float, load_r_n: float,
                           load_theta_nm: float, weight_n: float, half_length_m: float
                           ) -> tuple[float, float]:
    """(reach, down) in N: the force of the ground on the tip along the reach (> 0 toward
    the far end: the drag of a stroke toward the robot) and the vertical force of the tip
    on the ground (> 0 down), that balance the joints' motor loads and an unbalanced
    weight ``weight_n`` (acting at half the rake's length) at rest."""
    load_r = load_r_n + weight_n * math.sin(theta_rad)
    load_theta = load_theta_nm + weight_n * (r_m - half_length_m) * math.cos(theta_rad)
    # J⁻ᵀ(load) is the tip's force on the ground as (reach, height); J⁻ᵀ(−load), the
    # ground's on the tip, is (reach, down) as returned: tip_force's one tuple, bit for bit
    # the negation of the former (IEEE rounding is symmetric)
    return kinematics.tip_force(r_m, theta_rad, -load_r, -load_theta)


PLAUSIBLE_MARGIN = (0.05, 0.1)  # m on r, rad on θ: beyond the workspace's limits by more
Range = tuple[float, float]


def plausible_ranges(geometry: GeometrySettings) -> tuple[Range, Range]:
    """The joint positions a robot of this geometry can report: its limits (its end
    stops) widened by :data:`PLAUSIBLE_MARGIN`."""
    g, (margin_r, margin_theta) = geometry, PLAUSIBLE_MARGIN
    return ((g.r_min_m - margin_r, g.r_max_m + margin_r),
            (g.theta_min_rad - margin_theta, g.theta_max_rad + margin_theta))


def implausible_joints(r_m: float, theta_rad: float, ranges: tuple[Range, Range],
                       nodes: tuple[int, int]) -> str:
    """One line naming the drive whose position no robot of this geometry can have (a
    corrupt or absurd TPDO, an encoder fault), or "" when both are plausible."""
    for name, node, value, (low, high), unit, margin in (
            ("r", nodes[0], r_m, ranges[0], "m", PLAUSIBLE_MARGIN[0]),
            ("θ", nodes[1], theta_rad, ranges[1], "rad", PLAUSIBLE_MARGIN[1])):
        if not low <= value <= high:
            return (f"implausible feedback: {name} drive (node {node}) reports {value:.6g} "
                    f"{unit}, outside {low:.3g} … {high:.3g} {unit} (the workspace's limits, "
                    f"geometry.*, ± {margin:g} {unit})")
    return ""
