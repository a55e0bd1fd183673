"""The root of the controller's configuration, :class:`Settings`, and the constraints
between its options (pure). Every option is declared once, in its section's module: the
motion (impedance, estimator, lane, jog) in :mod:`rakectl.config.motion`, the arm
(joint loops, geometry, motors) in :mod:`rakectl.config.machine`, the voltage clamp and
force supervision in :mod:`rakectl.config.safety`, the descent budget in
:mod:`rakectl.config.descent`, the service's (bus, drives, daemon, weight check) in
:mod:`rakectl.config.service`. The control sections and the declaration functions are
re-exported here.

See :mod:`rakectl.config.declare` for how; names carry their units (``_m``, ``_s``,
``_n_per_m`` …). The emulator's options are in drivers.settings.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

from rakectl.config.declare import Bounds, has_default, section, setting
from rakectl.config.descent import DescentSettings, descent_checks
from rakectl.config.machine import (
    GeometrySettings,
    JointControlSettings,
    JointLoopSettings,
    MotorsSettings,
)
from rakectl.config.motion import EstimatorSettings, ImpedanceSettings, JogSettings, LaneSettings
from rakectl.config.safety import ClampSettings, SupervisionSettings
from rakectl.config.service import (
    BusSettings,
    DaemonSettings,
    DrivesSettings,
    SelfTestSettings,
)
from rakectl.core.kinematics import Workspace, inverse
from rakectl.core.stability import MAX_DELAY_TICKS, spectral_radius
from rakectl.errors import KinematicsError
from rakectl.limits import FORCE_LIMIT_N

# A control cycle's frames on the bus with their 47 bits of frame overhead, before bit
# stuffing: SYNC (1 B, 55 bits), 2 TPDO1 (8 B, 111 bits), 2 RPDO1 (4 B, 79 bits; a
# Roboteq-class drive's is shorter). docs/can-bus.md, "Bus load".
CYCLE_BITS = 55 + 2 * 111 + 2 * 79
# The most of the bus the cycle may take before stuffing: worst-case stuffing adds about a
# fifth, and heartbeats, TPDO2, EMCY and SDO need the rest
MAX_BUS_LOAD = 0.6
# The position loop's time constants the load-time stability check tries (s): from five
# times faster than the rake's own (its vertical step: 63 % in 96 ms) to the paper's
# P(s) = 1/(0.2 s + 1); a faster loop is the less stable one for the same impedance
LOOP_TIME_CONSTANTS_S = (0.02, 0.05, 0.1, 0.2)

# re-exported: the declaration functions (rakectl.config.declare) and the control
# sections (rakectl.config.motion, rakectl.config.machine, rakectl.config.safety)
__all__ = [
    "Bounds", "ClampSettings", "EstimatorSettings", "GeometrySettings", "ImpedanceSettings",
    "JogSettings", "JointControlSettings", "JointLoopSettings", "LaneSettings",
    "MotorsSettings", "SupervisionSettings", "has_default", "section", "setting",
]


# --------------------------------------------------------------------------- root


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
    ids = {"drives.r_node_id": d.r_node_id, "drives.theta_node_id": d.theta_node_id,
           "drives.controller_node_id": d.controller_node_id}
    errors.extend(node_id_clashes(ids))
    load = CYCLE_BITS * s.rate_hz / s.bus.bitrate
    if load > MAX_BUS_LOAD:  # named by the bit rate where it is below the robot's
        key, value = (("bus.bitrate", f"{s.bus.bitrate} bit/s") if s.bus.bitrate < 1_000_000
                      else ("rate_hz", f"{s.rate_hz:g} Hz"))
        errors.append((key, f"{value}: a cycle's {CYCLE_BITS} bits at {s.rate_hz:g} Hz take "
                       f"{100 * load:.0f} % of a {s.bus.bitrate} bit/s bus before bit "
                       f"stuffing (at most {100 * MAX_BUS_LOAD:.0f} %; the robot runs 1000 Hz "
                       "on 1 Mbit/s)"))
    if d.sync_counter_overflow == 1:
        errors.append(("drives.sync_counter_overflow",
                       "must be 0 (SYNC without counter) or 2 … 240 (CiA 301), got 1"))
    if d.heartbeat_timeout_ms <= d.heartbeat_period_ms:
        errors.append(("drives.heartbeat_timeout_ms",
                       f"must be > drives.heartbeat_period_ms ({d.heartbeat_period_ms})"))
    if s.daemon.boot_timeout_s < 2e-3 * d.heartbeat_period_ms:
        errors.append(("daemon.boot_timeout_s",
                       f"must be >= 2 drives.heartbeat_period_ms ({d.heartbeat_period_ms} ms): "
                       "bring-up waits that long for a drive's heartbeat to say OPERATIONAL, "
                       "and a drive may send it only once a period"))
    if not errors:  # the press is checked against a valid geometry
        errors.extend(_press_checks(s))
    errors.extend(descent_checks(s.descent, s.clamp.force_limit_n, s.clamp.model_margin))
    delay_ticks = s.estimator.delay_s * s.rate_hz
    if not math.isclose(delay_ticks, round(delay_ticks), abs_tol=1e-6):
        errors.append(
            ("estimator.delay_s", f"{s.estimator.delay_s:g} s is not a whole number of loop "
             f"periods at rate_hz {s.rate_hz:g} ({1 / s.rate_hz:g} s): the estimator delays "
             "by whole ticks; change one or the other")
        )
    elif s.estimator.delay_s <= s.estimator.max_delay_s:
        errors.extend(_stability_check(s, round(delay_ticks)))
    return errors


def _stability_check(s: Settings, delay_ticks: int) -> list[tuple[str, str]]:
    """The nominal discrete loop (rakectl.core.stability) must be stable, spectral radius
    < 1, with its position loop P(s) = 1/(τs + 1) at each τ of LOOP_TIME_CONSTANTS_S and
    a scenario's own ``plant.time_constant_s`` (its first-order plant's): the joint loops'
    own response is not modelled, so the check holds for a range of them."""
    imp, est = s.impedance, s.estimator
    if delay_ticks > MAX_DELAY_TICKS:
        return [("estimator.delay_s", f"{est.delay_s:g} s is {delay_ticks} loop periods at "
                 f"rate_hz {s.rate_hz:g}: the load-time stability check covers at most "
                 f"{MAX_DELAY_TICKS}")]
    own = getattr(getattr(s, "plant", None), "time_constant_s", None)
    taus = sorted({*LOOP_TIME_CONSTANTS_S, *(() if own is None else (own,))})
    values = (imp.mass_kg, imp.damping_ns_per_m, imp.stiffness_n_per_m,
              est.environment_stiffness_n_per_m, est.delay_s)

    def radius(v: tuple[float, ...], tau_s: float) -> float:
        return spectral_radius(v[0], v[1], v[2], v[3], round(v[4] * s.rate_hz), tau_s,
                               1.0 / s.rate_hz)

    worst, tau_s = max((radius(values, tau), tau) for tau in taus)
    if worst < 1.0:
        return []
    key, changed = _blamed_loop_option(values, lambda v: radius(v, tau_s) < 1.0)
    return [(key, f"{changed} the impedance loop unstable: the nominal discrete loop has "
             f"spectral radius {worst:.6g} (stable needs < 1) with impedance.mass_kg "
             f"{imp.mass_kg:g}, damping_ns_per_m {imp.damping_ns_per_m:g}, stiffness_n_per_m "
             f"{imp.stiffness_n_per_m:g}, estimator.environment_stiffness_n_per_m "
             f"{est.environment_stiffness_n_per_m:g}, delay_s {est.delay_s:g}, rate_hz "
             f"{s.rate_hz:g} and a position loop P(s) = 1/({tau_s:g} s + 1)")]


_LOOP_OPTIONS = (("impedance.mass_kg", "kg"), ("impedance.damping_ns_per_m", "N·s/m"),
                 ("impedance.stiffness_n_per_m", "N/m"),
                 ("estimator.environment_stiffness_n_per_m", "N/m"), ("estimator.delay_s", "s"))


def _blamed_loop_option(values: tuple[float, ...], stable: Callable[[tuple[float, ...]], bool]
                        ) -> tuple[str, str]:
    """The key an unstable loop is reported on, and its text: the first option whose
    default alone makes the loop stable again (the defaults are stable), else the
    impedance's and estimator's values together."""
    defaults = (ImpedanceSettings().mass_kg, ImpedanceSettings().damping_ns_per_m,
                ImpedanceSettings().stiffness_n_per_m,
                EstimatorSettings().environment_stiffness_n_per_m, EstimatorSettings().delay_s)
    for i, ((key, unit), value, default) in enumerate(zip(_LOOP_OPTIONS, values, defaults,
                                                         strict=True)):
        if value != default and stable((*values[:i], default, *values[i + 1:])):
            return key, f"{value:g} {unit} makes"
    return "impedance", "and estimator values together make"


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


def node_id_clashes(ids: dict[str, int]) -> list[tuple[str, str]]:
    """(key, message) for each two of these node-ID options that are equal, both named."""
    return [(key, f"and {other} are both {node}: the drives' and the controller's node-IDs "
                  "must differ")
            for (key, node), (other, other_node) in itertools.combinations(ids.items(), 2)
            if node == other_node]


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
