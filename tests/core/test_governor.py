"""The force-adaptive stroke speed: the governor alone, then inside the lane planner (pure)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rakectl.config.settings import LaneSettings
from rakectl.core.governor import (
    DEPTH_GROWTH_MAX,
    SLOWDOWN_RATIO,
    StrokeGovernor,
    next_depth_step_m,
)
from rakectl.core.lane import PLUNGE_TAIL_S, LanePhase, LanePlanner
from rakectl.errors import ConfigError

DT_S = 1e-3
TARGET_N = 44.0
LAG_TARGET_M = 0.01
V_MIN, V_MAX, GAIN = 0.03, 0.25, 2.0


def _governor(start: float = 0.05) -> StrokeGovernor:
    return StrokeGovernor(V_MIN, V_MAX, GAIN, DT_S, start)


def _run(governor: StrokeGovernor, force_n: float, ticks: int, lag_m: float = 0.0) -> float:
    for _ in range(ticks):
        governor.update(force_n, TARGET_N, lag_m, LAG_TARGET_M, governor.speed_m_per_s)
    return governor.speed_m_per_s


def test_no_force_rises_at_the_gain_to_the_top_speed_and_no_further() -> None:
    g = _governor(V_MIN)
    assert _run(g, 0.0, 100) == pytest.approx(V_MIN + GAIN * V_MAX * 0.1)
    assert _run(g, 0.0, 10_000) == V_MAX


def test_above_the_target_it_falls_slowdown_ratio_times_faster_than_it_rises() -> None:
    rise = _governor(0.1)
    fall = _governor(0.1)
    up = _run(rise, 0.0, 10) - 0.1  # margin +1
    down = 0.1 - _run(fall, 2 * TARGET_N, 10)  # margin −1
    assert down == pytest.approx(SLOWDOWN_RATIO * up)
    assert _run(fall, 2 * TARGET_N, 1000) == V_MIN


def test_the_lag_slows_it_too_but_only_as_fast_as_it_speeds_up() -> None:
    by_lag, by_force = _governor(0.2), _governor(0.2)
    down_lag = 0.2 - _run(by_lag, 0.0, 10, lag_m=2 * LAG_TARGET_M)
    down_force = 0.2 - _run(by_force, 2 * TARGET_N, 10)
    assert down_lag == pytest.approx(GAIN * V_MAX * DT_S * 10)
    assert down_force == pytest.approx(SLOWDOWN_RATIO * down_lag)


def test_it_slows_from_the_speed_the_reference_has_not_from_its_limit() -> None:
    g = _governor(V_MAX)
    g.update(TARGET_N * 1.01, TARGET_N, 0.0, LAG_TARGET_M, reference_speed_m_per_s=0.03)
    assert g.speed_m_per_s <= 0.03


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_input_slows_it(bad: float) -> None:
    g = _governor(0.2)
    g.update(bad, TARGET_N, 0.0, LAG_TARGET_M, 0.2)
    assert g.speed_m_per_s < 0.2
    g = _governor(0.2)
    g.update(0.0, TARGET_N, bad, LAG_TARGET_M, 0.2)
    assert g.speed_m_per_s < 0.2


def test_invalid_limits_are_refused() -> None:
    with pytest.raises(ValueError):
        StrokeGovernor(0.3, 0.2, GAIN, DT_S, 0.25)


finite_or_not = st.one_of(st.floats(-1e6, 1e6), st.sampled_from([math.nan, math.inf]))


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.tuples(finite_or_not, st.floats(0.0, 0.1), st.floats(0.0, 1.0)),
                      min_size=1, max_size=60),
       start=st.floats(0.0, 2.0))
def test_it_stays_in_its_range_and_never_speeds_up_above_a_target(
        steps: list[tuple[float, float, float]], start: float) -> None:
    g = _governor(start)
    assert V_MIN <= g.speed_m_per_s <= V_MAX
    for force_n, lag_m, reference in steps:
        before = g.speed_m_per_s
        after = g.update(force_n, TARGET_N, lag_m, LAG_TARGET_M, reference)
        assert V_MIN <= after <= V_MAX
        if not (force_n <= TARGET_N and lag_m <= LAG_TARGET_M):
            assert after <= before
        else:
            assert after <= before + GAIN * V_MAX * DT_S + 1e-15


@pytest.mark.parametrize("gain_n_per_m_per_s", [50.0, 200.0, 800.0])
def test_against_force_proportional_to_speed_it_rides_just_under_the_target(
        gain_n_per_m_per_s: float) -> None:
    """A toy soil whose force follows k·v with a 20 ms lag (F̂ = K_e·v·α in steady state):
    the speed settles where k·v is just under the target, from below, and the force never
    goes 10 % over the target on the way."""
    g, force_n = _governor(V_MIN), 0.0
    lag = 1.0 - math.exp(-DT_S / 0.02)
    peak_n = 0.0
    for _ in range(20_000):
        speed = g.update(force_n, TARGET_N, 0.0, LAG_TARGET_M, g.speed_m_per_s)
        force_n += lag * (gain_n_per_m_per_s * speed - force_n)
        peak_n = max(peak_n, force_n)
    expected = min(V_MAX, TARGET_N / gain_n_per_m_per_s)
    assert g.speed_m_per_s == pytest.approx(expected, rel=0.02)
    assert peak_n <= 1.1 * TARGET_N


# --------------------------------------------------------------------------- in the planner

LANE = LaneSettings(reach_far_m=1.2, reach_near_m=0.7, depth_step_m=0.02, target_depth_m=0.02,
                    stroke_speed_m_per_s=0.05, adaptive=True, max_stroke_speed_m_per_s=0.3,
                    accel_m_per_s2=1.0)


def _stroke_speeds(lane: LaneSettings, force_n: float,
                   phase: LanePhase = LanePhase.STROKE) -> list[float]:
    """Reference speeds along the lane's strokes (or another phase), with a constant force
    estimate."""
    planner = LanePlanner(lane, DT_S, lane.reach_far_m, -lane.clearance_m)
    speeds = []
    while not planner.done:
        planner.observe(planner.reach_m, planner.depth_m)  # a tip on its reference: no lag
        planner.govern(force_n, caution_n=55.0)
        if planner.phase is phase:
            speeds.append(planner.speed_m_per_s)
        planner.step()
    return speeds


def test_an_adaptive_stroke_runs_fast_without_force_and_slow_with_it() -> None:
    free = _stroke_speeds(LANE, 0.0)
    loaded = _stroke_speeds(LANE, 60.0)
    fixed = _stroke_speeds(dataclasses.replace(LANE, adaptive=False), 0.0)
    assert max(free) == pytest.approx(LANE.max_stroke_speed_m_per_s)
    assert max(loaded) <= LANE.stroke_speed_m_per_s + LANE.accel_m_per_s2 * DT_S
    assert len(loaded) > 5 * len(free)
    assert max(fixed) == pytest.approx(LANE.stroke_speed_m_per_s)


def test_the_adaptive_speed_respects_the_acceleration_limit() -> None:
    speeds = _stroke_speeds(LANE, 0.0)
    rises = [b - a for a, b in itertools.pairwise(speeds)]
    assert max(rises) <= LANE.accel_m_per_s2 * DT_S + 1e-12


def test_govern_acts_only_on_a_stroke_of_an_adaptive_lane() -> None:
    planner = LanePlanner(LANE, DT_S, LANE.reach_far_m, -LANE.clearance_m)
    assert planner.governor is not None
    before = planner.stroke_speed_m_per_s
    planner.govern(0.0, 55.0)  # APPROACH: nothing changes
    assert planner.stroke_speed_m_per_s == before
    fixed = LanePlanner(dataclasses.replace(LANE, adaptive=False), DT_S, 1.2, -0.03)
    assert fixed.governor is None
    fixed.govern(0.0, 55.0)
    assert fixed.stroke_speed_m_per_s == LANE.stroke_speed_m_per_s


def test_min_above_max_stroke_speed_is_refused() -> None:
    from rakectl.errors import ConfigError

    with pytest.raises(ConfigError, match="min_stroke_speed_m_per_s"):
        dataclasses.replace(LANE, min_stroke_speed_m_per_s=0.5)


# --------------------------------------------------------------------------- closed loop


def _stroke_speed_in(soil: str) -> tuple[float, float, LanePlanner]:
    """One adaptive cycle (0.4 m at 10 mm) of the benchmark's soil through the full chain:
    (mean stroke speed, largest true vertical force, the planner at the end)."""
    from rakectl.config.loader import load_settings
    from rakectl.sim.rake_plant import RakeLoop
    from rakectl.sim.scenario import Scenario
    from rakectl.sim.simulate import advance_reference, build_reference

    # The set point at 0.3 × caution (16.5 N): clay's stroke loads, as the current-based
    # estimate sees them (~25 N), are above it, sand's (~10 N) below. At the default 0.8
    # nothing in these three soils reaches it below 0.25 m/s (`rakectl bench --excavation`).
    settings = load_settings(
        f"config/scenarios/excavate-{soil}.yaml",
        ["lane.reach_near_m=1.0", "lane.target_depth_m=0.005", "lane.depth_step_m=0.005",
         "lane.force_target_share=0.3"], root=Scenario)
    planner = build_reference(settings)
    assert isinstance(planner, LanePlanner)
    loop = RakeLoop(settings, planner.reach_m, planner.depth_m)
    loop.reset()
    speeds, peak_n = [], 0.0
    for _ in range(60_000):
        loop.step(planner.reach_m, planner.depth_m, planner.contact)
        peak_n = max(peak_n, loop.contact.peak_down_n)
        if planner.phase is LanePhase.STROKE:
            speeds.append(planner.speed_m_per_s)
        advance_reference(planner, loop)
        if planner.done:
            break
    return sum(speeds) / len(speeds), peak_n, planner


@pytest.mark.slow
def test_in_the_full_chain_an_adaptive_stroke_is_faster_in_sand_than_in_clay() -> None:
    """A 5 mm cut (clay's drag at 10 mm is more than the side budget lets the arm push):
    sand's stroke runs near the top speed (0.15 m/s, the clamp's budget toward the robot
    shrinks fast above it), clay's is held back by its load, and clay's
    first stroke rides up more than 3 mm where it starts, which the planner strokes again."""
    sand_speed, sand_peak_n, sand = _stroke_speed_in("sand")
    clay_speed, clay_peak_n, clay = _stroke_speed_in("clay")
    assert sand.done and sand.floor_m == pytest.approx(0.005) and sand.cycle == 1
    assert sand.found_at is None and not sand.stopped_by_force
    assert clay.done and clay.found_at is None and not clay.stopped_by_force
    assert clay.floor_m == pytest.approx(0.005)
    assert clay_speed < 0.8 * sand_speed  # measured: 0.093 against 0.133 m/s (top 0.15)
    assert max(sand_peak_n, clay_peak_n) < 90.0


# --------------------------------------------------------------------------- depth of cut


def test_the_next_cut_scales_with_the_last_strokes_margin() -> None:
    def step(force_n: float, lag_m: float = 0.0, step_m: float = 0.01) -> float:
        return next_depth_step_m(step_m, force_n, 40.0, lag_m, 0.01, 0.01, 0.04)

    assert step(0.0) == pytest.approx(0.01 * DEPTH_GROWTH_MAX)  # no load: at most doubled
    assert step(32.0, step_m=0.02) == pytest.approx(0.025)  # 40/32 × 20 mm
    assert step(40.0, step_m=0.02) == pytest.approx(0.02)  # at the set point: the same
    assert step(80.0, step_m=0.03) == pytest.approx(0.015)  # twice over: half as deep
    assert step(500.0, step_m=0.03) == 0.01  # never below the lane's own step
    assert step(1.0, step_m=0.03) == 0.04  # nor beyond the deepest cut
    assert step(10.0, lag_m=0.02, step_m=0.02) == pytest.approx(0.01)  # the lag counts too
    assert step(math.nan, step_m=0.03) == 0.01
    assert step(10.0, lag_m=math.inf, step_m=0.03) == 0.01


def _cycle_depths(lane: LaneSettings, force_n: float) -> list[float]:
    """Each cycle's depth on a lane raked with a constant force estimate."""
    planner = LanePlanner(lane, DT_S, lane.reach_far_m, -lane.clearance_m)
    depths: list[float] = []
    while not planner.done:
        planner.observe(planner.reach_m, planner.depth_m)
        planner.govern(force_n, caution_n=55.0)
        if planner.phase is LanePhase.STROKE and depths[-1:] != [planner.cycle_depth_m]:
            depths.append(planner.cycle_depth_m)
        planner.step()
    return depths


