"""A DC motor, its voltage drive and its transmission to one joint (pure model).

Electrical model, with k_e = k_t in SI units and ω_m the motor speed::

    L di/dt = V − R i − k_e ω_m

The drive saturates the commanded voltage at ±supply and, like a real drive's
current limiter, lowers the applied voltage so that |i| stays at the current
limit. Over one substep ω_m is frozen and the current is integrated exactly
(exponential decay towards (V − k_e ω_m)/R), so the electrical time constant
L/R (0.2–0.3 ms here) never limits the substep.

Transmission: a joint moves ``joint_per_motor_rad`` (rad for a gearhead, m
for a lead screw) per radian of motor shaft. The gear's input torque is the
motor torque k_t i minus the motor's viscous and Coulomb friction. The
efficiency η acts in the direction of power flow: when the motor drives the
load the joint receives η × the ideal load; when the load back-drives the
motor, the motor sees η × the load's ideal torque, so the joint meets
1/η × the ideal. Both friction kinds only ever take energy out. At rest the
joint sticks while the other loads fall inside the band those two cases span
(:func:`joint_load_band`); this is resolved implicitly (backward Euler on the
set-valued friction law, :func:`stick_slip_velocity`), so there is no chatter
at zero speed. The rotor inertia is reflected to the joint as J_m / k² and
treated as lossless: η acts on the motor's torque net of its friction, not on
the torque that accelerates the rotor.

Joint units: positions in rad or m, velocities in rad/s or m/s, joint loads
in N·m or N, depending on whether the joint is rotary (``lead_m_per_rev`` = 0)
or a lead screw.
"""

from __future__ import annotations

import enum
import math

from rakectl.core.motor_model import (
    R_MOTOR_DEFAULT,
    THETA_MOTOR_DEFAULT,
    TWO_PI,
    MotorParams,
    check_declared_bounds,
    joint_band,
    joint_load_band,
    joint_per_motor_rad,
    joint_resolution,
    no_load_joint_speed,
    reflected_inertia,
    stall_current_a,
    stall_joint_load,
)
from rakectl.errors import ConfigError

__all__ = [
    "R_MOTOR_DEFAULT",
    "THETA_MOTOR_DEFAULT",
    "TWO_PI",
    "Bridge",
    "MotorDrive",
    "MotorJoint",
    "MotorParams",
    "check_declared_bounds",
    "joint_band",
    "joint_load_band",
    "joint_per_motor_rad",
    "joint_resolution",
    "no_load_joint_speed",
    "reflected_inertia",
    "stall_current_a",
    "stall_joint_load",
    "stick_slip_velocity",
    "substeps_in",
]

class Bridge(enum.Enum):
    """State of the drive's output stage."""

    DRIVEN = "driven"  # the H-bridge applies the commanded voltage (0 V shorts the motor)
    OPEN = "open"  # motor leads disconnected (e.g. safety contactor): no current flows


def substeps_in(dt_s: float, substep_s: float) -> int:
    """Number of substeps in dt_s; ConfigError unless dt_s is a whole multiple of substep_s."""
    count = round(dt_s / substep_s)
    if count < 1 or abs(count * substep_s - dt_s) > 1e-9 * dt_s:
        raise ConfigError(f"dt_s={dt_s:g} s is not a whole number of substeps of {substep_s:g} s")
    return count


# --------------------------------------------------------------------------- discrete model


def stick_slip_velocity(
    free_momentum: float, impulse_plus: float, impulse_minus: float, mass: float
) -> float:
    """New velocity under a set-valued (stick-slip) load, backward Euler.

    ``free_momentum`` is mass × velocity after all other impulses of the substep;
    ``impulse_plus``/``impulse_minus`` are the friction-bearing load's impulses
    if the joint ends the substep moving + / − (impulse_plus ≤ impulse_minus).
    Friction never reverses the motion: where neither fits, the joint sticks.
    """
    velocity = (free_momentum + impulse_plus) / mass
    if velocity > 0.0:
        return velocity
    velocity = (free_momentum + impulse_minus) / mass
    if velocity < 0.0:
        return velocity
    return 0.0


