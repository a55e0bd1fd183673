"""Every option of the controller's configuration, declared once (pure): the control
sections here, the service's (bus, drives, daemon, weight check) in
:mod:`rakectl.config.service`, under the root :class:`Settings`.

See :mod:`rakectl.config.declare` for how; names carry their units (``_m``, ``_s``,
``_n_per_m`` …). The emulator's options are in drivers.settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rakectl.config.declare import Bounds, has_default, section, setting
from rakectl.config.descent import DescentSettings, descent_checks
from rakectl.config.service import (
    BusSettings,
    DaemonSettings,
    DrivesSettings,
    SelfTestSettings,
)
from rakectl.core.kinematics import Workspace, inverse
from rakectl.core.motor_model import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, MotorParams
from rakectl.errors import KinematicsError
from rakectl.limits import FORCE_LIMIT_N

__all__ = ["Bounds", "has_default", "section", "setting"]  # re-exported declaration functions


# --------------------------------------------------------------------------- sections


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
        "tip's speed (at 1.2 m with the 5 kN/m mount: 35 N at rest, 27 N at 0.1 m/s, 18 N at "
        "0.15 m/s, none from 0.23 m/s): faster, a stroke at depth is cut until it rides up out "
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


@dataclass(frozen=True)
class JointLoopSettings:
    """Gains of one joint position loop (PID with velocity feed-forward); per joint unit."""

    kp_v_per_unit: float = setting(2000.0, "Proportional gain.", unit="V/(m or rad)", ge=0,
                                   le=1e7)
    ki_v_per_unit_s: float = setting(1000.0, "Integral gain.", unit="V/((m or rad)·s)", ge=0,
                                     le=1e9)
    kd_v_s_per_unit: float = setting(40.0, "Derivative gain on the measured velocity.",
                                     unit="V·s/(m or rad)", ge=0, le=1e5)
    kff_v_s_per_unit: float = setting(16.0, "Velocity feed-forward (back-EMF).",
                                      unit="V·s/(m or rad)", ge=0, le=1e5)


@dataclass(frozen=True)
class JointControlSettings:
    """Joint position loops: the physical counterpart of the paper's P(s)."""

    r: JointLoopSettings = section(JointLoopSettings)
    theta: JointLoopSettings = section(
        JointLoopSettings,
        JointLoopSettings(kp_v_per_unit=1200.0, ki_v_per_unit_s=600.0, kd_v_s_per_unit=40.0,
                          kff_v_s_per_unit=7.0),
    )
    voltage_limit_v: float = setting(24.0, "Largest voltage the loops command.", unit="V",
                                     gt=0, le=60)


@dataclass(frozen=True)
class GeometrySettings:
    """Geometry and joint limits of the r-θ rake."""

    pivot_height_m: float = setting(0.6, "Height of the θ pivot above the ground.", unit="m",
                                    gt=0, le=5)
    r_min_m: float = setting(0.35, "Shortest rake length.", unit="m", ge=0.01, le=10)
    r_max_m: float = setting(1.6, "Longest rake length.", unit="m", gt=0.01, le=10)
    theta_min_rad: float = setting(-0.2, "Lowest joint angle (θ below horizontal).",
                                   unit="rad", gt=-1.5, lt=1.5)
    theta_max_rad: float = setting(1.3, "Highest joint angle (θ below horizontal).",
                                   unit="rad", gt=-1.5, lt=1.5)


@dataclass(frozen=True)
class MotorsSettings:
    """The controller's model of its motors and transmissions (counts → joint units, clamp)."""

    r: MotorParams = section(MotorParams, R_MOTOR_DEFAULT,
                             "Motor, lead screw and drive of the sliding joint r.")
    theta: MotorParams = section(MotorParams, THETA_MOTOR_DEFAULT,
                                 "Motor, gearhead and drive of the rotary joint θ.")


