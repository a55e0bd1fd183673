"""The voltage clamp, checked against an independent worst case in every direction.

The checks use other code than the clamp: the emulator's own friction band
(rakectl.core.motor_model.joint_load_band), the Jacobian of rakectl.core.kinematics,
the emulator's joint masses and gravity loads (drivers.mechanics), numpy's linear algebra,
a dense set of 1440 contact directions around the circle (the clamp samples 72), and an RK4
simulation
of the two joints meeting a spring-damper (not the clamp's formula).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mechanics import ArmParams, gravity_joint_loads, joint_masses
from rakectl.config.settings import ClampSettings, GeometrySettings
from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.envelope import SAMPLING_MARGIN
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
DENSE = np.linspace(-math.pi, math.pi, 1440, endpoint=False)  # φ from straight down, 0.25°


def _arm(clamp: ClampSettings) -> ArmParams:
    return ArmParams(rake_mass_kg=clamp.rake_mass_kg, rake_length_m=clamp.rake_length_m,
                     gravity_m_per_s2=clamp.gravity_m_per_s2,
                     platform_inertia_kgm2=clamp.platform_inertia_kgm2,
                     counterweight_kg=clamp.counterweight_kg,
                     counterbalance_share=clamp.counterbalance_share)


def _loads(p: MotorParams, voltage_v: float, velocity: float, margin: float) -> list[float]:
    """The extreme joint loads the motor can exert at this voltage: steady currents at the
    ends of the velocity interval within the drive's limit, each at both edges of the stick
    band (η when the motor drives the load, 1/η when the load back-drives it)."""
    loads = []
    for vel in (velocity - margin, velocity + margin):
        motor_rad_per_s = vel / joint_per_motor_rad(p)
        i = (voltage_v - p.torque_constant_nm_per_a * motor_rad_per_s) / p.resistance_ohm
        loads += joint_load_band(p, max(-p.current_limit_a, min(p.current_limit_a, i)))
    return loads


@dataclasses.dataclass
class Independent:
    """The peak contact force in every dense direction, computed apart from the clamp."""

    clamp: ClampSettings
    motor_r: MotorParams
    motor_theta: MotorParams

    def peaks_n(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float,
                v_r: float, v_theta: float) -> np.ndarray:
        c = self.clamp
        arm = _arm(c)
        mass_r, inertia = joint_masses(arm, self.motor_r, self.motor_theta, r_m)
        m_inv = np.diag([1.0 / mass_r, 1.0 / inertia])
        jac = np.array(kinematics.jacobian(r_m, theta_rad)).reshape(2, 2)
        hold = np.array(gravity_joint_loads(arm, r_m, theta_rad))
        margin_r = (c.velocity_margin_counts * joint_resolution(self.motor_r) / DT_S
                    + c.velocity_margin_share * abs(r_vel))
        margin_theta = (c.velocity_margin_counts * joint_resolution(self.motor_theta) / DT_S
                        + c.velocity_margin_share * abs(theta_vel))
        corners = np.array(list(itertools.product(
            _loads(self.motor_r, v_r, r_vel, margin_r),
            _loads(self.motor_theta, v_theta, theta_vel, margin_theta)))) - hold  # Q + G
        u = np.stack([-np.sin(DENSE), -np.cos(DENSE)], axis=1)
        mobility = jac @ m_inv @ jac.T
        mass = 1.0 / np.einsum("ij,jk,ik->i", u, mobility, u)
        push = (mass[:, None] * (u @ jac @ m_inv @ corners.T)).max(axis=1)  # F_u, worst
        g = u @ jac  # Jᵀu per direction
        speed = g @ (r_vel, theta_vel) + np.abs(g) @ (margin_r, margin_theta)
        speed = np.maximum(speed, 0.0) + 0.5 * self.limit_n * c.reaction_latency_s / mass
        stiffness = 1.0 / (u[:, 0] ** 2 / c.side_contact_stiffness_n_per_m
                           + u[:, 1] ** 2 / c.contact_stiffness_n_per_m)
        tau = max(c.contact_damping_ns_per_m / c.contact_stiffness_n_per_m,
                  c.side_contact_damping_ns_per_m / c.side_contact_stiffness_n_per_m)
        return (push + np.sqrt(np.maximum(push, 0.0) ** 2 + stiffness * mass * speed ** 2)
                + tau * stiffness * speed)

    @property
    def limit_n(self) -> float:
        return self.clamp.force_limit_n * (1.0 - self.clamp.model_margin)


finite_voltage = st.floats(-1e6, 1e6)
any_voltage = st.one_of(finite_voltage, st.sampled_from([math.nan, math.inf, -math.inf]))
pose = st.tuples(st.floats(GEOMETRY.r_min_m, GEOMETRY.r_max_m),
                 st.floats(GEOMETRY.theta_min_rad, GEOMETRY.theta_max_rad))
velocity = st.tuples(st.floats(-0.3, 0.3), st.floats(-0.4, 0.4))


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


@settings(max_examples=300, deadline=None)
@given(pose, velocity, any_voltage, any_voltage, motors(R_MOTOR_DEFAULT),
       motors(THETA_MOTOR_DEFAULT), st.floats(10.0, 90.0), st.floats(5e2, 1e5),
       st.sampled_from([0.0, 2.0, 8.0]), st.floats(0.0, 1.2))
def test_clamped_voltages_keep_every_direction_under_the_limit(
    q: tuple[float, float], qd: tuple[float, float], v_r: float, v_theta: float,
    motor_r: MotorParams, motor_theta: MotorParams, limit_n: float, side_stiffness: float,
    counterweight_kg: float, share: float
) -> None:
    """Whatever is asked, the voltages returned cannot make a contact met in any of 1440
    directions peak above the limit (unless even the safest voltages cannot: saturated)."""
    settings_ = dataclasses.replace(CLAMP, force_limit_n=limit_n,
                                    side_contact_stiffness_n_per_m=side_stiffness,
                                    counterweight_kg=counterweight_kg,
                                    counterbalance_share=share)
    clamp = VoltageClamp(settings_, motor_r, motor_theta, DT_S)
    out_r, out_theta = clamp.apply(*q, *qd, v_r, v_theta)
    if not (math.isfinite(v_r) and math.isfinite(v_theta)):
        assert clamp.non_finite and (out_r, out_theta) == (0.0, 0.0)
        return
    assert math.isfinite(out_r) and math.isfinite(out_theta)
    assert abs(out_r) <= motor_r.supply_voltage_v and abs(out_theta) <= motor_theta.supply_voltage_v
    if clamp.saturated:
        return
    peaks = Independent(settings_, motor_r, motor_theta).peaks_n(*q, *qd, out_r, out_theta)
    assert peaks.max() <= clamp.limit_n * (1 + 1e-9) + 1e-9, (
        f"{peaks.max():.3f} N at φ = {math.degrees(DENSE[peaks.argmax()]):.1f}°")


@settings(max_examples=200, deadline=None)
@given(pose, velocity, st.floats(-24, 24), st.floats(-24, 24))
def test_requests_within_every_budget_pass_unchanged(q: tuple[float, float],
                                                     qd: tuple[float, float], v_r: float,
                                                     v_theta: float) -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    out = clamp.apply(*q, *qd, v_r, v_theta)
    if clamp.clamped == 0:
        assert out == (v_r, v_theta)
        peaks = Independent(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT).peaks_n(*q, *qd, *out)
        assert peaks.max() <= clamp.limit_n * (1 + 1e-9)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(pose, velocity), min_size=2, max_size=6), st.floats(-24, 24),
       st.floats(-24, 24))
def test_a_clamp_used_tick_after_tick_answers_as_a_fresh_one(
        ticks: list[tuple[tuple[float, float], tuple[float, float]]], v_r: float,
        v_theta: float) -> None:
    """Within a tick the envelope looks up the voltage pairs it has already judged: from
    one tick to the next (another pose or motion, the same request) nothing carries
    over, to the last bit."""
    kept = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    for q, qd in ticks:
        fresh = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
        assert kept.apply(*q, *qd, v_r, v_theta) == fresh.apply(*q, *qd, v_r, v_theta)
        assert (kept.worst_case_n, kept.worst_direction_rad) == (
            fresh.worst_case_n, fresh.worst_direction_rad)


def test_a_request_safe_in_every_direction_is_not_cut() -> None:
    """Holding the weight at rest (the anchor's own voltages) passes as asked."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    clamp.apply(1.0, 0.6, 0.0, 0.0, 0.0, 0.0)
    hold, excess = clamp._anchor(1.0, 0.6, 0.0, 0.0)
    assert excess <= 0.0
    assert clamp.apply(1.0, 0.6, 0.0, 0.0, *hold) == hold
    assert clamp.clamped == 0


def test_a_request_a_few_ulps_from_the_anchor_finds_no_kink_and_warns_nothing() -> None:
    """The segment's kinks divide by the voltage step: a subnormal step sends them to
    inf, outside (0, 1), silently (it once raised numpy's overflow warning)."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    zero = np.float64(0.0)  # numpy scalars, as a caller may pass them
    clamp.apply(1.0, 0.6, zero, zero, 0.0, 0.0)  # the envelope at this motion
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert clamp._kinks((zero, zero), (np.float64(5e-324), np.float64(-5e-324))) == []


def test_the_default_robot_is_feasible_everywhere_at_rest() -> None:
    """With the configured rake and motors the bounds can be met in every pose at rest."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    for r_m in (GEOMETRY.r_min_m, 0.8, 1.2, GEOMETRY.r_max_m):
        for theta_rad in (GEOMETRY.theta_min_rad, 0.0, 0.6, GEOMETRY.theta_max_rad):
            for request in ((24.0, 24.0), (-24.0, -24.0), (24.0, -24.0), (-24.0, 24.0)):
                clamp.apply(r_m, theta_rad, 0.0, 0.0, *request)
    assert not clamp.infeasible and clamp.saturated == 0


@pytest.mark.parametrize(("request_v", "side"), [((-24.0, 0.0), 1.0), ((24.0, 0.0), -1.0)])
# φ > 0 is toward the robot: retracting r at θ = 0 pulls the tip that way
def test_a_full_voltage_push_sideways_is_cut_to_the_budget(request_v: tuple[float, float],
                                                           side: float) -> None:
    """At θ = 0 the r joint pushes straight along the reach: 24 V would be ~97 N sideways."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    out = clamp.apply(1.0, 0.0, 0.0, 0.0, *request_v)
    assert abs(out[0]) < 2.0 and clamp.clamped == 1
    assert clamp.worst_case_n <= 0.5 * clamp.limit_n
    assert math.copysign(1.0, clamp.worst_direction_rad) == side  # toward where it pushes


def test_the_vertical_only_switch_lets_a_side_push_through() -> None:
    """``directions=1`` (tests only) bounds straight down alone: the 97 N side push passes."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S, directions=1)
    assert clamp.apply(1.0, 0.0, 0.0, 0.0, -24.0, 0.0)[0] == -24.0
    with pytest.raises(ValueError, match="multiple of 4"):
        VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S, directions=6)


