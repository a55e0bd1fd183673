"""The motion's options, declared once (pure): the desired impedance on the vertical
axis, the force estimate from delayed positions, raking a lane (at a set or a
force-adaptive stroke speed) and operator jogging. Sections of
:class:`rakectl.config.settings.Settings` (see :mod:`rakectl.config.declare` for how;
names carry their units).
"""

from __future__ import annotations

from dataclasses import dataclass

from rakectl.config.declare import setting


@dataclass(frozen=True)
class ImpedanceSettings:
    """Desired impedance M_d ẍ_c + B_d ẋ_c + K_d x_c = F_d − F̂ on the vertical axis."""

    mass_kg: float = setting(0.39, "Desired mass M_d.", unit="kg", gt=0, le=1e4)
    damping_ns_per_m: float = setting(
        1.33e4, "Desired damping B_d.", unit="N·s/m", gt=0, le=1e8
    )
    stiffness_n_per_m: float = setting(
        1.0e4, "Desired stiffness K_d.", unit="N/m", gt=0, le=1e8
    )


@dataclass(frozen=True)
class EstimatorSettings:
    """Force estimate F̂ = K_e (x(t) − x(t − α)) from delayed measured positions."""

    environment_stiffness_n_per_m: float = setting(
        2.0e5, "Assumed soil stiffness K_e.", unit="N/m", gt=0, le=1e9
    )
    delay_s: float = setting(
        0.01, "Delay α of the undeformed-soil estimate x_e = x(t − α); 0 = free space.",
        unit="s", ge=0, le=1.0,
    )
    max_delay_s: float = setting(
        0.5, "Longest α the position history can serve (sizes the ring).", unit="s", gt=0, le=5.0
    )


