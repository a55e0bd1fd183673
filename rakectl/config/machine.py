"""The arm's options, declared once (pure): the gains of the two joint position loops,
the r-θ rake's geometry and joint limits, and the controller's model of its motors and
transmissions (counts to joint units, the clamp's motor constants). Sections of
:class:`rakectl.config.settings.Settings` (see :mod:`rakectl.config.declare` for how;
names carry their units).
"""

from __future__ import annotations

from dataclasses import dataclass

from rakectl.config.declare import section, setting
from rakectl.core.motor_model import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, MotorParams


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
