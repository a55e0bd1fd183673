"""Force supervision: the current-based estimate and the caution/hard levels."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.mechanics import ArmParams, gravity_joint_loads
from rakectl.config.settings import ClampSettings, SupervisionSettings
from rakectl.core import kinematics
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