def test_sampling_every_five_degrees_misses_at_most_the_margin() -> None:
    """Between the clamp's 72 sampled directions the peak bound's left side exceeds its
    largest sampled value by less than SAMPLING_MARGIN, over poses, pushes and speeds."""
    rng = np.random.default_rng(20261125)
    arm = _arm(CLAMP)
    sampled = np.linspace(-math.pi, math.pi, 72, endpoint=False)
    worst_ratio = 1.0
    for _ in range(3000):
        r_m = rng.uniform(GEOMETRY.r_min_m, GEOMETRY.r_max_m)
        theta_rad = rng.uniform(GEOMETRY.theta_min_rad, GEOMETRY.theta_max_rad)
        mass_r, inertia = joint_masses(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, r_m)
        jac = np.array(kinematics.jacobian(r_m, theta_rad)).reshape(2, 2)
        mobility = jac @ np.diag([1.0 / mass_r, 1.0 / inertia]) @ jac.T
        push = rng.uniform(0, 40) * np.array([math.cos(a := rng.uniform(0, 2 * math.pi)),
                                              math.sin(a)])
        vel = rng.uniform(0, 0.5) * np.array([math.cos(b := rng.uniform(0, 2 * math.pi)),
                                              math.sin(b)])

        def lhs(phis: np.ndarray, push: np.ndarray = push, vel: np.ndarray = vel,
                mobility: np.ndarray = mobility) -> float:
            u = np.stack([-np.sin(phis), -np.cos(phis)], axis=1)
            mass = 1.0 / np.einsum("ij,jk,ik->i", u, mobility, u)
            force = mass * (u @ (mobility @ push))
            k = 1.0 / (u[:, 0] ** 2 / CLAMP.side_contact_stiffness_n_per_m
                       + u[:, 1] ** 2 / CLAMP.contact_stiffness_n_per_m)
            speed = np.maximum(u @ vel, 0.0)
            return float((force + np.sqrt(force ** 2 + k * mass * speed ** 2)).max())

        at_samples = lhs(sampled)
        if at_samples > 1.0:
            worst_ratio = max(worst_ratio, lhs(DENSE) / at_samples)
    print(f"\nbetween the samples, up to {100 * (worst_ratio - 1):.2f} % over the sampled")
    assert worst_ratio < 1.0 + SAMPLING_MARGIN
    assert worst_ratio > 1.001  # the margin is needed: directions between samples do matter