@dataclass(frozen=True)
class ClampSettings:
    """The voltage clamp: the last stage before a voltage is encoded (see rakectl.core.clamp)."""

    force_limit_n: float = setting(
        FORCE_LIMIT_N, "Largest force the tip may put on anything it meets, in any direction "
        "(the ground, a buried object's top, side or edge). May be lowered, never raised above "
        "90 N (pressure-fused mines).", unit="N", gt=0, le=FORCE_LIMIT_N)
    model_margin: float = setting(
        0.2, "Share of force_limit_n kept back for model error (masses, friction, k_t, η).",
        ge=0.05, lt=1)
    velocity_margin_counts: float = setting(
        1.0, "Uncertainty of a measured joint velocity, in encoder counts per control period "
        "(a difference of two positions each quantized within one count is off by < 1).",
        ge=0, le=1000)
    velocity_margin_share: float = setting(
        0.1, "Further velocity uncertainty as a share of the measured velocity.", ge=0, le=1)
    rake_mass_kg: float = setting(4.0, "The controller's model of the rake and carriage mass.",
                                  unit="kg", gt=0, le=100)
    rake_length_m: float = setting(1.6, "The controller's model of the rake's length (its "
                                   "centre of mass is at r − length/2).", unit="m", gt=0, le=10)
    gravity_m_per_s2: float = setting(9.81, "Gravity.", unit="m/s²", gt=9, lt=10.5)
    platform_inertia_kgm2: float = setting(
        0.3, "The controller's model of the rotating platform's inertia about the pivot (for "
        "the tip's apparent mass).", unit="kg·m²", ge=0, le=1e3)
    counterweight_kg: float = setting(
        8.0, "The controller's model of the counterweight linked to the carriage (0: none).",
        unit="kg", ge=0, le=1e3)
    counterbalance_share: float = setting(
        0.5, "The controller's model of the share of the rake's weight the counterweight "
        "balances. A hardware requirement: with the θ gear's efficiency band (η = 0.68) an "
        "unbalanced rake cannot be lifted at full reach within the every-direction budget, "
        "and a fully balanced one presses down only through that band.",
        ge=0, le=1.5)
    contact_stiffness_n_per_m: float = setting(
        5.0e3, "Stiffest vertical contact the tines can meet: their compliant mount's stiffness, "
        "in series with anything they press (a stone, a mine's plate). A hardware requirement "
        "(90 N at 18 mm), pushed up and pulled down alike: a rigid tine on a rigid plate would "
        "make any descent speed an impact above 90 N, and a lift into an object's bottom the "
        "same.", unit="N/m", gt=0, le=1e9)
    contact_damping_ns_per_m: float = setting(
        7.5, "Damping in parallel with that stiffness (the mount's).", unit="N·s/m", ge=0,
        le=1e6)
    side_contact_stiffness_n_per_m: float = setting(
        5.0e3, "Stiffest horizontal contact the tines can meet: their mount's horizontal "
        "stiffness (a hardware requirement, as the vertical one). A tine rigid sideways meets "
        "a stone's side at 0.1 m/s with several hundred newtons; a mount softer sideways than "
        "vertically stores energy a rounded edge turns into a vertical push √(k_v/k_h) times "
        "larger, so the clamp's side budgets shrink by that factor.", unit="N/m", gt=0, le=1e9)
    side_contact_damping_ns_per_m: float = setting(
        7.5, "Damping in parallel with the horizontal stiffness (the mount's).", unit="N·s/m",
        ge=0, le=1e6)
    reaction_latency_s: float = setting(
        0.004, "Longest time from a velocity measurement until the voltage chosen from it "
        "stops acting: the drives hold a command until the next one arrives or, when none "
        "does (a stalled or dead controller, a lost command), until their command watchdog "
        "(drives.watchdog_timeout_ms) ends it, and the measurement is up to one loop period "
        "old. So at least drives.watchdog_timeout_ms plus one period (the robot: 3 + 1 ms).",
        unit="s", ge=0, le=0.1)


@dataclass(frozen=True)
class SupervisionSettings:
    """Force supervision on two estimates: the delayed-position F̂ and the motor currents."""

    caution_force_n: float = setting(
        55.0, "Above this estimated vertical force the motion holds still (no advance).",
        unit="N", gt=0, lt=FORCE_LIMIT_N)
    hard_force_n: float = setting(
        75.0, "Above this the motion stops and the tip backs off upward; must stay below 90 N.",
        unit="N", gt=0, lt=FORCE_LIMIT_N)
    back_off_m: float = setting(0.01, "How far the tip backs off upward on the hard level.",
                                unit="m", gt=0, le=0.1)
    current_filter_s: float = setting(
        0.02, "Time constant of the low-pass on the current-based force estimate.", unit="s",
        gt=0, le=1)


