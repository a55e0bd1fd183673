"""The force bounds' options, declared once (pure): the voltage clamp (the force limit,
its margins, the controller's model of the rake and of the stiffest contact the tines
can meet, the reaction latency it covers) and the force supervision's caution and hard
levels. Sections of :class:`rakectl.config.settings.Settings` (see
:mod:`rakectl.config.declare` for how; names carry their units).
"""

from __future__ import annotations

from dataclasses import dataclass

from rakectl.config.declare import setting
from rakectl.limits import FORCE_LIMIT_N


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
