"""The voltage clamp, checked against an independent worst case.

The check uses other code than the clamp: the emulator's own friction band
(drivers.motor.joint_load_band), J⁻ᵀ from rakectl.kinematics.tip_force and
the emulator's gravity loads (drivers.arm.gravity_joint_loads), over the
current interval that the velocity uncertainty allows.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arm import ArmParams, gravity_joint_loads
from rakectl import kinematics
from rakectl.clamp import VoltageClamp
from rakectl.motor_model import (
    R_MOTOR_DEFAULT,
    THETA_MOTOR_DEFAULT,
    MotorParams,
    joint_load_band,
    joint_per_motor_rad,
    joint_resolution,
)
from rakectl.settings import ClampSettings, GeometrySettings

DT_S = 1e-3
GEOMETRY = GeometrySettings()
CLAMP = ClampSettings()


def _currents(p: MotorParams, voltage_v: float, velocity: float, margin: float) -> list[float]:
    """Steady currents at the ends of the velocity interval, within the drive's limit."""
    out = []
    for vel in (velocity - margin, velocity + margin):
        motor_rad_per_s = vel / joint_per_motor_rad(p)
        i = (voltage_v - p.torque_constant_nm_per_a * motor_rad_per_s) / p.resistance_ohm
        out.append(max(-p.current_limit_a, min(p.current_limit_a, i)))
    return out


def _loads(p: MotorParams, voltage_v: float, velocity: float, margin: float) -> list[float]:
    """The extreme joint loads the motor can hold statically: both edges of the stick band
    (η when the motor drives the load, 1/η when the load back-drives it)."""
    loads = []
    for i in _currents(p, voltage_v, velocity, margin):
        loads += joint_load_band(p, i)
    return loads


def worst_down_force_n(clamp: ClampSettings, r_m: float, theta_rad: float, r_vel: float,
                       theta_vel: float, v_r: float, v_theta: float,
                       motor_r: MotorParams, motor_theta: MotorParams) -> float:
    arm = ArmParams(rake_mass_kg=clamp.rake_mass_kg, rake_length_m=clamp.rake_length_m,
                    gravity_m_per_s2=clamp.gravity_m_per_s2)
    hold_r, hold_theta = gravity_joint_loads(arm, r_m, theta_rad)  # what holds the arm up
    margin_r = (clamp.velocity_margin_counts * joint_resolution(motor_r) / DT_S
                + clamp.velocity_margin_share * abs(r_vel))
    margin_theta = (clamp.velocity_margin_counts * joint_resolution(motor_theta) / DT_S
                    + clamp.velocity_margin_share * abs(theta_vel))
    worst = -math.inf
    for load_r, load_theta in itertools.product(
        _loads(motor_r, v_r, r_vel, margin_r), _loads(motor_theta, v_theta, theta_vel, margin_theta)
    ):
        # the tip presses on the ground with J⁻ᵀ(Q + G), G = −hold
        _, f_height = kinematics.tip_force(r_m, theta_rad, load_r - hold_r, load_theta - hold_theta)
        worst = max(worst, -f_height)
    return worst


finite_voltage = st.floats(-1e6, 1e6)
any_voltage = st.one_of(finite_voltage, st.sampled_from([math.nan, math.inf, -math.inf]))
pose = st.tuples(st.floats(GEOMETRY.r_min_m, GEOMETRY.r_max_m),
                 st.floats(GEOMETRY.theta_min_rad, GEOMETRY.theta_max_rad))
velocity = st.tuples(st.floats(-0.5, 0.5), st.floats(-1.0, 1.0))


@st.composite
def motors(draw: st.DrawFn, base: MotorParams) -> MotorParams:
    return dataclasses.replace(
        base,
        resistance_ohm=draw(st.floats(0.05, 20.0)),
        torque_constant_nm_per_a=draw(st.floats(0.005, 0.5)),
        gear_efficiency=draw(st.floats(0.3, 1.0)),
        coulomb_friction_nm=draw(st.floats(0.0, 0.02)),
        current_limit_a=draw(st.floats(0.5, 50.0)),
        supply_voltage_v=draw(st.floats(6.0, 60.0)),
        gear_ratio=draw(st.floats(1.0, 500.0)) if base.lead_m_per_rev == 0 else base.gear_ratio,
    )


@settings(max_examples=400, deadline=None)
@given(pose, velocity, any_voltage, any_voltage, motors(R_MOTOR_DEFAULT),
       motors(THETA_MOTOR_DEFAULT), st.floats(10.0, 90.0))
def test_clamped_voltages_never_allow_more_than_the_limit(
    q: tuple[float, float], qd: tuple[float, float], v_r: float, v_theta: float,
    motor_r: MotorParams, motor_theta: MotorParams, limit_n: float
) -> None:
    clamp_settings = dataclasses.replace(CLAMP, force_limit_n=limit_n)
    clamp = VoltageClamp(clamp_settings, motor_r, motor_theta, DT_S)
    out_r, out_theta = clamp.apply(*q, *qd, v_r, v_theta)
    if not (math.isfinite(v_r) and math.isfinite(v_theta)):
        assert clamp.non_finite and (out_r, out_theta) == (0.0, 0.0)
        return
    assert math.isfinite(out_r) and math.isfinite(out_theta)
    assert abs(out_r) <= motor_r.supply_voltage_v and abs(out_theta) <= motor_theta.supply_voltage_v
    worst = worst_down_force_n(clamp_settings, *q, *qd, out_r, out_theta, motor_r, motor_theta)
    # the clamp's own worst case is a true bound (it ignores help from lifting loads)
    assert worst <= clamp.worst_case_n + 1e-6
    if not clamp.infeasible:
        assert worst <= clamp.limit_n * (1 + 1e-9) + 1e-9


@given(pose, velocity, st.floats(-24, 24), st.floats(-24, 24))
def test_requests_within_the_bound_pass_unchanged(q: tuple[float, float],
                                                  qd: tuple[float, float], v_r: float,
                                                  v_theta: float) -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    out = clamp.apply(*q, *qd, v_r, v_theta)
    if clamp.clamped == 0:
        assert out == (v_r, v_theta)
    else:  # a cut only ever moves a voltage away from the ground side
        assert clamp.worst_case_n <= CLAMP.force_limit_n * (1 - CLAMP.model_margin) + 1e-6


def test_lifting_is_never_restricted() -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    assert clamp.apply(1.0, 0.6, 0.0, 0.0, -24.0, -24.0) == (-24.0, -24.0)
    assert clamp.clamped == 0


def test_the_default_robot_is_feasible_everywhere_at_rest() -> None:
    """With the configured rake and motors the bound can be met in every pose at rest."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    for r_m in (GEOMETRY.r_min_m, 0.8, 1.2, GEOMETRY.r_max_m):
        for theta_rad in (GEOMETRY.theta_min_rad, 0.0, 0.6, GEOMETRY.theta_max_rad):
            clamp.apply(r_m, theta_rad, 0.0, 0.0, 24.0, 24.0)
    assert not clamp.infeasible


def test_pressing_at_full_voltage_is_cut() -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    v_r, v_theta = clamp.apply(1.0, 0.6, 0.0, 0.0, 24.0, 24.0)
    assert v_r < 24.0 and v_theta < 24.0
    assert clamp.clamped == 1
    assert clamp.worst_case_n <= 72.0 + 1e-9
