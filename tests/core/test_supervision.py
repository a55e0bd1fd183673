"""Force supervision: the current-based estimate and the caution/hard levels."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.mechanics import ArmParams, gravity_joint_loads
from rakectl.config.descent import DescentSettings
from rakectl.config.settings import ClampSettings, SupervisionSettings
from rakectl.core import kinematics
from rakectl.core.descent import drag_limit_n
from rakectl.core.motor_model import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, joint_per_motor_rad
from rakectl.core.supervision import ForceLevel, ForceSupervisor

CLAMP = ClampSettings()
SUP = SupervisionSettings()
ARM = ArmParams(rake_mass_kg=CLAMP.rake_mass_kg, rake_length_m=CLAMP.rake_length_m)


def _currents_for(r_m: float, theta_rad: float, down_n: float) -> tuple[float, float]:
    """Motor currents that hold the rake while it presses ``down_n`` on the ground:
    the emulator's gravity loads plus Jᵀ of the ground's reaction (independent path)."""
    hold_r, hold_theta = gravity_joint_loads(ARM, r_m, theta_rad)
    press_r, press_theta = kinematics.joint_loads(r_m, theta_rad, 0.0, -down_n)
    k_r, k_theta = joint_per_motor_rad(R_MOTOR_DEFAULT), joint_per_motor_rad(THETA_MOTOR_DEFAULT)
    return ((hold_r + press_r) * k_r / R_MOTOR_DEFAULT.torque_constant_nm_per_a,
            (hold_theta + press_theta) * k_theta / THETA_MOTOR_DEFAULT.torque_constant_nm_per_a)


@given(st.floats(0.4, 1.6), st.floats(0.05, 1.2), st.floats(0.0, 200.0))
def test_currents_that_press_a_known_force_read_back_as_that_force(
        r_m: float, theta_rad: float, down_n: float) -> None:
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    i_r, i_theta = _currents_for(r_m, theta_rad, down_n)
    assert sup.force_from_currents_n(r_m, theta_rad, i_r, i_theta) == pytest.approx(
        down_n, abs=1e-6)


def test_levels_follow_the_larger_estimate_after_the_filter() -> None:
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    i_r, i_theta = _currents_for(1.0, 0.6, 0.0)
    for _ in range(200):
        assert sup.step(0.0, 1.0, 0.6, i_r, i_theta) is ForceLevel.OK
    assert sup.step(SUP.caution_force_n + 1, 1.0, 0.6, i_r, i_theta) is ForceLevel.CAUTION
    i_r, i_theta = _currents_for(1.0, 0.6, SUP.hard_force_n + 5)
    levels = [sup.step(0.0, 1.0, 0.6, i_r, i_theta) for _ in range(300)]
    assert levels[0] is ForceLevel.OK  # the low-pass takes a few ticks
    assert levels[-1] is ForceLevel.HARD
    assert sup.f_max_n == pytest.approx(SUP.hard_force_n + 5, rel=0.01)


def test_a_brief_f_hat_spike_holds_the_motion_a_sustained_one_stops_it() -> None:
    """F̂ is a differentiated position: a tine dropping 0.6 mm into collapsed clay read
    78 N for ~10 ms while the ground felt 20 N. Its raw value sets CAUTION at once; the
    hard level takes it low-passed like the currents (supervision.current_filter_s)."""
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    i_r, i_theta = _currents_for(1.0, 0.6, 10.0)
    for _ in range(100):
        sup.step(0.0, 1.0, 0.6, i_r, i_theta)
    spike = [sup.step(100.0, 1.0, 0.6, i_r, i_theta) for _ in range(10)]
    assert set(spike) == {ForceLevel.CAUTION}
    for _ in range(200):
        sup.step(0.0, 1.0, 0.6, i_r, i_theta)
    sustained = [sup.step(100.0, 1.0, 0.6, i_r, i_theta) for _ in range(60)]
    assert sustained[0] is ForceLevel.CAUTION and sustained[-1] is ForceLevel.HARD
    # 100 N low-passed at 20 ms passes 75 N after 20 ms · ln 4 ≈ 28 ms
    assert sustained.index(ForceLevel.HARD) == pytest.approx(28, abs=2)


def test_non_finite_input_is_the_hard_level() -> None:
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    assert sup.step(math.nan, 1.0, 0.6, 0.0, 0.0) is ForceLevel.HARD
    assert sup.step(0.0, 1.0, 0.6, math.inf, 0.0) is ForceLevel.HARD


def _hand_currents(r_m: float, theta_rad: float, ground_reach_n: float,
                   ground_up_n: float) -> tuple[float, float]:
    """Motor currents that hold the rake still while the ground pushes its tip with
    (ground_reach_n toward the far end, ground_up_n upward), by hand.

    The tip is at p = (r cos θ, −r sin θ) from the pivot, so
    J = ∂p/∂(r, θ) = [[cos θ, −r sin θ], [−sin θ, −r cos θ]] and the push g loads the
    joints with Jᵀg = (g_x cos θ − g_z sin θ, −r (g_x sin θ + g_z cos θ)). The unbalanced
    weight W (the counterweight takes its share) acts at c = (r − L/2)(cos θ, −sin θ):
    J_cᵀ(0, −W) = (W sin θ, W (r − L/2) cos θ). At rest the motors supply the opposite of
    both; a joint load Q is the current Q·k/k_t of its motor (k: joint motion per motor
    radian)."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    weight_n = (1.0 - CLAMP.counterbalance_share) * CLAMP.rake_mass_kg * CLAMP.gravity_m_per_s2
    com_m = r_m - 0.5 * CLAMP.rake_length_m
    load_r_n = -(ground_reach_n * c - ground_up_n * s) - weight_n * s
    load_theta_nm = r_m * (ground_reach_n * s + ground_up_n * c) - weight_n * com_m * c
    return (load_r_n * joint_per_motor_rad(R_MOTOR_DEFAULT)
            / R_MOTOR_DEFAULT.torque_constant_nm_per_a,
            load_theta_nm * joint_per_motor_rad(THETA_MOTOR_DEFAULT)
            / THETA_MOTOR_DEFAULT.torque_constant_nm_per_a)