def test_an_adaptive_lane_cuts_deep_in_soft_soil_and_shallow_in_hard() -> None:
    lane = LaneSettings(reach_far_m=1.1, reach_near_m=1.0, depth_step_m=0.01,
                        target_depth_m=0.1, max_depth_step_m=0.04, stroke_speed_m_per_s=0.2,
                        plunge_speed_m_per_s=0.05, max_plunge_speed_m_per_s=0.1,
                        travel_speed_m_per_s=0.5, accel_m_per_s2=5.0)
    fixed = _cycle_depths(lane, 0.0)
    soft = _cycle_depths(dataclasses.replace(lane, adaptive=True), 0.0)
    hard = _cycle_depths(dataclasses.replace(lane, adaptive=True), 50.0)  # over 0.8 × 55 N
    assert fixed == pytest.approx([0.01 * k for k in range(1, 11)])
    assert soft == pytest.approx([0.01, 0.03, 0.07, 0.1])  # steps 10, 20, 40 (the cap), 30
    assert hard == pytest.approx(fixed)


def test_a_max_depth_step_below_the_depth_step_is_refused_on_an_adaptive_lane() -> None:
    LaneSettings(depth_step_m=0.02, max_depth_step_m=0.01)  # not adaptive: unused
    with pytest.raises(ConfigError, match="max_depth_step_m"):
        LaneSettings(adaptive=True, depth_step_m=0.02, max_depth_step_m=0.01)