@dataclass(frozen=True)
class Settings:
    """Root of the daemon's configuration file (a scenario adds the simulation's own sections)."""

    impedance: ImpedanceSettings = section(ImpedanceSettings)
    estimator: EstimatorSettings = section(EstimatorSettings)
    lane: LaneSettings = section(LaneSettings)
    jog: JogSettings = section(JogSettings)
    geometry: GeometrySettings = section(GeometrySettings)
    joint_control: JointControlSettings = section(JointControlSettings)
    motors: MotorsSettings = section(MotorsSettings)
    clamp: ClampSettings = section(ClampSettings)
    supervision: SupervisionSettings = section(SupervisionSettings)
    descent: DescentSettings = section(DescentSettings)
    bus: BusSettings = section(BusSettings)
    drives: DrivesSettings = section(DrivesSettings)
    daemon: DaemonSettings = section(DaemonSettings)
    selftest: SelfTestSettings = section(SelfTestSettings)
    desired_force_n: float = setting(0.0, "Desired contact force F_d.", unit="N",
                                     ge=-FORCE_LIMIT_N, le=FORCE_LIMIT_N)
    rate_hz: float = setting(1000.0, "Control loop rate.", unit="Hz", ge=10, le=10000)

    def cross_checks(self) -> list[tuple[str, str]]:
        """Constraints between options: (dotted key, message) for each violation."""
        return cross_checks(self)


def held_command_gap(s: Settings) -> str:
    """Why the voltage clamp's bound does not cover the command the drives hold when the
    controller falls silent, or "" (pure). The drives apply a command until the next one
    or, without one, until their watchdog: up to ``drives.watchdog_timeout_ms`` after it
    arrived, one loop period after the measurement it was chosen from. The clamp's
    budget carries ``clamp.reaction_latency_s`` of that (rakectl.core.envelope)."""
    needed_s = s.drives.watchdog_timeout_ms * 1e-3 + 1.0 / s.rate_hz
    carried_s = s.clamp.reaction_latency_s
    if carried_s >= needed_s - 1e-12:
        return ""
    return (f"clamp.reaction_latency_s ({carried_s * 1e3:g} ms) does not cover the command "
            f"the drives hold after the controller falls silent: drives.watchdog_timeout_ms "
            f"({s.drives.watchdog_timeout_ms} ms) plus one loop period "
            f"({1e3 / s.rate_hz:g} ms) = {needed_s * 1e3:g} ms")


def cross_checks(s: Settings) -> list[tuple[str, str]]:
    """Constraints between options: (dotted key, message) for each violation."""
    errors: list[tuple[str, str]] = []
    g = s.geometry
    if not g.r_max_m > g.r_min_m:
        errors.append(("geometry.r_max_m", f"must be > geometry.r_min_m ({g.r_min_m:g})"))
    if not g.theta_max_rad > g.theta_min_rad:
        errors.append(
            ("geometry.theta_max_rad", f"must be > geometry.theta_min_rad ({g.theta_min_rad:g})")
        )
    if s.estimator.delay_s > s.estimator.max_delay_s:
        errors.append(
            ("estimator.delay_s", f"must be <= estimator.max_delay_s ({s.estimator.max_delay_s:g})")
        )
    if not s.lane.reach_far_m > s.lane.reach_near_m:
        errors.append(
            ("lane.reach_far_m", f"must be > lane.reach_near_m ({s.lane.reach_near_m:g})")
        )
    if not s.supervision.hard_force_n > s.supervision.caution_force_n:
        caution = s.supervision.caution_force_n
        errors.append(("supervision.hard_force_n",
                       f"must be > supervision.caution_force_n ({caution:g})"))
    d = s.drives
    if len({d.r_node_id, d.theta_node_id, d.controller_node_id}) < 3:
        errors.append(("drives.theta_node_id", "node-IDs of drives and controller must differ"))
    if d.sync_counter_overflow == 1:
        errors.append(("drives.sync_counter_overflow",
                       "must be 0 (SYNC without counter) or 2 … 240 (CiA 301), got 1"))
    if d.heartbeat_timeout_ms <= d.heartbeat_period_ms:
        errors.append(("drives.heartbeat_timeout_ms",
                       f"must be > drives.heartbeat_period_ms ({d.heartbeat_period_ms})"))
    if not errors:  # the press is checked against a valid geometry
        errors.extend(_press_checks(s))
    errors.extend(descent_checks(s.descent, s.clamp.force_limit_n, s.clamp.model_margin))
    delay_ticks = s.estimator.delay_s * s.rate_hz
    if not math.isclose(delay_ticks, round(delay_ticks), abs_tol=1e-6):
        errors.append(
            ("estimator.delay_s", f"must be a whole number of loop periods (1/{s.rate_hz:g} s)")
        )
    return errors


