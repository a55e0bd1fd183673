"""The lane planner of paper Fig. 3: phases, depths, contact flags, speed limits."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rakectl.excavation import (
    LANDING_BAND_M,
    PLUNGE_MARGIN_M,
    SETTLE_TIMEOUT_S,
    LanePhase,
    LanePlanner,
)
from rakectl.settings import LaneSettings

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
