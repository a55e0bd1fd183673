"""The lane planner of paper Fig. 3: phases, depths, contact flags, speed limits."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rakectl.config.settings import LaneSettings
from rakectl.core.cut_profile import RISE_PER_M, CutProfile
from rakectl.core.lane import (
    LANDING_BAND_M,
    PLUNGE_MARGIN_M,
    SETTLE_ERROR_M,
    SETTLE_TIMEOUT_S,
    LanePhase,
    LanePlanner,
)

LANE = LaneSettings(reach_far_m=1.2, reach_near_m=0.9, depth_step_m=0.02, target_depth_m=0.05,
                    clearance_m=0.03, stroke_speed_m_per_s=0.1, plunge_speed_m_per_s=0.01,
                    travel_speed_m_per_s=0.3, accel_m_per_s2=1.0)


Row = tuple[LanePhase, int, float, float, float]


def _run(lane: LaneSettings, dt_s: float = 1e-3, limit: int = 10**6) -> list[Row]:
    planner = LanePlanner(lane, dt_s, lane.reach_near_m, -lane.clearance_m)
    trace = []
    for _ in range(limit):
        trace.append((planner.phase, planner.cycle, planner.reach_m, planner.depth_m,
                      planner.cycle_depth_m))
        if planner.done:
            return trace
        planner.step()
    raise AssertionError("planner never finished")


def test_cycles_deepen_by_the_step_until_the_target() -> None:
    trace = _run(LANE)
    stroke_depths = sorted({round(depth, 9) for phase, _, _, depth, _ in trace
                            if phase is LanePhase.STROKE})
    assert stroke_depths[-3:] == [0.02, 0.04, 0.05]
    assert max(cycle for _, cycle, *_ in trace) == 3
    assert trace[-1][0] is LanePhase.DONE
    assert trace[-1][3] == pytest.approx(-LANE.clearance_m)


def test_strokes_drag_toward_the_robot_and_only_plunge_and_stroke_are_contact() -> None:
    planner = LanePlanner(LANE, 1e-3, LANE.reach_far_m, -LANE.clearance_m)
    previous_reach = planner.reach_m
    while not planner.done:
        if planner.phase is LanePhase.STROKE:
            assert planner.reach_m <= previous_reach + 1e-12
            assert planner.contact
        elif planner.phase in (LanePhase.APPROACH, LanePhase.LOWER, LanePhase.LIFT):
            assert not planner.contact
            if planner.phase is not LanePhase.LIFT:
                # free space stays above the last completed floor
                assert planner.depth_m <= planner.floor_m
        previous_reach = planner.reach_m
        planner.step()


@settings(max_examples=25, deadline=None)
@given(stroke=st.floats(0.01, 0.5), travel=st.floats(0.05, 1.0), accel=st.floats(0.2, 5.0))
def test_reference_respects_speed_and_acceleration_limits(stroke: float, travel: float,
                                                          accel: float) -> None:
    lane = LaneSettings(reach_far_m=1.2, reach_near_m=1.0, depth_step_m=0.03,
                        target_depth_m=0.03, stroke_speed_m_per_s=stroke,
                        travel_speed_m_per_s=travel, accel_m_per_s2=accel)
    dt = 1e-3
    trace = _run(lane, dt)
    speeds = [math.hypot(b[2] - a[2], b[3] - a[3]) / dt for a, b in itertools.pairwise(trace)]
    top = max(travel, stroke, lane.plunge_speed_m_per_s)
    assert max(speeds) <= top + accel * dt + 1e-9
    for (a, b), v0, v1 in zip(itertools.pairwise(trace), speeds, speeds[1:], strict=False):
        if a[0] is b[0]:  # within a phase the speed changes by at most a·dt per tick
            assert abs(v1 - v0) <= 2 * accel * dt + 1e-9


def _ticks_to_plunge(planner: LanePlanner, tip_of: Callable[[int, float], float] | None) -> int:
    """Ticks until PLUNGE; ``tip_of(tick, reference depth)`` is the measured tip (None: the
    planner is not told where the tip is)."""
    for k in range(100_000):
        if planner.phase is LanePhase.PLUNGE:
            return k
        if tip_of is not None:
            planner.observe(planner.reach_m, tip_of(k, planner.depth_m))
        planner.step()
    raise AssertionError("no plunge")


def test_a_plunge_waits_until_the_tip_has_arrived_above_the_soil() -> None:
    """The estimator is re-anchored where contact begins: a tip still moving down there
    would read as force. LOWER ends once the measured tip has stopped."""
    blind = _ticks_to_plunge(LanePlanner(LANE, 1e-3, 1.2, -0.03), None)
    lagging = [-0.03]

    def first_order(k: int, reference_m: float) -> float:  # 30 ms behind its reference
        lagging[0] += (reference_m - lagging[0]) * 1e-3 / 0.03
        return lagging[0]

    waited = _ticks_to_plunge(LanePlanner(LANE, 1e-3, 1.2, -0.03), first_order)
    assert waited > blind + 50  # the tip needs a few time constants to settle
    assert waited < blind + SETTLE_TIMEOUT_S * 1e3


def test_feedback_that_stops_coming_is_not_a_tip_that_has_settled() -> None:
    """The drives' answers stop for 15 ticks (a loaded bus or emulator) while the tip still
    descends toward the landing, then arrive together: the plunge waits for the tip as if
    every answer had come on time, never starts during the silence."""
    def plunge_tick(stall_from: int | None) -> tuple[int, float]:
        planner, tip, read = LanePlanner(LANE, 1e-3, 1.2, -0.03), [-0.03], [-0.03]
        pending = 0
        for k in range(100_000):
            if planner.phase is LanePhase.PLUNGE:
                return k, tip[0] - read[0]
            tip[0] += (planner.depth_m - tip[0]) * 1e-3 / 0.03  # 30 ms behind
            pending += 1
            stalled = stall_from is not None and stall_from <= k < stall_from + 15
            samples, pending = (0, pending) if stalled else (pending, 0)
            if samples:
                read[0] = tip[0]
            planner.observe(planner.reach_m, read[0], samples)
            planner.step()
        raise AssertionError("no plunge")

    on_time, _ = plunge_tick(None)
    for stall_from in range(on_time - 120, on_time + 1, 5):
        k, unseen_m = plunge_tick(stall_from)
        assert k >= on_time - 1, stall_from
        assert abs(unseen_m) < 1e-9  # a plunge never starts on a stale reading


def test_a_tip_at_the_turning_point_of_an_overshoot_has_not_settled() -> None:
    """An arm that overshoots the landing stands still at its turning point for longer
    than the settle window, then swings back: the plunge (contact, F̂ re-anchored) waits
    until it is still near its reference, so it does not enter contact at swing speed."""
    omega, zeta = 2 * math.pi * 2.0, 0.3  # 2 Hz, underdamped: overshoots by a third
    planner, tip, vel = LanePlanner(LANE, 1e-3, 1.2, -0.03), [-0.03], [0.0]
    speeds = []
    for _ in range(100_000):
        if planner.phase is LanePhase.PLUNGE:
            break
        acc = -omega**2 * (tip[0] - planner.depth_m) - 2 * zeta * omega * vel[0]
        vel[0] += acc * 1e-3
        tip[0] += vel[0] * 1e-3
        speeds.append(abs(vel[0]))
        planner.observe(planner.reach_m, tip[0])
        planner.step()
    assert planner.phase is LanePhase.PLUNGE
    assert abs(tip[0] - planner.depth_m) <= SETTLE_ERROR_M
    assert max(speeds[-10:]) < 0.0075  # the swing has died down: F̂ ≲ 15 N at entry


def test_a_tip_that_never_settles_delays_the_plunge_by_the_timeout_only() -> None:
    blind = _ticks_to_plunge(LanePlanner(LANE, 1e-3, 1.2, -0.03), None)

    def trembling(k: int, reference_m: float) -> float:
        return reference_m + 1e-3 * (k % 2)

    waited = _ticks_to_plunge(LanePlanner(LANE, 1e-3, 1.2, -0.03), trembling)
    assert waited == pytest.approx(blind + SETTLE_TIMEOUT_S * 1e3, abs=2)


def _second_descent_end(ride_up_m: float, riding: Callable[[float], bool]) -> float:
    """Where the second cycle's free-space descent ends, after a first stroke whose tip rode
    ``ride_up_m`` above its reference wherever ``riding(reference reach)``."""
    planner = LanePlanner(LANE, 1e-3, LANE.reach_far_m, -LANE.clearance_m)
    depth_before = planner.depth_m
    while not (planner.cycle == 2 and planner.phase is LanePhase.PLUNGE):
        lift = ride_up_m if planner.phase is LanePhase.STROKE and riding(planner.reach_m) else 0
        planner.observe(planner.reach_m, planner.depth_m - lift)
        depth_before = planner.depth_m
        planner.step()
    return depth_before


def test_the_next_descent_stops_above_the_soil_the_last_stroke_left_at_its_start() -> None:
    floor, far = LANE.depth_step_m, LANE.reach_far_m
    # a tip on its reference: the descent ends just above the last stroke's depth
    assert _second_descent_end(0.0, lambda _: False) == pytest.approx(floor - PLUNGE_MARGIN_M)
    # a tip dragged up 8 mm as the stroke began left soil there: stop above that
    assert _second_descent_end(0.008, lambda reach: reach > far - 0.01) == pytest.approx(
        floor - 0.008 - PLUNGE_MARGIN_M)
    # a tip that rode up only further along is not where the next descent lands
    assert _second_descent_end(0.008, lambda reach: reach < far - 2 * LANDING_BAND_M) == (
        pytest.approx(floor - PLUNGE_MARGIN_M))


# --------------------------------------------------------------------------- the cut profile

ADAPTIVE = LaneSettings(reach_far_m=1.4, reach_near_m=0.4, depth_step_m=0.01,
                        target_depth_m=0.1, max_depth_step_m=0.04, adaptive=True)
FORCE_TARGET_N, LAG_TARGET_M = 44.0, 0.01


def _stroke(profile: CutProfile, force_of: Callable[[float], float],
            ride_of: Callable[[float], float] = lambda reach: 0.0) -> None:
    """One stroke from the profile's start to the near end, 1 mm per tick: the force
    estimate ``force_of(reach)``, the tip ``ride_of(reach)`` above its reference."""
    reach = profile.start_reach_m
    while reach >= profile.near_m:
        ride = ride_of(reach)
        profile.record(reach, profile.depth_and_slope_at(reach)[0] - ride, ride)
        profile.record_force(reach, force_of(reach))
        reach -= 0.001
    profile.finish(FORCE_TARGET_N, LAG_TARGET_M)


def _shape_holds(profile: CutProfile) -> None:
    plan, done, rise = profile.plan_m, profile.done_m, RISE_PER_M * profile.width_m
    for near, far in itertools.pairwise(range(profile.n_bins)):
        assert plan[near] <= plan[far] + 1e-12  # never descending toward the robot
        assert plan[far] - plan[near] <= rise + 1e-12
    target, step = ADAPTIVE.target_depth_m, ADAPTIVE.depth_step_m
    for b in range(profile.start + 1):  # every bin not yet done makes progress
        assert plan[b] >= min(target, done[b] + step) - 1e-12
    assert max(plan) <= target + 1e-12


def test_a_lane_goes_deeper_where_the_load_is_light_and_strokes_start_where_it_is_not_done(
        ) -> None:
    profile = CutProfile(ADAPTIVE)
    heavy_near = 0.7

    def force(reach: float) -> float:  # over the set point near the robot, light beyond
        return 60.0 if reach < heavy_near else 10.0

    strokes = 0
    while not profile.complete:
        assert profile.start_reach_m == pytest.approx(  # the far edge of the first bin not done
            profile.near_m + (profile.start + 1) * profile.width_m)
        _stroke(profile, force)
        _shape_holds(profile)
        strokes += 1
        if strokes == 2:
            far, near = profile.plan_m[-1], profile.plan_m[0]
            assert far > near + 0.02  # far: doubled twice from 10 mm; near: one step a cycle
            assert near == pytest.approx(0.03)
    assert strokes == 10  # the near end, one depth step a stroke, sets the count
    assert profile.done_m == pytest.approx([ADAPTIVE.target_depth_m] * profile.n_bins)


def test_partial_strokes_begin_once_the_far_part_is_done() -> None:
    profile = CutProfile(ADAPTIVE)
    starts = []
    while not profile.complete:
        starts.append(profile.start_reach_m)
        _stroke(profile, lambda reach: 60.0 if reach < 0.7 else 10.0)
    assert starts[0] == pytest.approx(ADAPTIVE.reach_far_m)
    # the last strokes rake only the heavy part near the robot and the rise out of it
    assert starts[-1] < 0.9
    assert starts == sorted(starts, reverse=True)


def test_a_bins_next_cut_counts_from_where_the_tip_really_was() -> None:
    """A tip that rode 8 mm up near the robot left soil there: the next cut's depth there
    counts from that floor (not from the reference), within one depth step of it."""
    flat = CutProfile(ADAPTIVE)
    rode = CutProfile(ADAPTIVE)
    _stroke(flat, lambda reach: 44.0)  # at the set point: the same cut again
    _stroke(rode, lambda reach: 44.0, lambda reach: 0.008 if reach < 0.6 else 0.0)
    assert flat.plan_m[0] == pytest.approx(0.02)
    assert rode.plan_m[0] == pytest.approx(0.02)  # at least one step below what was done
    assert rode.left_m[0] == pytest.approx(0.002)
    assert rode.plan_m[-1] == pytest.approx(0.02)


def test_a_sliver_short_of_the_target_is_cut_with_the_last_stroke() -> None:
    lane = dataclasses.replace(ADAPTIVE, target_depth_m=0.037, max_depth_step_m=0.04)
    profile = CutProfile(lane)
    _stroke(profile, lambda reach: 22.0)  # half the set point: twice as deep, 20 mm
    assert profile.plan_m[0] == pytest.approx(0.03)  # 7 mm short: a cycle of its own
    lane = dataclasses.replace(lane, target_depth_m=0.033)
    profile = CutProfile(lane)
    _stroke(profile, lambda reach: 22.0)
    assert profile.plan_m[0] == pytest.approx(0.033)  # 3 mm short: cut with this one


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 200.0), st.floats(0.0, 0.03), st.floats(0.4, 1.4)),
                min_size=1, max_size=6))
def test_the_profile_keeps_its_shape_and_progress_whatever_the_strokes_meet(
        loads: list[tuple[float, float, float]]) -> None:
    """Forces and ride-ups that change along the lane and from stroke to stroke: the plan
    never descends toward the robot, rises within its limit, and every stroke deepens
    every bin not done by a step, so the lane is done in target/step strokes at most, and
    one more where the tine rode up on the stroke at the target."""
    profile = CutProfile(ADAPTIVE)
    for k in range(11):
        force_n, ride_m, where = loads[k % len(loads)]

        def force(reach: float, f: float = force_n, w: float = where) -> float:
            return f if reach < w else 0.5 * f

        def ride(reach: float, r: float = ride_m, w: float = where) -> float:
            return r if reach < w else 0.0

        _stroke(profile, force, ride)
        _shape_holds(profile)
        if profile.complete:
            break
    assert profile.complete


def test_a_bin_the_tine_rode_up_in_at_the_target_gets_one_more_stroke() -> None:
    lane = dataclasses.replace(ADAPTIVE, target_depth_m=0.02)
    for ride_m, strokes in ((0.002, 2), (0.004, 3)):  # within the tolerance, or beyond it
        profile = CutProfile(lane)
        done = 0
        def ride(reach: float, r: float = ride_m) -> float:
            return r if 0.6 < reach < 0.65 else 0.0

        while not profile.complete:
            _stroke(profile, lambda reach: 44.0, ride)
            done += 1
            assert done <= strokes
            if not profile.complete:
                assert profile.depth_reached_m < lane.target_depth_m
        assert done == strokes
        assert profile.depth_reached_m == pytest.approx(lane.target_depth_m)


def test_a_partial_stroke_approaches_lowers_and_plunges_at_its_start() -> None:
    lane = dataclasses.replace(ADAPTIVE, reach_far_m=1.0, reach_near_m=0.6,
                               target_depth_m=0.03, travel_speed_m_per_s=0.5,
                               accel_m_per_s2=2.0, plunge_speed_m_per_s=0.05,
                               max_plunge_speed_m_per_s=0.05)
    planner = LanePlanner(lane, 1e-3, lane.reach_far_m, -lane.clearance_m)
    plunges: dict[int, float] = {}
    while not planner.done:
        planner.observe(planner.reach_m, planner.depth_m)
        heavy = planner.phase is LanePhase.STROKE and planner.reach_m < 0.8
        planner.govern(60.0 if heavy else 5.0, caution_n=55.0)
        if planner.phase in (LanePhase.LOWER, LanePhase.PLUNGE):
            plunges.setdefault(planner.cycle, planner.reach_m)
            assert planner.reach_m == pytest.approx(plunges[planner.cycle])
        planner.step()
    assert plunges[1] == pytest.approx(lane.reach_far_m)
    # a stroke that began where the lane was not done (the heavy part and the rise out of it)
    assert min(plunges.values()) < lane.reach_far_m - 0.05
    assert planner.floor_m == pytest.approx(lane.target_depth_m)
