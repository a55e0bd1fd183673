"""The tine-mount check on the emulated arm (the emulator is the judge): the press on an
anvil (a protruding stone: steel, 10⁷ N/m) reads the mount's stiffness through the motor
currents and encoders; the configured mount passes, a stiffer, blocked or softer one fails
naming both values, and a missing anvil fails saying so; the true force stays low."""

from __future__ import annotations

import dataclasses
import math

import pytest

from drivers.ground_params import BuriedObjects, StoneParams
from rakectl.config.settings import Settings, cross_checks
from rakectl.core.control import workspace_of
from rakectl.core.mount_check import MountCheck, MountResult, Phase
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import PlantKind, PlantSettings, Scenario

ANVIL_REACH_M, ANVIL_HEIGHT_M = 1.0, 0.03
START = (1.05, -0.06)  # reach, depth: 60 mm above the ground, beside the anvil


def _press(mount_n_per_m: float, anvil: bool = True, configured_height_m: float = ANVIL_HEIGHT_M,
           press_force_n: float = 10.0) -> tuple[MountCheck, float, list[Phase]]:
    """The check run on the emulated arm with this mount, the anvil's top configured at
    ``configured_height_m``; its true peak force down."""
    base = Scenario()
    stones = (StoneParams(reach_m=ANVIL_REACH_M, depth_m=-ANVIL_HEIGHT_M, width_m=0.06,
                          thickness_m=0.2),) if anvil else ()
    ground = dataclasses.replace(base.emulator.ground, objects=BuriedObjects(stones=stones))
    arm = dataclasses.replace(base.emulator.arm, tine_mount_stiffness_n_per_m=mount_n_per_m)
    selftest = dataclasses.replace(base.selftest, press=True, anvil_reach_m=ANVIL_REACH_M,
                                   anvil_height_m=configured_height_m,
                                   press_force_n=press_force_n)
    s = dataclasses.replace(base, plant=PlantSettings(kind=PlantKind.RAKE), selftest=selftest,
                            emulator=dataclasses.replace(base.emulator, arm=arm, ground=ground))
    loop = RakeLoop(s, *START)
    loop.reset()
    for _ in range(300):
        loop.step(*START, False)
    check = MountCheck(s.selftest, s.clamp, s.motors.r, s.motors.theta, workspace_of(s),
                       loop.dt_s, *START)
    phases = [check.phase]
    pivot_m = s.geometry.pivot_height_m
    while not check.done:
        m = loop.arm.measure()
        check.observe(m.r_m, m.theta_rad, m.r_vel_m_per_s, m.theta_vel_rad_per_s,
                      m.current_r_a, m.current_theta_a)
        check.step(m.r_m * math.cos(m.theta_rad), m.r_m * math.sin(m.theta_rad) - pivot_m)
        loop.step(check.reach_m, check.depth_m, False)
        if check.phase is not phases[-1]:
            phases.append(check.phase)
    return check, loop.ground.truth.max_force_down_n, phases


def _result(check: MountCheck) -> MountResult:
    assert check.result is not None
    return check.result


def test_the_configured_mount_passes_and_the_tip_comes_back() -> None:
    check, true_peak_n, phases = _press(5000.0)
    result = _result(check)
    assert result.passed, result.message
    assert result.stiffness_n_per_m == pytest.approx(5000.0, rel=0.15)
    assert not result.at_least and result.samples > 100
    assert phases == [Phase.RISE, Phase.ACROSS, Phase.DOWN, Phase.PRESS, Phase.HOLD,
                      Phase.UP, Phase.BACK, Phase.RETURN, Phase.LOWER, Phase.DONE]
    assert (check.reach_m, check.depth_m) == START
    assert 8.0 < true_peak_n < 20.0  # the press of 10 N, read through the currents
    assert "matches 5000 N/m configured (clamp.contact_stiffness_n_per_m" in result.message


@pytest.mark.parametrize(("mount_n_per_m", "stiffer"), [(6.5e3, True), (5.0e4, True),
                                                        (1.0e6, True), (2.0e3, False)])
def test_a_mount_of_another_stiffness_fails_naming_both(mount_n_per_m: float,
                                                        stiffer: bool) -> None:
    """1.3 times stiffer (the clamp takes the configured stiffness as the stiffest: the
    stiff side's tolerance is 0.2), ten times (springs swapped), 200 times (blocked: the
    encoders see at most a few counts of give, so the check names a lower bound) and 2.5
    times softer."""
    check, true_peak_n, _ = _press(mount_n_per_m)
    result = _result(check)
    assert not result.passed
    assert "does not match 5000 N/m configured" in result.message
    if stiffer:
        assert result.stiffness_n_per_m > 1.2 * 5000.0
        assert "stiffer than the clamp's bound assumes" in result.message
    else:
        assert result.stiffness_n_per_m == pytest.approx(mount_n_per_m, rel=0.2)
    assert true_peak_n < 20.0  # the press of 10 N, whatever the mount


