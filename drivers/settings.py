"""Settings of the emulated hardware: arm, motors, ground (pure declarations)."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.arm import DEFAULT_SUBSTEP_S, ArmParams
from drivers.objects import GroundParams
from rakectl.declare import section, setting
from rakectl.motor_model import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, MotorParams


@dataclass(frozen=True)
class EmulatorSettings:
    """The physics behind the drives: what the real robot would be."""

    arm: ArmParams = section(ArmParams)
    motor_r: MotorParams = section(MotorParams, R_MOTOR_DEFAULT,
                                   "Motor, lead screw and drive of the sliding joint r.")
    motor_theta: MotorParams = section(MotorParams, THETA_MOTOR_DEFAULT,
                                       "Motor, gearhead and drive of the rotary joint θ.")
    ground: GroundParams = section(GroundParams)
    substep_s: float = setting(DEFAULT_SUBSTEP_S, "Integration substep of the arm and ground.",
                               unit="s", gt=0, le=1e-3)
    seed: int = setting(0, "Seed of soil heterogeneity and sensor noise.", ge=0, le=2**32 - 1)
