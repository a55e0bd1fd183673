"""The weight check: its verdict on currents made from the motor model (pure), and on the
emulated arm with and without its counterweight (the emulator is the judge)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest

from rakectl.config.service import SelfTestSettings
from rakectl.config.settings import ClampSettings, MotorsSettings
from rakectl.core.motor_model import MotorParams, joint_per_motor_rad
from rakectl.core.selftest import Phase, WeightCheck
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import PlantKind, PlantSettings, Scenario

CLAMP, MOTORS, SELFTEST = ClampSettings(), MotorsSettings(), SelfTestSettings()
DT_S = 0.001


def _current_for(motor: MotorParams, load: float, moving_up: bool) -> float:
    """The current whose band entry on the side the joint moves to is ``load`` (the
    inverse of joint_load_band, without viscous friction: the joint velocity given is 0)."""
    k = joint_per_motor_rad(motor)
    torque = load * k  # at the gear's output side, per motor radian
    eta, coulomb = motor.gear_efficiency, motor.coulomb_friction_nm
    if moving_up:  # ahead = (t − c)·η or /η
        gear = torque / eta if torque > 0.0 else torque * eta
        return (gear + coulomb) / motor.torque_constant_nm_per_a
    gear = torque * eta if torque > 0.0 else torque / eta
    return (gear - coulomb) / motor.torque_constant_nm_per_a


def _synthetic(weight_n: float, r_m: float = 1.1, theta_rad: float = 0.4) -> WeightCheck:
    """The check fed the currents that hold ``weight_n`` as the joints move up then down."""
    check = WeightCheck(SELFTEST, CLAMP, MOTORS.r, MOTORS.theta, DT_S, 1.1, 0.0)
    half_length_m = 0.5 * CLAMP.rake_length_m
    step_r, step_theta = 2e-5, 2e-5
    r, theta = r_m, theta_rad
    while not check.done:
        phase = check.phase
        direction = 1.0 if phase is Phase.UP else -1.0 if phase is Phase.DOWN else 0.0
        r, theta = r + direction * step_r, theta + direction * step_theta
        loads = (-weight_n * math.sin(theta),
                 -weight_n * (r - half_length_m) * math.cos(theta))
        currents = [_current_for(m, load, direction > 0.0)
                    for m, load in zip((MOTORS.r, MOTORS.theta), loads, strict=True)]
        check.observe(r, theta, 0.0, 0.0, currents[0], currents[1])
        check.step()
    return check


def test_the_configured_weight_passes_and_a_doubled_one_fails_naming_both() -> None:
    expected = (1.0 - CLAMP.counterbalance_share) * CLAMP.rake_mass_kg * CLAMP.gravity_m_per_s2
    passed = _synthetic(expected).result
    assert passed is not None and passed.passed
    assert passed.weight_n == pytest.approx(expected, rel=1e-9)
    failed = _synthetic(2.0 * expected).result
    assert failed is not None and not failed.passed
    assert f"{2 * expected:.1f} N measured does not match {expected:.1f} N" in failed.message
    assert "counterweight" in failed.message


def test_a_pose_without_lever_cannot_tell_the_weight() -> None:
    # r at half the rake's length and θ = 0: no gravity load on either joint
    result = _synthetic(20.0, r_m=0.5 * CLAMP.rake_length_m, theta_rad=0.0).result
    assert result is not None and not result.passed and "no lever" in result.message


def test_the_reference_lifts_holds_and_returns() -> None:
    check = WeightCheck(SELFTEST, CLAMP, MOTORS.r, MOTORS.theta, DT_S, 1.1, 0.01)
    depths = []
    while not check.done:
        check.step()
        depths.append(check.depth_m)
    assert min(depths) == pytest.approx(0.01 - SELFTEST.lift_m)
    assert depths[-1] == pytest.approx(0.01) and check.reach_m == 1.1
    steps = [abs(b - a) for a, b in itertools.pairwise(depths)]
    assert max(steps) == pytest.approx(SELFTEST.speed_m_per_s * DT_S, rel=0.01)


@pytest.mark.parametrize(("counterweight_kg", "passes"), [(8.0, True), (0.0, False)])
def test_on_the_emulated_arm_a_missing_counterweight_is_found(counterweight_kg: float,
                                                             passes: bool) -> None:
    """The clamp configured for the 8 kg counterweight; the emulated arm with it, or
    without it (then the motors hold the whole 39 N instead of 19.6 N, and the clamp's
    upward budget leaves nothing to lift it with: the check fails saying so)."""
    base = Scenario()
    arm = dataclasses.replace(base.emulator.arm, counterweight_kg=counterweight_kg)
    settings = dataclasses.replace(base, plant=PlantSettings(kind=PlantKind.RAKE),
                                   emulator=dataclasses.replace(base.emulator, arm=arm))
    loop = RakeLoop(settings, 1.1, -0.05)  # 50 mm above the ground
    loop.reset()
    for _ in range(300):
        loop.step(1.1, -0.05, False)
    check = WeightCheck(settings.selftest, settings.clamp, settings.motors.r,
                        settings.motors.theta, loop.dt_s, 1.1, -0.05)
    while not check.done:
        check.step()
        loop.step(check.reach_m, check.depth_m, False)
        m = loop.arm.measure()
        check.observe(m.r_m, m.theta_rad, m.r_vel_m_per_s, m.theta_vel_rad_per_s,
                      m.current_r_a, m.current_theta_a)
    result = check.result
    assert result is not None and result.passed is passes, result.message
    if passes:
        assert result.weight_n == pytest.approx(0.5 * arm.rake_mass_kg * 9.81, rel=0.05)
    else:  # 39 N to hold: the clamp's upward budget, set by the 19.6 N configured, is spent
        assert "did not follow the 20 mm lift" in result.message
        assert "counterweight" in result.message
