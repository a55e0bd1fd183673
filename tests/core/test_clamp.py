"""The voltage clamp, checked against an independent worst case.

The check uses other code than the clamp: the emulator's own friction band
(drivers.motor.joint_load_band), J⁻ᵀ from rakectl.core.kinematics.tip_force and
the emulator's gravity loads (drivers.arm.gravity_joint_loads), over the
current interval that the velocity uncertainty allows.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arm import ArmParams, gravity_joint_loads, tip_apparent_masses_kg
from rakectl.config.settings import ClampSettings, GeometrySettings
from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.motor_model import (
    R_MOTOR_DEFAULT,
    THETA_MOTOR_DEFAULT,
    MotorParams,
    joint_load_band,
    joint_per_motor_rad,
    joint_resolution,
)

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
    # the clamp's own worst case is a true bound
    assert worst <= clamp.worst_case_n + 1e-6
    # the budget never allows more than half the limit: a suddenly met contact doubles it
    assert clamp.budget_n <= 0.5 * clamp.limit_n * (1 + 1e-12)
    if clamp.saturated == 0:
        assert worst <= clamp.budget_n + 1e-9 * clamp.limit_n + 1e-9
    else:  # even full lift cannot meet the budget: as good as both motors at full lift
        full_r = -math.copysign(motor_r.supply_voltage_v, math.sin(q[1]) or 1.0)
        full = worst_down_force_n(clamp_settings, *q, *qd, full_r, -motor_theta.supply_voltage_v,
                                  motor_r, motor_theta)
        assert worst <= full + 1e-6 * max(1.0, abs(full))


@given(pose, velocity, st.floats(-24, 24), st.floats(-24, 24))
def test_requests_within_the_bound_pass_unchanged(q: tuple[float, float],
                                                  qd: tuple[float, float], v_r: float,
                                                  v_theta: float) -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    out = clamp.apply(*q, *qd, v_r, v_theta)
    if clamp.clamped == 0:
        assert out == (v_r, v_theta)
    else:  # a cut only ever moves a voltage away from the ground side
        assert clamp.worst_case_n <= clamp.budget_n + 1e-6 or clamp.saturated


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


def _contact_peak_n(mass_kg: float, stiffness: float, damping: float, speed_m_per_s: float,
                    push_n: float) -> float:
    """Peak force of a mass arriving at ``speed_m_per_s`` on a spring-damper, pushed by a
    constant ``push_n``: integrated (RK4, 2 µs) until it rebounds off the contact."""
    h, x, v, peak = 2e-6, 0.0, speed_m_per_s, 0.0

    def accel(x: float, v: float) -> float:
        return (push_n - max(stiffness * x + damping * v, 0.0)) / mass_kg

    for _ in range(2_000_000):
        k1x, k1v = v, accel(x, v)
        k2x, k2v = v + 0.5 * h * k1v, accel(x + 0.5 * h * k1x, v + 0.5 * h * k1v)
        k3x, k3v = v + 0.5 * h * k2v, accel(x + 0.5 * h * k2x, v + 0.5 * h * k2v)
        k4x, k4v = v + h * k3v, accel(x + h * k3x, v + h * k3v)
        x += h * (k1x + 2 * k2x + 2 * k3x + k4x) / 6
        v += h * (k1v + 2 * k2v + 2 * k3v + k4v) / 6
        peak = max(peak, stiffness * x + damping * v)
        if v < 0.0 and x > 0.0 and stiffness * x < push_n:  # past the peak, rebounding
            break
    return peak


@settings(max_examples=25, deadline=None)
@given(pose, st.floats(0.0, 0.5), st.floats(1e3, 1e6), st.floats(0.0, 500.0))
def test_the_dynamic_budget_bounds_the_impact_peak(q: tuple[float, float], speed: float,
                                                   stiffness: float, damping: float) -> None:
    """Pushing with the budget the clamp allows at a measured downward speed, the tip that
    meets the stiffest contact configured at that speed peaks below the limit (simulated
    here, not from the clamp's formula); with no margins the bound is nearly reached."""
    exact = dataclasses.replace(CLAMP, contact_stiffness_n_per_m=stiffness,
                                contact_damping_ns_per_m=damping, velocity_margin_counts=0.0,
                                velocity_margin_share=0.0, reaction_latency_s=0.0)
    clamp = VoltageClamp(exact, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    r_m, theta_rad = q
    mass_kg = clamp.tip_mass_kg(r_m, theta_rad)
    # a measured joint motion whose downward tip speed is ``speed``
    theta_vel = speed / (r_m * math.cos(theta_rad))
    budget_n = clamp.dynamic_budget_n(r_m, theta_rad, 0.0, theta_vel)
    if budget_n < 0.0:  # must brake: nothing to push with
        assert math.sqrt(stiffness * mass_kg) * speed + damping * speed > 0.5 * clamp.limit_n
        return
    peak_n = _contact_peak_n(mass_kg, stiffness, damping, speed, budget_n)
    assert peak_n <= clamp.limit_n * (1 + 1e-3)
    if damping == 0.0:
        assert peak_n >= clamp.limit_n * 0.99


def test_the_tip_mass_is_the_emulators() -> None:
    """The clamp's apparent mass against the emulator's own (other code)."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    arm = ArmParams(rake_mass_kg=CLAMP.rake_mass_kg, rake_length_m=CLAMP.rake_length_m,
                    platform_inertia_kgm2=CLAMP.platform_inertia_kgm2)
    for r_m, theta_rad in itertools.product((0.9, 1.2, 1.5), (-0.2, 0.0, 0.3, 0.7)):
        expected = tip_apparent_masses_kg(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, r_m,
                                          theta_rad)[1]
        assert clamp.tip_mass_kg(r_m, theta_rad) == pytest.approx(expected, rel=1e-12)


def test_a_fast_descent_gets_a_braking_budget() -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    at_rest = clamp.dynamic_budget_n(1.2, 0.2, 0.0, 0.0)
    assert 0.3 * clamp.limit_n < at_rest < 0.5 * clamp.limit_n
    falling = clamp.dynamic_budget_n(1.2, 0.2, 0.0, 0.3 / (1.2 * math.cos(0.2)))
    assert falling < 0.0
    out = clamp.apply(1.2, 0.2, 0.0, 0.3 / (1.2 * math.cos(0.2)), 0.0, 0.0)
    assert out[1] < 0.0  # θ lifts: it brakes the fall
    assert not clamp.infeasible