PRESS_HEIGHT_TOLERANCE_M = 0.005  # how well the anvil's height must be known
PRESS_MAX_DEPTH_M = 0.02


SIDE_BELOW_TOP_M = 0.01  # the anvil's side is pressed at least this far below its top


def press_depth_m(selftest: SelfTestSettings, clamp: ClampSettings, sideways: bool = False
                  ) -> float:
    """How far past the anvil's configured face (its top, or with ``sideways`` its near
    side) the tine-mount check's press may go: the face's tolerance plus 2.5 times the
    configured mount's compression that way at the press's force, at most
    ``PRESS_MAX_DEPTH_M`` (with no anvil there, what lies beyond is pressed no further)."""
    stiffness = clamp.side_contact_stiffness_n_per_m if sideways else \
        clamp.contact_stiffness_n_per_m
    compression_m = selftest.press_force_n / stiffness
    return min(PRESS_MAX_DEPTH_M, PRESS_HEIGHT_TOLERANCE_M + 2.5 * compression_m)


def anvil_side_reach_m(selftest: SelfTestSettings) -> float:
    """The reach of the anvil's near side, the face the sideways press meets."""
    return selftest.anvil_reach_m - 0.5 * selftest.anvil_width_m


def _press_checks(s: Settings) -> list[tuple[str, str]]:
    """The tine-mount check's anvil must be reachable and its press within the clamp's
    bound on a push at rest."""
    t = s.selftest
    if not t.press:
        return []
    errors = []
    if t.press_force_n > 0.5 * s.clamp.force_limit_n:
        errors.append(("selftest.press_force_n", f"must be <= half clamp.force_limit_n "
                       f"({0.5 * s.clamp.force_limit_n:g} N), got {t.press_force_n:g}"))
    if t.anvil_side_height_m > t.anvil_height_m - SIDE_BELOW_TOP_M:
        errors.append(("selftest.anvil_side_height_m", "must be at least "
                       f"{1e3 * SIDE_BELOW_TOP_M:g} mm below the anvil's top "
                       f"(selftest.anvil_height_m {t.anvil_height_m:g} m): the side is pressed "
                       f"on its flat face, got {t.anvil_side_height_m:g}"))
    g = s.geometry
    try:  # from below the anvil's top (the press's deepest) to above it (the approach)
        workspace = Workspace(g.pivot_height_m, g.r_min_m, g.r_max_m, g.theta_min_rad,
                              g.theta_max_rad)
        for height_m in (t.anvil_height_m - press_depth_m(t, s.clamp), t.anvil_height_m + 0.02):
            inverse(workspace, t.anvil_reach_m, height_m)
    except KinematicsError as error:
        errors.append(("selftest.anvil_reach_m", "the press on the anvil (selftest.anvil_reach_m, "
                       f"anvil_height_m) leaves the workspace: {error}"))
        return errors
    side_m = anvil_side_reach_m(t)
    try:  # beside the near side, above it, and the sideways press's furthest
        for reach_m, height_m in ((side_m - 0.02, t.anvil_height_m + 0.02),
                                  (side_m - 0.02, t.anvil_side_height_m),
                                  (side_m + press_depth_m(t, s.clamp, sideways=True),
                                   t.anvil_side_height_m)):
            inverse(workspace, reach_m, height_m)
    except KinematicsError as error:
        errors.append(("selftest.anvil_width_m", "the press on the anvil's near side "
                       "(selftest.anvil_reach_m − anvil_width_m/2, anvil_side_height_m) leaves "
                       f"the workspace: {error}"))
    return errors