def test_a_max_plunge_speed_below_the_plunge_speed_is_refused_on_an_adaptive_lane() -> None:
    LaneSettings(plunge_speed_m_per_s=0.05, max_plunge_speed_m_per_s=0.02)  # not adaptive
    with pytest.raises(ConfigError, match="max_plunge_speed_m_per_s"):
        LaneSettings(adaptive=True, plunge_speed_m_per_s=0.05, max_plunge_speed_m_per_s=0.02)


def test_an_adaptive_plunge_speeds_up_without_force_and_keeps_its_floor_with_it() -> None:
    lane = dataclasses.replace(LANE, plunge_speed_m_per_s=0.007, max_plunge_speed_m_per_s=0.02,
                               depth_step_m=0.04, target_depth_m=0.04, max_depth_step_m=0.04)
    free = _stroke_speeds(lane, 0.0, LanePhase.PLUNGE)
    loaded = _stroke_speeds(lane, 60.0, LanePhase.PLUNGE)  # over 0.8 × 55 N from the start
    fixed = _stroke_speeds(dataclasses.replace(lane, adaptive=False), 0.0, LanePhase.PLUNGE)
    assert max(free) == pytest.approx(0.02)
    assert max(loaded) == pytest.approx(0.007)  # never slower than the lane's plunge speed,
    assert max(fixed) == pytest.approx(0.007)  # nor faster when loaded or not adaptive
    assert len(free) < 0.5 * len(loaded)
    rises = [b - a for a, b in itertools.pairwise(free)]
    assert max(rises) <= lane.accel_m_per_s2 * DT_S + 1e-12