@dataclass(frozen=True)
class LaneSettings:
    """Raking a lane (paper Fig. 3): contact strokes toward the robot, deeper each cycle."""

    reach_far_m: float = setting(1.3, "Where each contact stroke starts.", unit="m", gt=0,
                                 le=10)
    reach_near_m: float = setting(0.8, "Where each contact stroke ends.", unit="m", gt=0,
                                  le=10)
    depth_step_m: float = setting(0.01, "Depth added after each cycle.", unit="m", gt=0,
                                  le=0.1)
    target_depth_m: float = setting(0.05, "Depth of the last stroke below ground level 0.",
                                    unit="m", gt=0, le=0.5)
    clearance_m: float = setting(0.03, "Height of the tip above ground on the return.",
                                 unit="m", ge=0.005, le=0.5)
    stroke_speed_m_per_s: float = setting(0.05, "Tip speed along a contact stroke.",
                                          unit="m/s", gt=0, le=1)
    plunge_speed_m_per_s: float = setting(0.007, "Descent speed into the soil.", unit="m/s",
                                          gt=0, le=1)
    travel_speed_m_per_s: float = setting(0.15, "Tip speed in free space.", unit="m/s", gt=0,
                                          le=2)
    stall_error_m: float = setting(
        0.02, "A contact stroke whose tip lags its reference by more than this has met a rigid "
        "object (a stone, a mine): stop, lift clear, report where.", unit="m", gt=0.002, le=0.5)
    accel_m_per_s2: float = setting(0.5, "Tip acceleration limit of the reference; it stops "
                                    "at every corner of the path.", unit="m/s²", gt=0, le=20)
    adaptive: bool = setting(
        False, "Force-adaptive stroke speed (rakectl.core.governor): the first contact stroke "
        "starts at stroke_speed_m_per_s; the speed then follows the larger force estimate (F̂ or "
        "the current-based one) toward force_target_share × supervision.caution_force_n, keeps the "
        "tip's lag under half of stall_error_m, and stays within min_stroke_speed_m_per_s … "
        "max_stroke_speed_m_per_s.")
    min_stroke_speed_m_per_s: float = setting(
        0.03, "Adaptive: slowest stroke (supervision's caution level still holds the motion). "
        "Slower than ~3× the emulated drag's smoothing speed (0.01 m/s), a tine that the "
        "drag has lifted is let go and drops.", unit="m/s", gt=0, le=1)
    max_stroke_speed_m_per_s: float = setting(
        0.15, "Adaptive: fastest stroke. The clamp's budget toward the robot shrinks with the "
        "tip's speed (at 1.2 m with the 5 kN/m mount: 35 N at rest, 26 N at 0.1 m/s, 17 N at "
        "0.15 m/s, none from 0.22 m/s): faster, a stroke at depth is cut until it rides up out "
        "of its cut.", unit="m/s",
        gt=0, le=1)
    max_plunge_speed_m_per_s: float = setting(
        0.02, "Adaptive: fastest plunge. Each plunge starts at plunge_speed_m_per_s and "
        "follows the stroke's force set point up to this, never slower than "
        "plunge_speed_m_per_s (in steady state F̂ = K_e·v·α: 2000 N per m/s with the "
        "paper's values).", unit="m/s", gt=0, le=1)
    force_target_share: float = setting(
        0.8, "Adaptive: the stroke's force set point as a share of "
        "supervision.caution_force_n.", gt=0, lt=1)
    max_depth_step_m: float = setting(
        0.04, "Adaptive: deepest cut. Per 20 mm of reach, each cut is the one the last stroke "
        "took there (from the floor the tip left) times that stroke's margin there (force set "
        "point / its peak estimate, and the same for the lag), at most doubled, at least "
        "depth_step_m below what was done; deeper far from the robot, never descending toward "
        "it. Strokes start where the lane is not yet at target_depth_m.", unit="m", gt=0,
        le=0.1)
    governor_gain_per_s: float = setting(
        2.0, "Adaptive: with no force the speed limit rises by this share of "
        "max_stroke_speed_m_per_s per second; above the set point it falls 8× faster.",
        unit="1/s", gt=0, le=100)

    def __post_init__(self) -> None:
        from rakectl.errors import ConfigError

        if self.min_stroke_speed_m_per_s > self.max_stroke_speed_m_per_s:
            raise ConfigError("min_stroke_speed_m_per_s must be <= max_stroke_speed_m_per_s "
                              f"({self.max_stroke_speed_m_per_s:g})")
        if self.adaptive and self.max_plunge_speed_m_per_s < self.plunge_speed_m_per_s:
            raise ConfigError(f"max_plunge_speed_m_per_s ({self.max_plunge_speed_m_per_s:g}) "
                              f"must be >= plunge_speed_m_per_s ({self.plunge_speed_m_per_s:g}) "
                              "on an adaptive lane")
        if self.adaptive and self.max_depth_step_m < self.depth_step_m:
            raise ConfigError(f"max_depth_step_m ({self.max_depth_step_m:g}) must be >= "
                              f"depth_step_m ({self.depth_step_m:g}) on an adaptive lane")


@dataclass(frozen=True)
class JogSettings:
    """Operator jogging: speed and acceleration limits and the dead-man."""

    max_tip_speed_m_per_s: float = setting(0.1, "Largest tip speed in task-space jog.",
                                           unit="m/s", gt=0, le=1)
    max_r_speed_m_per_s: float = setting(0.1, "Largest r speed in joint-space jog.",
                                         unit="m/s", gt=0, le=1)
    max_theta_speed_rad_per_s: float = setting(0.15, "Largest θ speed in joint-space jog.",
                                               unit="rad/s", gt=0, le=2)
    accel_per_s: float = setting(4.0, "Largest change of the jog speed per second, as a share "
                                 "of the largest speed (4: full speed in 0.25 s).", unit="1/s",
                                 gt=0, le=100)
    deadman_s: float = setting(0.3, "Silence from the operator after which jogging stops "
                               "(clients send every 0.1 s).", unit="s", ge=0.05, le=5)
    contact_depth_m: float = setting(-0.005, "Jog references deeper than this are treated as "
                                     "contact (α > 0).", unit="m", ge=-0.5, le=0.5)
    max_lag_m: float = setting(
        0.02, "The jog reference waits while it is this far from the measured tip and a step "
        "would take it further (a tip blocked by something rigid, or held back by the clamp): "
        "the joint loops are never asked to push on through it.", unit="m", gt=0, le=0.5)
