"""Mass, geometry and static mechanics of the r-θ rake arm (pure functions of the pose).

Generalized coordinates q = (r, θ): rake length and angle below the horizontal.
The rake and its carriage (mass m, length L) are a uniform slender rod whose
centre of mass lies s = r − L/2 from the pivot along the rake; the platform
rotates with θ, its centre of mass on the pivot. A counterweight m_c, linked to
the carriage by a cable over a pulley at the pivot, sits b·s behind the pivot
along the rake (b = β m/m_c, β the counterbalance share), so the arm's centre of
mass moves only by the unbalanced (1 − β) m. From the Lagrangian::

    T = ½ M_r ṙ² + ½ M_θ(r) θ̇²,   M_r = m' + J_r/k_r²,   m' = m + β² m²/m_c,
    M_θ(r) = m' s² + m L²/12 + I_platform + J_θ/k_θ²
    V = (1 − β) m g (h − s sin θ)

the mass matrix is diagonal (polar coordinates of rigid rods on one axis). The
functions here give that mass matrix, the gravity loads and the tip's apparent
masses for a pose, for the plant that integrates the equations of motion
(:class:`drivers.arm.ArmPlant`) and for the tests that check the controller's
clamp against the emulated arm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.motor import MotorParams, check_declared_bounds, reflected_inertia
from rakectl.config.declare import setting
from rakectl.core import kinematics


@dataclass(frozen=True)
class ArmParams:
    """Mass, geometry and end stops of the rake arm (the r-θ links, not the motors).

    Defaults: an aluminium rake with tines and a sliding carriage, 4 kg over
    1.6 m; it weighs ≈31 N·m about the pivot when held horizontal at full reach.
    """

    rake_mass_kg: float = setting(
        4.0, "Mass moving along r: rake, tines and sliding carriage.", unit="kg", gt=0, le=1e3
    )
    rake_length_m: float = setting(
        1.6, "Length of the rake; its centre of mass is r − length/2 from the pivot.",
        unit="m", gt=0, le=10,
    )
    platform_inertia_kgm2: float = setting(
        0.3, "Rotating platform about the θ pivot (centre of mass on the pivot).",
        unit="kg·m²", ge=0, le=1e3,
    )
    gravity_m_per_s2: float = setting(9.81, "Gravitational acceleration.", unit="m/s²",
                                      ge=0, le=100)
    stop_stiffness_r_n_per_m: float = setting(
        2.0e6, "Stiffness of the r end stops (0 = none).", unit="N/m", ge=0, le=1e10
    )
    stop_damping_r_ns_per_m: float = setting(
        5.0e3, "Damping of the r end stops (only pushes back).", unit="N·s/m", ge=0, le=1e8
    )
    stop_stiffness_theta_nm_per_rad: float = setting(
        1.0e6, "Stiffness of the θ end stops (0 = none).", unit="N·m/rad", ge=0, le=1e10
    )
    stop_damping_theta_nms_per_rad: float = setting(
        2.0e3, "Damping of the θ end stops (only pushes back).", unit="N·m·s/rad", ge=0, le=1e8
    )
    damping_r_ns_per_m: float = setting(
        2.0, "Viscous damping of the r slide (seals, guides).", unit="N·s/m", ge=0, le=1e5
    )
    damping_theta_nms_per_rad: float = setting(
        0.5, "Viscous damping of the θ pivot bearings.", unit="N·m·s/rad", ge=0, le=1e5
    )
    tine_mount_stiffness_n_per_m: float = setting(
        5.0e3, "Vertical stiffness of the tines' compliant mount, pushed up or pulled down "
        "(0: rigid). In series with whatever the tines press on, it bounds the contact "
        "stiffness (rakectl.core.clamp).",
        unit="N/m", ge=0, le=1e9,
    )
    tine_mount_damping_ns_per_m: float = setting(
        7.5, "Damping of the tines' compliant mount.", unit="N·s/m", ge=0, le=1e6
    )
    counterweight_kg: float = setting(
        8.0, "Counterweight linked to the carriage (a cable over a pulley at the pivot): it "
        "moves behind the pivot as the rake extends, counterbalance_share × rake mass / this "
        "× (r − length/2), so it balances that share of the rake's weight on both joints and "
        "adds counterbalance_share² × rake mass² / this to the mass each moves (0: none).",
        unit="kg", ge=0, le=1e3,
    )
    counterbalance_share: float = setting(
        0.5, "Share of the rake's weight the counterweight balances (1: the arm is balanced "
        "in every pose). A hardware requirement (rakectl.core.clamp): half leaves at most "
        "10 N of the rake's weight at the tip, which presses down with no uncertainty "
        "band while the θ gear can still lift the rest.", ge=0, le=1.5,
    )
    tine_mount_side_stiffness_n_per_m: float = setting(
        5.0e3, "Horizontal stiffness of the tines' mount (0: rigid sideways). The tines meet a "
        "stone's or a mine's side through it (rakectl.core.clamp: "
        "clamp.side_contact_stiffness_n_per_m).", unit="N/m", ge=0, le=1e9,
    )
    tine_mount_side_damping_ns_per_m: float = setting(
        7.5, "Horizontal damping of the tines' mount.", unit="N·s/m", ge=0, le=1e6
    )

    def __post_init__(self) -> None:
        check_declared_bounds(self)


def unbalanced_weight_n(arm: ArmParams) -> float:
    """The rake's weight the counterweight leaves to the motors."""
    share = arm.counterbalance_share if arm.counterweight_kg > 0.0 else 0.0
    return (1.0 - share) * arm.rake_mass_kg * arm.gravity_m_per_s2