def _next_cut_after_a_spike(spike_at_s: float) -> float:
    """The second cycle's depth after a first stroke whose force estimate is 80 N (far over
    the 44 N set point) for 10 ms starting ``spike_at_s`` into the stroke, 0 otherwise."""
    lane = dataclasses.replace(LANE, target_depth_m=0.1, depth_step_m=0.01,
                               max_depth_step_m=0.04, max_plunge_speed_m_per_s=0.05)
    planner = LanePlanner(lane, DT_S, lane.reach_far_m, -lane.clearance_m)
    stroke_ticks = 0
    while planner.cycle == 1:
        planner.observe(planner.reach_m, planner.depth_m)
        in_spike = 0.0 <= stroke_ticks * DT_S - spike_at_s < 0.01
        planner.govern(80.0 if planner.phase is LanePhase.STROKE and in_spike else 0.0, 55.0)
        stroke_ticks += planner.phase is LanePhase.STROKE
        planner.step()
    return planner.cycle_depth_m


def test_the_next_cut_is_judged_after_the_plunges_tail() -> None:
    # At a stroke's start F̂ still reads the plunge's descent: that does not make the next
    # cut shallower; the same spike later in the stroke does.
    assert _next_cut_after_a_spike(0.0) == pytest.approx(0.01 + 0.02)
    assert _next_cut_after_a_spike(PLUNGE_TAIL_S + 0.05) == pytest.approx(0.01 + 0.01)