@given(st.floats(0.4, 1.6), st.floats(0.05, 1.2), st.floats(-80.0, 80.0), st.floats(0.0, 80.0))
def test_both_components_of_a_known_tip_force_follow_the_first_order_filter(
        r_m: float, theta_rad: float, ground_reach_n: float, ground_up_n: float) -> None:
    """From rest, a constant tip force reads x·(1 − exp(−t/τ)) on both estimates: the
    vertical one as the tip's push down, the reach one as the ground's push toward the far
    end (> 0: the drag of a stroke toward the robot)."""
    assert CLAMP.counterweight_kg > 0.0  # the hand computation counts the counterweight in
    dt_s = 1e-3
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, dt_s)
    i_r, i_theta = _hand_currents(r_m, theta_rad, ground_reach_n, ground_up_n)
    for tick in range(1, 301):
        sup.step(0.0, r_m, theta_rad, i_r, i_theta)
        if tick in (1, 20, 300):  # 300 ticks: settled (15 τ) to within 3e-7
            share = 1.0 - math.exp(-tick * dt_s / SUP.current_filter_s)
            assert sup.f_reach_current_n == pytest.approx(share * ground_reach_n, rel=1e-6,
                                                          abs=1e-9)
            assert sup.f_current_n == pytest.approx(share * ground_up_n, rel=1e-6, abs=1e-9)
    sup.reset()
    assert sup.f_reach_current_n == sup.f_current_n == 0.0


def test_a_non_finite_input_leaves_the_filtered_estimates_as_they_were() -> None:
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    i_r, i_theta = _hand_currents(1.2, 0.3, 15.0, 20.0)
    for _ in range(50):
        sup.step(0.0, 1.2, 0.3, i_r, i_theta)
    before = (sup.f_reach_current_n, sup.f_current_n)
    assert before[0] > 10.0 and before[1] > 10.0
    for bad in ((math.nan, 1.2, 0.3, i_r, i_theta), (0.0, math.nan, 0.3, i_r, i_theta),
                (0.0, 1.2, math.inf, i_r, i_theta), (0.0, 1.2, 0.3, -math.inf, i_theta),
                (0.0, 1.2, 0.3, i_r, math.nan)):
        assert sup.step(*bad) is ForceLevel.HARD
        assert (sup.f_reach_current_n, sup.f_current_n) == before
    sup.step(0.0, 1.2, 0.3, i_r, i_theta)
    assert before[0] < sup.f_reach_current_n < 15.0 and before[1] < sup.f_current_n < 20.0


@pytest.mark.parametrize(("ground_reach_n", "level"), [
    (19.0, ForceLevel.OK), (21.0, ForceLevel.HARD), (-21.0, ForceLevel.HARD),
    (-19.0, ForceLevel.OK)])
def test_a_drag_over_the_limit_either_way_is_the_hard_level(ground_reach_n: float,
                                                            level: ForceLevel) -> None:
    """With the descent limiter's drag limit (the budget 18 N plus 2 N), the settled drag
    read from the currents stops the motion past 20 N, toward the far end or the robot;
    without a limit nothing changes."""
    limit_n = drag_limit_n(dataclasses.replace(DescentSettings(), enforce=True), 90.0, 0.2)
    assert limit_n == pytest.approx(20.0)
    sup = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3, limit_n)
    free = ForceSupervisor(SUP, CLAMP, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1e-3)
    i_r, i_theta = _hand_currents(1.2, 0.3, ground_reach_n, 5.0)
    for _ in range(300):
        sup.step(0.0, 1.2, 0.3, i_r, i_theta)
        free.step(0.0, 1.2, 0.3, i_r, i_theta)
    assert sup.level is level
    assert free.level is ForceLevel.OK
    assert drag_limit_n(DescentSettings(), 90.0, 0.2) == math.inf