def _impact_peak_n(r_m: float, theta_rad: float, phi: float, joint_vel: tuple[float, float],
                   loads: tuple[float, float], stiffness: float, damping: float) -> float:
    """The two joints (the emulator's masses, gravity in the loads) meet a spring-damper
    along u(φ) at the tip, linearized about the pose: RK4 at 2 µs until it rebounds."""
    arm = _arm(CLAMP)
    mass_r, inertia = joint_masses(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, r_m)
    jac = np.array(kinematics.jacobian(r_m, theta_rad)).reshape(2, 2)
    g = jac.T @ np.array([-math.sin(phi), -math.cos(phi)])  # compression rate = g · q̇
    m_inv = np.array([1.0 / mass_r, 1.0 / inertia])
    push = np.array(loads)

    def deriv(state: np.ndarray) -> np.ndarray:
        s, qd = state[0], state[1:]
        rate = g @ qd
        f = max(stiffness * s + damping * rate, 0.0)
        return np.concatenate([[rate], m_inv * (push - g * f)])

    h, state, peak = 2e-6, np.array([0.0, *joint_vel]), 0.0
    for _ in range(300_000):
        k1 = deriv(state)
        k2 = deriv(state + 0.5 * h * k1)
        k3 = deriv(state + 0.5 * h * k2)
        k4 = deriv(state + h * k3)
        state = state + h * (k1 + 2 * k2 + 2 * k3 + k4) / 6
        rate = g @ state[1:]
        peak = max(peak, stiffness * state[0] + damping * rate)
        if (rate < 0.0 and state[0] > 0.0) or state[0] < -1e-6:  # rebounding, or separated
            break
    return peak