class MotorDrive:
    """One motor with drive and transmission, discretized at a fixed substep."""

    __slots__ = (
        "_coulomb",
        "_decay",
        "_efficiency",
        "_emf_per_vel",
        "_imax",
        "_inv_k",
        "_kt",
        "_mean",
        "_res",
        "_rise",
        "_visc_per_vel",
        "_vmax",
        "emf_damping",
        "params",
        "reflected_inertia",
        "resolution",
        "substep_s",
    )

    def __init__(self, params: MotorParams, substep_s: float) -> None:
        k = joint_per_motor_rad(params)
        self.params = params
        self.substep_s = substep_s
        self.reflected_inertia = reflected_inertia(params)
        self.resolution = joint_resolution(params)
        kt, self._res = params.torque_constant_nm_per_a, params.resistance_ohm
        self.emf_damping = kt * kt / (self._res * k * k)  # shorted-motor joint damping
        self._kt, self._inv_k = kt, 1.0 / k
        self._emf_per_vel = kt / k
        self._visc_per_vel = params.viscous_friction_nms_per_rad / k
        self._coulomb, self._efficiency = params.coulomb_friction_nm, params.gear_efficiency
        self._vmax, self._imax = params.supply_voltage_v, params.current_limit_a
        x = substep_s * self._res / params.inductance_h
        self._decay = math.exp(-x)  # exact decay of i over one substep
        self._rise = -math.expm1(-x)  # 1 − decay, without cancellation
        self._mean = self._rise / x  # mean of the decaying part over the substep

    def currents(
        self, current_a: float, voltage_cmd_v: float, joint_vel: float, bridge: Bridge
    ) -> tuple[float, float]:
        """(current at the end, mean current over) one substep at frozen joint_vel."""
        if bridge is Bridge.OPEN:
            return 0.0, 0.0
        emf_v = self._emf_per_vel * joint_vel
        volts = max(-self._vmax, min(self._vmax, voltage_cmd_v))
        steady_a = (volts - emf_v) / self._res
        end_a = steady_a + (current_a - steady_a) * self._decay
        if abs(end_a) > self._imax:  # limiter: the voltage that lands exactly on the limit
            steady_a = (math.copysign(self._imax, end_a) - current_a * self._decay) / self._rise
            volts = max(-self._vmax, min(self._vmax, steady_a * self._res + emf_v))
            steady_a = (volts - emf_v) / self._res
            end_a = steady_a + (current_a - steady_a) * self._decay
        return end_a, steady_a + (current_a - steady_a) * self._mean

    def load_band(self, current_a: float, joint_vel: float) -> tuple[float, float]:
        """As :func:`joint_load_band`, with the constants precomputed."""
        torque_nm = self._kt * current_a - self._visc_per_vel * joint_vel
        return joint_band(torque_nm, self._coulomb, self._efficiency, self._inv_k)

    def counts(self, joint_position: float) -> int:
        """Encoder counts at a joint position (incremental, zeroed at joint position 0)."""
        return math.floor(joint_position / self.resolution)


class MotorJoint:
    """One motor driving a rigid load on its own: the dyno rig of the motor tests.

    ``external_load`` (N or N·m) acts on the joint in its positive direction.
    """

    def __init__(self, params: MotorParams, load_inertia: float, substep_s: float) -> None:
        if not (load_inertia >= 0.0 and substep_s > 0.0):
            raise ConfigError("need load_inertia >= 0 and substep_s > 0")
        self.drive = MotorDrive(params, substep_s)
        self.mass = load_inertia + self.drive.reflected_inertia
        self.bridge = Bridge.DRIVEN
        self.position, self.velocity, self.current_a = 0.0, 0.0, 0.0

    def set_state(self, position: float, velocity: float, current_a: float) -> None:
        self.position, self.velocity, self.current_a = position, velocity, current_a

    def step(self, voltage_v: float, external_load: float, dt_s: float) -> None:
        """Advance dt_s (a whole number of substeps) at a constant voltage command."""
        drive, h, mass = self.drive, self.drive.substep_s, self.mass
        for _ in range(substeps_in(dt_s, h)):
            self.current_a, mean_a = drive.currents(
                self.current_a, voltage_v, self.velocity, self.bridge
            )
            plus, minus = drive.load_band(mean_a, self.velocity)
            free = mass * self.velocity + h * external_load
            self.velocity = stick_slip_velocity(free, h * plus, h * minus, mass)
            self.position += h * self.velocity