def test_a_mount_somewhat_softer_passes() -> None:
    check, _, _ = _press(4.0e3)  # 0.8 times: inside the soft side's 0.5
    result = _result(check)
    assert result.passed, result.message
    assert result.stiffness_n_per_m == pytest.approx(4.0e3, rel=0.15)


def test_a_press_the_clamp_holds_short_is_no_verdict() -> None:
    """Asked for 15 N, the press is held near 13 N by the clamp's bound at this pose: the
    ticks of the stalled arm would read a mount twice as stiff as configured as matching
    (5176 N/m for 10 000 N/m), so a press short of its force gives no stiffness."""
    check, _, _ = _press(1.0e4, press_force_n=15.0)
    result = _result(check)
    assert not result.passed and math.isnan(result.stiffness_n_per_m)
    assert result.message.startswith("tine-mount check: the press was held at ")
    assert "of the 15 N asked for (selftest.press_force_n)" in result.message


@pytest.mark.parametrize("error_m", [-0.005, 0.005])
def test_an_anvil_known_within_5_mm_is_enough(error_m: float) -> None:
    check, _, _ = _press(5000.0, configured_height_m=ANVIL_HEIGHT_M + error_m)
    result = _result(check)
    assert result.passed, result.message
    assert result.stiffness_n_per_m == pytest.approx(5000.0, rel=0.15)


def test_a_press_too_short_to_weigh_the_mount_fails_saying_so() -> None:
    """A mount ten times softer than configured gives 5 N at the press's deepest (10 mm
    past the anvil's top): too little rise of the force to fit."""
    check, _, _ = _press(500.0)
    result = _result(check)
    assert not result.passed and math.isnan(result.stiffness_n_per_m)
    assert "too little to weigh the mount" in result.message
    assert "a mount much softer than 5000 N/m" in result.message


def test_no_anvil_where_configured_fails_saying_so() -> None:
    check, true_peak_n, _ = _press(5000.0, anvil=False)
    result = _result(check)
    assert not result.passed and math.isnan(result.stiffness_n_per_m)
    assert result.message.startswith("tine-mount check: the tines met nothing")
    assert "selftest.anvil_reach_m 1 m, anvil_height_m 0.03 m" in result.message
    assert true_peak_n == 0.0


def test_the_press_is_checked_against_the_clamp_and_the_workspace() -> None:
    s = Settings()
    ok = dataclasses.replace(s, selftest=dataclasses.replace(s.selftest, press=True))
    assert cross_checks(ok) == []
    hard = dataclasses.replace(ok, selftest=dataclasses.replace(ok.selftest, press_force_n=20.0),
                               clamp=dataclasses.replace(s.clamp, force_limit_n=36.0),
                               descent=dataclasses.replace(s.descent, min_step_m=1e-4))
    assert cross_checks(hard) == [("selftest.press_force_n", "must be <= half "
                                   "clamp.force_limit_n (18 N), got 20")]
    far = dataclasses.replace(ok, selftest=dataclasses.replace(ok.selftest, anvil_reach_m=2.5))
    [(key, message)] = cross_checks(far)
    assert key == "selftest.anvil_reach_m"
    assert message.startswith("the press on the anvil (selftest.anvil_reach_m, anvil_height_m) "
                              "leaves the workspace: tip (2.5000 m")
    bad_geometry = dataclasses.replace(far, geometry=dataclasses.replace(
        s.geometry, r_max_m=0.3))  # below r_min_m: named once, for the geometry
    assert [key for key, _ in cross_checks(bad_geometry)] == ["geometry.r_max_m"]
    off = dataclasses.replace(far, selftest=dataclasses.replace(far.selftest, press=False))
    assert cross_checks(off) == []


def test_a_way_to_the_anvil_outside_the_joints_limits_fails_before_moving() -> None:
    """From high above, the way across to an anvil near the pivot would need r < r_min: the
    check ends at once, naming the pose to arm from instead, and the tip never moves."""
    s = Settings()
    selftest = dataclasses.replace(s.selftest, press=True, anvil_reach_m=0.25)
    check = MountCheck(selftest, s.clamp, s.motors.r, s.motors.theta, workspace_of(s), 0.001,
                       0.98, -0.40)
    assert check.done
    result = _result(check)
    assert not result.passed
    assert result.message.startswith("tine-mount check: the way to the anvil from reach "
                                     "0.980 m, height 0.400 m leaves the workspace (across)")
    assert result.message.endswith("arm from another pose")
    check.step(0.98, -0.40)
    assert (check.reach_m, check.depth_m) == (0.98, -0.40)
