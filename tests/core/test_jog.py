"""Jogging: limits, dead-man, workspace edges."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rakectl.config.settings import JogSettings
from rakectl.core import kinematics
from rakectl.core.jog import LIMIT_MARGIN, Jog, JogFrame

WS = kinematics.Workspace(0.6, 0.35, 1.6, -0.2, 1.3)
DT = 1e-3
JOG = JogSettings()


def _jog(r: float = 1.0, theta: float = 0.5) -> Jog:
    return Jog(JOG, WS, DT, r, theta)


def test_dead_man_stops_the_motion_after_the_timeout() -> None:
    jog = _jog()
    jog.command(JogFrame.TASK, 0.05, 0.0)
    for _ in range(200):
        jog.step()
    assert jog.moving
    for _ in range(round(JOG.deadman_s / DT) + round(1 / JOG.accel_per_s / DT) + 10):
        jog.step()
    assert jog.expired and not jog.moving


def test_a_held_jog_stays_put_counts_its_dead_man_and_starts_again_from_rest() -> None:
    """Held (the force supervisor's caution), the reference stays where it is and the
    dead-man runs out in its own time; a jog held and released moves on from rest."""
    jog = _jog()
    jog.command(JogFrame.TASK, 0.05, 0.0)
    for _ in range(200):
        jog.step()
    held_at = jog.tip()
    for _ in range(50):
        jog.step(held=True)
    assert jog.tip() == held_at and not jog.moving and not jog.expired
    jog.step()
    assert 0.0 < jog.tip()[0] - held_at[0] <= (JOG.accel_per_s * JOG.max_tip_speed_m_per_s
                                              * DT * DT + 1e-12)
    for _ in range(round(JOG.deadman_s / DT)):
        jog.step(held=True)
    assert jog.expired
    jog.step()
    assert not jog.moving


def test_commands_repeated_in_time_keep_it_moving() -> None:
    jog = _jog()
    start = jog.tip()
    for _ in range(30):  # 3 s of commands every 100 ms
        jog.command(JogFrame.TASK, -0.05, 0.0)
        for _ in range(100):
            jog.step()
    assert jog.moving
    assert jog.tip()[0] == pytest.approx(start[0] - 0.05 * 3.0, abs=0.005)
    assert jog.tip()[1] == pytest.approx(start[1], abs=1e-6)


@settings(max_examples=50, deadline=None)
@given(st.sampled_from(list(JogFrame)), st.floats(-10, 10), st.floats(-10, 10))
def test_speed_and_acceleration_are_limited(space: JogFrame, a: float, b: float) -> None:
    jog = _jog()
    limit_a, limit_b = ((JOG.max_tip_speed_m_per_s,) * 2 if space is JogFrame.TASK
                        else (JOG.max_r_speed_m_per_s, JOG.max_theta_speed_rad_per_s))
    previous = (0.0, 0.0)
    for k in range(400):
        if k % 100 == 0:
            jog.command(space, a, b)
        before = jog.q if space is JogFrame.JOINT else jog.tip()
        jog.step()
        after = jog.q if space is JogFrame.JOINT else jog.tip()
        velocity = ((after[0] - before[0]) / DT, (after[1] - before[1]) / DT)
        if space is JogFrame.TASK:
            velocity = (velocity[0], -velocity[1])  # tip() gives depth; commands give height
        assert abs(velocity[0]) <= limit_a * 1.001 + 1e-9
        assert abs(velocity[1]) <= limit_b * 1.001 + 1e-9
        assert abs(velocity[0] - previous[0]) <= JOG.accel_per_s * limit_a * DT * 1.01 + 1e-6
        previous = velocity


def test_stops_short_of_the_workspace_edge() -> None:
    """At a joint limit is its end stop, where a drive faults on the hit: the reference
    stops LIMIT_MARGIN inside it."""
    jog = _jog(r=1.55, theta=0.5)
    for _ in range(50):
        jog.command(JogFrame.JOINT, 0.1, 0.0)
        for _ in range(100):
            jog.step()
    assert jog.q[0] == WS.r_max_m - LIMIT_MARGIN[0]
    assert not jog.moving
    assert math.isfinite(jog.q[1])


@pytest.mark.parametrize(("theta", "rate", "moves"), [(-0.19, -0.1, False), (-0.19, 0.1, True)])
def test_armed_inside_the_margin_it_only_jogs_back_out(theta: float, rate: float,
                                                       moves: bool) -> None:
    """Armed between the margin and the end stop: a jog further toward the stop is not
    taken, one back in is (never a jump to the margin's bound)."""
    jog = _jog(r=1.0, theta=theta)
    previous = jog.q[1]
    for _ in range(200):
        jog.command(JogFrame.JOINT, 0.0, rate)
        jog.step()
        assert abs(jog.q[1] - previous) <= 0.15 * DT * 1.001  # no jump
        previous = jog.q[1]
    assert (jog.q[1] > theta) if moves else (jog.q[1] == theta)


def test_contact_flag_follows_depth() -> None:
    jog = _jog(r=1.0, theta=0.3)  # tip above ground
    assert not jog.contact
    jog = _jog(r=1.0, theta=0.7)  # tip ~4 cm below ground
    assert jog.contact


def test_the_reference_waits_for_a_blocked_tip() -> None:
    """The tip stays where it is (something rigid): the reference runs ahead of it by
    ``max_lag_m`` and no further; once the tip follows, the reference moves on."""
    jog = _jog()
    blocked = jog.tip()
    for _ in range(10):  # 1 s at 0.1 m/s toward the robot
        jog.command(JogFrame.TASK, -0.1, 0.0)
        for _ in range(100):
            jog.observe(*blocked)
            jog.step()
    reach, depth = jog.tip()
    lag_m = math.hypot(reach - blocked[0], depth - blocked[1])
    assert JOG.max_lag_m - 0.1 * DT <= lag_m <= JOG.max_lag_m + 1e-9
    assert jog.waiting > 600
    jog.command(JogFrame.TASK, -0.1, 0.0)
    for _ in range(50):  # the tip catches up: the reference advances again
        jog.observe(*jog.tip())
        jog.step()
    assert jog.tip()[0] < reach - 0.004


def test_a_reference_behind_the_tip_may_always_move_back_toward_it() -> None:
    """A tip pushed far from the reference (lag over the limit): a step that brings the
    reference closer is taken."""
    jog = _jog()
    reach, depth = jog.tip()
    jog.command(JogFrame.TASK, -0.1, 0.0)
    for _ in range(300):
        jog.observe(reach - 0.1, depth)  # the tip is 0.1 m nearer the robot
        jog.step()
    assert jog.tip()[0] < reach - 0.015 and jog.waiting == 0