@settings(max_examples=20, deadline=None)
@given(pose, st.floats(0.0, 0.3), st.floats(0.0, 2 * math.pi), st.integers(0, 71))
def test_an_allowed_push_meeting_a_contact_peaks_under_the_limit(
        q: tuple[float, float], speed: float, heading: float, sample: int) -> None:
    """Simulated, not from the formula: the joints pushed by the worst-case loads of the
    voltages the clamp allows, moving at any speed and heading, meet the configured mount
    along one of the sampled directions; the contact peaks under the limit."""
    exact = dataclasses.replace(CLAMP, velocity_margin_counts=0.0, velocity_margin_share=0.0,
                                reaction_latency_s=0.0)
    clamp = VoltageClamp(exact, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    r_m, theta_rad = q
    tip_vel = speed * np.array([math.cos(heading), math.sin(heading)])
    jac = np.array(kinematics.jacobian(r_m, theta_rad)).reshape(2, 2)
    joint_vel = tuple(np.linalg.solve(jac, tip_vel))
    out = clamp.apply(r_m, theta_rad, *joint_vel, 24.0 * math.cos(3 * heading),
                      24.0 * math.sin(5 * heading))
    if clamp.saturated:
        return
    phi = float(clamp.angles_rad[sample])
    k = 1.0 / (math.sin(phi) ** 2 / exact.side_contact_stiffness_n_per_m
               + math.cos(phi) ** 2 / exact.contact_stiffness_n_per_m)
    tau = exact.contact_damping_ns_per_m / exact.contact_stiffness_n_per_m
    jac_u = jac.T @ np.array([-math.sin(phi), -math.cos(phi)])
    if jac_u @ joint_vel < 0.0:  # moving away from it: judged again before it can come back
        return
    hold = np.array(gravity_joint_loads(_arm(exact), r_m, theta_rad))
    loads_r = _loads(R_MOTOR_DEFAULT, out[0], joint_vel[0], 0.0)
    loads_t = _loads(THETA_MOTOR_DEFAULT, out[1], joint_vel[1], 0.0)
    peaks = [_impact_peak_n(r_m, theta_rad, phi, joint_vel, (load_r - hold[0], load_t - hold[1]),
                            k, tau * k)
             for load_r, load_t in itertools.product((min(loads_r), max(loads_r)),
                                                     (min(loads_t), max(loads_t)))]
    assert max(peaks) <= clamp.limit_n * (1 + 1e-3)


def test_the_tip_mass_is_the_emulators() -> None:
    """The clamp's apparent mass against the emulator's own (other code)."""
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    arm = _arm(CLAMP)
    for r_m, theta_rad in itertools.product((0.9, 1.2, 1.5), (-0.2, 0.0, 0.3, 0.7)):
        mass_r, inertia = joint_masses(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, r_m)
        jac = np.array(kinematics.jacobian(r_m, theta_rad)).reshape(2, 2)
        mobility = jac @ np.diag([1.0 / mass_r, 1.0 / inertia]) @ jac.T
        for phi in (-1.2, -0.4, 0.0, 0.7, 1.5):
            u = np.array([-math.sin(phi), -math.cos(phi)])
            assert clamp.tip_mass_kg(r_m, theta_rad, phi) == pytest.approx(
                1.0 / (u @ mobility @ u), rel=1e-12)


def _along(clamp: VoltageClamp, phi: float) -> int:
    """The index of the sampled direction φ (0 straight down, 90° toward the robot)."""
    return int(np.argmin(np.abs(clamp.angles_rad - phi)))


def test_a_fast_descent_brakes_without_calling_it_infeasible() -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    at_rest = clamp.budgets_n(1.2, 0.2, 0.0, 0.0)
    assert 0.4 * clamp.limit_n < at_rest.min() and at_rest.max() < 0.5 * clamp.limit_n
    falling = 0.7 / (1.2 * math.cos(0.2))  # θ̇ of a 0.7 m/s descent (brakes from ~0.55)
    assert clamp.budgets_n(1.2, 0.2, 0.0, falling)[_along(clamp, 0.0)] < 0.0  # brake
    out = clamp.apply(1.2, 0.2, 0.0, falling, 0.0, 24.0)
    m = THETA_MOTOR_DEFAULT  # the θ motor's back-EMF at that speed
    emf_v = m.torque_constant_nm_per_a * falling / joint_per_motor_rad(m)
    assert out[1] < emf_v  # θ's current opposes the fall: it brakes
    assert not clamp.infeasible


def test_a_fast_side_motion_gets_a_smaller_side_budget() -> None:
    clamp = VoltageClamp(CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, DT_S)
    still = clamp.budgets_n(1.0, 0.0, 0.0, 0.0)
    toward_robot = clamp.budgets_n(1.0, 0.0, -0.3, 0.0)  # r retracting at θ = 0
    near, far = _along(clamp, 0.5 * math.pi), _along(clamp, -0.5 * math.pi)
    assert toward_robot[near] < still[near] - 5.0  # into whatever is on the robot's side
    assert toward_robot[far] == pytest.approx(still[far], abs=0.5)  # the far side: unchanged
