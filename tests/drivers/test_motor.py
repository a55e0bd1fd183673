"""Motor, drive and transmission model against its closed forms."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.motor import (
    R_MOTOR_DEFAULT,
    THETA_MOTOR_DEFAULT,
    Bridge,
    MotorDrive,
    MotorJoint,
    MotorParams,
    joint_load_band,
    joint_per_motor_rad,
    joint_resolution,
    no_load_joint_speed,
    stall_current_a,
    stall_joint_load,
    substeps_in,
)
from rakectl.errors import ConfigError

SUBSTEP_S = 1e-4
MOTORS = {"theta": THETA_MOTOR_DEFAULT, "r": R_MOTOR_DEFAULT}
motor_names = st.sampled_from(sorted(MOTORS))
volts = st.floats(0.5, 30.0).flatmap(lambda v: st.sampled_from([v, -v]))


def _run(joint: MotorJoint, voltage_v: float, load: float, seconds: float) -> None:
    for _ in range(round(seconds / 1e-3)):
        joint.step(voltage_v, load, 1e-3)


def _emf_damping_motor_side(p: MotorParams) -> float:
    """Torque per motor rad/s of a shorted motor plus its viscous friction."""
    return p.torque_constant_nm_per_a**2 / p.resistance_ohm + p.viscous_friction_nms_per_rad


# --------------------------------------------------------------------------- closed forms


def test_joint_per_motor_rad_rotary_and_screw() -> None:
    assert joint_per_motor_rad(THETA_MOTOR_DEFAULT) == pytest.approx(1 / 230)
    assert joint_per_motor_rad(R_MOTOR_DEFAULT) == pytest.approx(0.010 / (2 * math.pi))
    assert joint_resolution(R_MOTOR_DEFAULT) == pytest.approx(0.010 / 2000)


def test_default_motors_are_their_datasheet_class() -> None:
    theta, r = THETA_MOTOR_DEFAULT, R_MOTOR_DEFAULT
    # RE 40 24 V: ≈7600 rpm no-load at 24 V; RE 30 24 V: ≈8800 rpm.
    for p, rpm in ((theta, 7580), (r, 8810)):
        motor_rad_per_s = no_load_joint_speed(p, 24.0) / joint_per_motor_rad(p)
        assert motor_rad_per_s * 60 / (2 * math.pi) == pytest.approx(rpm, rel=0.03)
    assert stall_joint_load(theta, 24.0) == pytest.approx(46.8, rel=0.01)  # N·m at 10 A
    assert stall_joint_load(r, 24.0) == pytest.approx(86.7, rel=0.01)  # N at 6 A


def test_stall_current_saturates_at_supply_and_limit() -> None:
    p = THETA_MOTOR_DEFAULT
    assert stall_current_a(p, 1.0) == pytest.approx(1.0 / p.resistance_ohm)
    assert stall_current_a(p, 24.0) == p.current_limit_a
    assert stall_current_a(p, -100.0) == -p.current_limit_a
    assert no_load_joint_speed(p, 100.0) == no_load_joint_speed(p, 24.0)


# --------------------------------------------------------------------------- simulated


@settings(max_examples=12, deadline=None)
@given(name=motor_names, voltage_v=volts)
def test_no_load_speed_matches_closed_form(name: str, voltage_v: float) -> None:
    p = MOTORS[name]
    joint = MotorJoint(p, 0.0, SUBSTEP_S)  # free: only the reflected rotor
    _run(joint, voltage_v, 0.0, 0.6)
    assert joint.velocity == pytest.approx(no_load_joint_speed(p, voltage_v), rel=1e-6)


@settings(max_examples=12, deadline=None)
@given(name=motor_names, voltage_v=volts)
def test_locked_rotor_current_is_stall_current(name: str, voltage_v: float) -> None:
    p = MOTORS[name]
    joint = MotorJoint(p, 1e9, SUBSTEP_S)  # a locked load: practically infinite inertia
    _run(joint, voltage_v, 0.0, 0.02)
    assert joint.current_a == pytest.approx(stall_current_a(p, voltage_v), rel=1e-6)


@settings(max_examples=20, deadline=None)
@given(name=motor_names, voltage_v=volts)
def test_stall_load_is_where_the_motor_stops_pushing(name: str, voltage_v: float) -> None:
    """Against 98 % of the stall load the joint moves forward; against 102 % it stays put."""
    p = MOTORS[name]
    stall = stall_joint_load(p, voltage_v)
    for fraction, moves in ((0.98, True), (1.02, False)):
        joint = MotorJoint(p, 0.0, SUBSTEP_S)
        joint.set_state(0.0, 0.0, stall_current_a(p, voltage_v))
        _run(joint, voltage_v, -fraction * stall, 0.02)
        assert (joint.position * math.copysign(1.0, voltage_v) > 0.0) is moves
        if not moves:
            assert joint.position == 0.0 and joint.velocity == 0.0


def test_current_follows_exact_first_order_response() -> None:
    p = THETA_MOTOR_DEFAULT
    joint = MotorJoint(p, 1e12, SUBSTEP_S)
    tau_s = p.inductance_h / p.resistance_ohm
    for step in range(1, 6):
        joint.step(1.0, 0.0, SUBSTEP_S)
        exact_a = (1.0 / p.resistance_ohm) * (1.0 - math.exp(-step * SUBSTEP_S / tau_s))
        assert joint.current_a == pytest.approx(exact_a, rel=1e-9)


@settings(max_examples=30, deadline=None)
@given(
    name=motor_names,
    commands=st.lists(st.floats(-48.0, 48.0), min_size=1, max_size=20),
    velocity=st.floats(-1.0, 1.0),
)
def test_current_limiter_holds_the_limit(name: str, commands: list[float], velocity: float) -> None:
    """Holds while the back-EMF is within the supply (beyond it the motor regenerates)."""
    p = MOTORS[name]
    joint = MotorJoint(p, 0.5, SUBSTEP_S)
    joint.set_state(0.0, velocity * no_load_joint_speed(p, 24.0), 0.0)
    for voltage_v in commands:
        joint.step(voltage_v, 0.0, 1e-3)
        assert abs(joint.current_a) <= p.current_limit_a * (1 + 1e-9)


def test_efficiency_acts_in_the_direction_of_power_flow() -> None:
    """Steady speeds: motor driving a load (η on the output), load back-driving a shorted motor."""
    p = THETA_MOTOR_DEFAULT
    k, eta = joint_per_motor_rad(p), p.gear_efficiency
    kt, res, tc = p.torque_constant_nm_per_a, p.resistance_ohm, p.coulomb_friction_nm
    joint = MotorJoint(p, 0.0, SUBSTEP_S)
    _run(joint, 12.0, -10.0, 0.5)  # motor lifts 10 N·m
    driving = (kt * 12.0 / res - tc - 10.0 * k / eta) / _emf_damping_motor_side(p)
    assert joint.velocity / k == pytest.approx(driving, rel=1e-6)
    joint = MotorJoint(p, 0.0, SUBSTEP_S)
    _run(joint, 0.0, -20.0, 0.5)  # 20 N·m back-drives the shorted motor
    back = -(eta * k * 20.0 - tc) / _emf_damping_motor_side(p)
    assert joint.velocity / k == pytest.approx(back, rel=1e-6)


# --------------------------------------------------------------------------- friction


@settings(max_examples=40, deadline=None)
@given(name=motor_names, start=st.floats(-2.0, 2.0), fraction=st.floats(-0.98, 0.98))
def test_friction_holds_loads_inside_its_band_without_creep(
    name: str, start: float, fraction: float
) -> None:
    p = MOTORS[name]
    current_a = start  # in A; the voltage R·i keeps it there while the joint is at rest
    plus, minus = joint_load_band(p, current_a)
    load = -(plus + minus) / 2 + fraction * (minus - plus) / 2  # inside [−minus, −plus]
    joint = MotorJoint(p, 0.1, SUBSTEP_S)
    joint.set_state(0.0, 0.0, current_a)
    _run(joint, current_a * p.resistance_ohm, load, 0.2)
    assert joint.position == 0.0 and joint.velocity == 0.0


@settings(max_examples=40, deadline=None)
@given(name=motor_names, start=st.floats(-0.2, 0.2).filter(lambda v: abs(v) > 1e-4))
def test_friction_never_injects_energy_nor_reverses(name: str, start: float) -> None:
    p = MOTORS[name]
    joint = MotorJoint(p, 0.0, SUBSTEP_S)
    joint.bridge = Bridge.OPEN  # leads disconnected: only friction acts
    joint.set_state(0.0, start, 0.0)
    speed = abs(start)
    for _ in range(2000):
        joint.step(0.0, 0.0, 1e-3)
        assert joint.velocity * start >= 0.0
        assert abs(joint.velocity) <= speed
        speed = abs(joint.velocity)
    assert joint.velocity == 0.0


# --------------------------------------------------------------------------- validation


def test_parameters_out_of_bounds_are_rejected() -> None:
    with pytest.raises(ConfigError, match="gear_efficiency"):
        dataclasses.replace(THETA_MOTOR_DEFAULT, gear_efficiency=1.2)
    with pytest.raises(ConfigError, match="resistance_ohm"):
        MotorParams(resistance_ohm=math.nan)


def test_step_must_be_whole_substeps() -> None:
    assert substeps_in(1e-3, 1e-4) == 10
    with pytest.raises(ConfigError):
        substeps_in(1.5e-4, 1e-4)
    with pytest.raises(ConfigError):
        MotorJoint(THETA_MOTOR_DEFAULT, 0.0, SUBSTEP_S).step(0.0, 0.0, 0.0)


def test_encoder_counts_floor_to_the_count_below() -> None:
    drive = MotorDrive(R_MOTOR_DEFAULT, SUBSTEP_S)
    assert drive.counts(0.0) == 0
    assert drive.counts(4.9e-6) == 0
    assert drive.counts(-1e-9) == -1
    assert drive.counts(1.0 + 1e-9) == 200_000