def counterweight_mass_kg(arm: ArmParams) -> float:
    """What the counterweight adds to the mass along r (and, times (r − length/2)², to θ's
    inertia): it moves counterbalance_share × rake mass / counterweight as fast."""
    if arm.counterweight_kg <= 0.0:
        return 0.0
    return (arm.counterbalance_share * arm.rake_mass_kg) ** 2 / arm.counterweight_kg


def gravity_joint_loads(arm: ArmParams, r_m: float, theta_rad: float) -> tuple[float, float]:
    """Loads (F_r in N, τ_θ in N·m) the motors must supply to hold the pose against gravity."""
    weight_n = unbalanced_weight_n(arm)
    com_m = r_m - 0.5 * arm.rake_length_m
    return -weight_n * math.sin(theta_rad), -weight_n * com_m * math.cos(theta_rad)


def joint_masses(
    arm: ArmParams, motor_r: MotorParams, motor_theta: MotorParams, r_m: float
) -> tuple[float, float]:
    """Diagonal of the mass matrix at rake length r_m: (M_r in kg, M_θ in kg·m²)."""
    com_m = r_m - 0.5 * arm.rake_length_m
    moving_kg = arm.rake_mass_kg + counterweight_mass_kg(arm)
    return moving_kg + reflected_inertia(motor_r), (
        _inertia_at_com(arm) + arm.platform_inertia_kgm2 + reflected_inertia(motor_theta)
        + moving_kg * com_m * com_m
    )


def tip_apparent_masses_kg(
    arm: ArmParams, motor_r: MotorParams, motor_theta: MotorParams, r_m: float, theta_rad: float
) -> tuple[float, float]:
    """Mass the tip presents to a force along reach and along height: 1 / (uᵀ J M⁻¹ Jᵀ u)."""
    mass_r, inertia_theta = joint_masses(arm, motor_r, motor_theta, r_m)
    j11, j12, j21, j22 = kinematics.jacobian(r_m, theta_rad)
    return (
        1.0 / (j11 * j11 / mass_r + j12 * j12 / inertia_theta),
        1.0 / (j21 * j21 / mass_r + j22 * j22 / inertia_theta),
    )


def _inertia_at_com(arm: ArmParams) -> float:
    return arm.rake_mass_kg * arm.rake_length_m**2 / 12.0
