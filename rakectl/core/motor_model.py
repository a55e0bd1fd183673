"""The controller's and the emulator's shared model of a DC motor and its transmission (pure).

A brushed DC motor with k_e = k_t in SI units, its voltage drive (supply and
current limits) and its transmission to one joint (a gearhead, or a lead
screw when ``lead_m_per_rev`` > 0). The declaration and the closed forms live
here so that both sides read them from one place: the controller converts
encoder counts to joint units and bounds voltages with them (the safety
clamp), the emulator (drivers.motor) integrates the same model in time.
The efficiency η acts in the direction of power flow: η × the ideal load when
the motor drives it, 1/η × when the load back-drives the motor.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from rakectl.config.declare import Bounds, setting
from rakectl.errors import ConfigError

TWO_PI = 2.0 * math.pi


def check_declared_bounds(params: Any) -> None:
    """Raise ConfigError if a field of a ``setting``-declared dataclass is out of bounds."""
    for f in dataclasses.fields(params):
        bounds = f.metadata.get("bounds")
        value = getattr(params, f.name)
        if isinstance(bounds, Bounds) and isinstance(value, int | float):
            problem = bounds.violation(float(value))
            if problem is not None:
                raise ConfigError(f"{type(params).__name__}.{f.name} {problem}")


@dataclass(frozen=True)
class MotorParams:
    """A brushed DC motor, its drive and its transmission to one joint.

    The defaults are the θ joint: a Maxon RE 40 (Ø40 mm, graphite brushes,
    150 W, 24 V winding, e.g. 148867) with a GP 52 C-class four-stage planetary
    gearhead (≈230:1, max. efficiency ≈68 %), a 500-CPT quadrature encoder and a
    24 V / 10 A-peak drive. At 10 A it delivers ≈47 N·m at the joint, against
    ≈31 N·m of gravity for the default 1.6 m, 4 kg rake held horizontal.
    :data:`R_MOTOR_DEFAULT` is the r joint.
    """

    resistance_ohm: float = setting(
        0.299, "Terminal resistance R (winding and brushes).", unit="Ω", gt=0, le=1e3
    )
    inductance_h: float = setting(0.082e-3, "Terminal inductance L.", unit="H", gt=0, le=1.0)
    torque_constant_nm_per_a: float = setting(
        0.0302, "Torque constant k_t, equal to the back-EMF constant k_e in SI.",
        unit="N·m/A", gt=0, le=10,
    )
    rotor_inertia_kgm2: float = setting(
        1.5e-5, "Inertia turning at motor speed: rotor, gearhead input, coupling, screw.",
        unit="kg·m²", gt=0, le=1,
    )
    viscous_friction_nms_per_rad: float = setting(
        2.0e-6, "Viscous friction at the motor shaft.", unit="N·m·s/rad", ge=0, le=1
    )
    coulomb_friction_nm: float = setting(
        2.5e-3, "Coulomb (brush and bearing) friction at the motor shaft.", unit="N·m",
        ge=0, le=10,
    )
    gear_ratio: float = setting(
        230.0, "Motor turns per output turn (per screw turn for a lead screw).", gt=0, le=1e5
    )
    gear_efficiency: float = setting(
        0.68, "Efficiency η of gearhead and screw, applied in the direction of power flow.",
        gt=0, le=1,
    )
    lead_m_per_rev: float = setting(
        0.0, "Screw lead; 0 makes a rotary joint, > 0 a linear (lead-screw) joint.",
        unit="m", ge=0, le=1,
    )
    supply_voltage_v: float = setting(
        24.0, "Drive supply: the commanded voltage saturates at ±this.", unit="V", gt=0, le=1e3
    )
    current_limit_a: float = setting(
        10.0, "Drive current limit: the applied voltage is reduced to hold |i| here.",
        unit="A", gt=0, le=1e3,
    )
    encoder_counts_per_rev: int = setting(
        2000, "Encoder counts per motor-shaft turn (4 × lines for quadrature).", ge=1, le=1e9
    )
    current_noise_a: float = setting(
        0.02, "Standard deviation of the drive's current measurement.", unit="A", ge=0, le=100
    )

    def __post_init__(self) -> None:
        check_declared_bounds(self)


THETA_MOTOR_DEFAULT = MotorParams()
"""θ joint: RE 40-class 24 V motor + GP 52 C-class ≈230:1 planetary (the class defaults)."""

R_MOTOR_DEFAULT = MotorParams(
    resistance_ohm=0.611,
    inductance_h=0.119e-3,
    torque_constant_nm_per_a=0.0259,
    rotor_inertia_kgm2=2.5e-5,
    viscous_friction_nms_per_rad=1.0e-6,
    coulomb_friction_nm=2.0e-3,
    gear_ratio=1.0,
    gear_efficiency=0.9,
    lead_m_per_rev=0.010,
    supply_voltage_v=24.0,
    current_limit_a=6.0,
    encoder_counts_per_rev=2000,
    current_noise_a=0.02,
)
"""r joint: Maxon RE 30-class (Ø30 mm, 24 V winding, e.g. 310007: 0.611 Ω, 0.119 mH,
25.9 mN·m/A, rotor 33.5 g·cm²) coupled directly to a Ø12 mm ball screw of 10 mm lead
(η ≈ 0.9; the ≈1.4 m screw's ≈220 g·cm² are included in the rotor inertia, which then
reflects to ≈9.9 kg on r), 500-CPT quadrature encoder, 24 V / 6 A drive: ≈1.5 m/s
no-load, ≈87 N at the current limit."""


# --------------------------------------------------------------------------- closed forms


def joint_per_motor_rad(p: MotorParams) -> float:
    """Joint motion per motor radian: 1/ratio (rad/rad) or lead/(2π·ratio) (m/rad)."""
    if p.lead_m_per_rev > 0.0:
        return p.lead_m_per_rev / (TWO_PI * p.gear_ratio)
    return 1.0 / p.gear_ratio


def reflected_inertia(p: MotorParams) -> float:
    """Motor-side inertia seen at the joint, J_m / k² (kg·m² rotary, kg linear)."""
    return p.rotor_inertia_kgm2 / joint_per_motor_rad(p) ** 2


def joint_resolution(p: MotorParams) -> float:
    """Joint motion per encoder count (rad or m)."""
    return TWO_PI * joint_per_motor_rad(p) / p.encoder_counts_per_rev


def joint_band(torque_nm: float, coulomb_nm: float, efficiency: float, inv_k: float) -> tuple[
    float, float
]:
    """(joint load while moving +, while moving −) from the motor-side torque."""
    ahead = torque_nm - coulomb_nm  # gear input torque while the joint moves +
    behind = torque_nm + coulomb_nm  # ... while it moves −
    # η on power flowing out to the load, 1/η on power flowing back from it.
    ahead = ahead * efficiency if ahead > 0.0 else ahead / efficiency
    behind = behind / efficiency if behind > 0.0 else behind * efficiency
    return ahead * inv_k, behind * inv_k


def joint_load_band(p: MotorParams, current_a: float, joint_vel: float = 0.0) -> tuple[
    float, float
]:
    """Load the drive puts on the joint if it moves + and if it moves −.

    At rest the joint sticks while the sum of all other loads lies in
    [−second, −first]: the first value is the largest load the motor can push
    forward against, the second the smallest that back-drives it.
    """
    k = joint_per_motor_rad(p)
    torque_nm = p.torque_constant_nm_per_a * current_a - p.viscous_friction_nms_per_rad * (
        joint_vel / k
    )
    return joint_band(torque_nm, p.coulomb_friction_nm, p.gear_efficiency, 1.0 / k)


def no_load_joint_speed(p: MotorParams, voltage_v: float) -> float:
    """Steady joint speed with no load at the joint (rad/s or m/s), signed like voltage_v."""
    volts = min(abs(voltage_v), p.supply_voltage_v)
    kt, res = p.torque_constant_nm_per_a, p.resistance_ohm
    motor_rad_per_s = (kt * volts - res * p.coulomb_friction_nm) / (
        kt * kt + res * p.viscous_friction_nms_per_rad
    )
    if p.viscous_friction_nms_per_rad > 0.0:  # the current limiter can cap the speed too
        capped = (kt * p.current_limit_a - p.coulomb_friction_nm) / p.viscous_friction_nms_per_rad
        motor_rad_per_s = min(motor_rad_per_s, capped)
    return math.copysign(max(motor_rad_per_s, 0.0) * joint_per_motor_rad(p), voltage_v)


def stall_current_a(p: MotorParams, voltage_v: float) -> float:
    """Steady current at standstill: V/R with V saturated at the supply, capped by the limit."""
    volts = max(-p.supply_voltage_v, min(p.supply_voltage_v, voltage_v))
    return max(-p.current_limit_a, min(p.current_limit_a, volts / p.resistance_ohm))


def stall_joint_load(p: MotorParams, voltage_v: float) -> float:
    """Largest load (N or N·m) the motor can push against at voltage_v, signed like voltage_v.

    η (k_t i_stall − τ_c) / k, with i_stall from :func:`stall_current_a`.
    """
    current_a = abs(stall_current_a(p, voltage_v))
    forward, _ = joint_load_band(p, current_a)
    return math.copysign(max(forward, 0.0), voltage_v)
