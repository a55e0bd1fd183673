"""The ground map and the descent limiter: the floor against hand-worked tables, the pass
that lowers a cell, and the limiter's latch (pure)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rakectl.core.ground_map import (
    BRAKE_M_PER_S2,
    CELL_M,
    LEAD_M,
    OFFSET_GAIN_PER_S,
    OFFSET_MAX_M,
    TRACKING_MARGIN_M,
    DescentLimiter,
    GroundMap,
)

CEILING_M, STEP_M = 0.05, 0.002
MARGIN = TRACKING_MARGIN_M


def _map(side_reach_m: float = 0.01) -> GroundMap:
    """Cells of 5 mm from 1.0 m to 1.05 m: 11 cells."""
    return GroundMap(1.0, 1.05, CEILING_M, STEP_M, side_reach_m)


def _sweep(ground: GroundMap, reach_from_m: float, reach_to_m: float, height_m: float,
           ticks: int = 200) -> None:
    for k in range(ticks + 1):
        ground.track(reach_from_m + (reach_to_m - reach_from_m) * k / ticks, height_m)


def test_the_floor_is_the_step_below_the_highest_soil_within_the_side_reach() -> None:
    ground = _map()
    assert ground.n_cells == 11
    assert ground.floor_m == pytest.approx([0.048] * 11)
    ground.lower(5, 0.0)  # one cell raked to level 0: its neighbours still see the ceiling
    assert ground.floor_m == pytest.approx([0.048] * 11)
    ground.reset()
    for i in range(11):
        ground.lower(i, 0.02 - 0.002 * i)  # a floor falling 2 mm per cell
    # by hand: floor_i = max over |j - i| <= 2 of (top_j - step)
    tops = [0.02 - 0.002 * i for i in range(11)]
    expected = [max(tops[j] - STEP_M for j in range(max(0, i - 2), min(11, i + 3)))
                for i in range(11)]
    assert ground.floor_m == pytest.approx(expected)
    assert expected[6] == pytest.approx(0.02 - 0.008 - 0.002)  # cell 4 two cells away rules
    assert ground.floor_at_m(1.0 + 6.5 * CELL_M) == pytest.approx(expected[6])
    assert ground.floor_at_m(0.5) == ground.floor_m[0]  # beyond the map: its end cells
    assert ground.floor_at_m(2.0) == ground.floor_m[10]


def test_only_a_cell_crossed_whole_in_one_pass_comes_down() -> None:
    ground = _map(side_reach_m=0.0)
    _sweep(ground, 1.0005, 1.0125, 0.01)  # from inside cell 0 to inside cell 2
    assert ground.top_m[:4] == pytest.approx([CEILING_M, 0.01, CEILING_M, CEILING_M])
    ground.reset()
    for h in (0.03, 0.02, 0.01, 0.0):  # a plunge inside cell 3 lowers nothing
        ground.track(1.017, h)
    assert ground.top_m == pytest.approx([CEILING_M] * 11)
    _sweep(ground, 1.017, 1.0375, 0.0)  # from there toward the far end: 4, 5, 6 crossed
    assert ground.top_m[3:8] == pytest.approx([CEILING_M, 0.0, 0.0, 0.0, CEILING_M])


def test_a_pass_is_counted_at_its_highest_point() -> None:
    ground = _map(side_reach_m=0.0)
    for k in range(101):  # across cell 1 and back up in its middle
        reach = 1.004 + 0.007 * k / 100
        ground.track(reach, 0.004 if abs(reach - 1.0075) < 1e-3 else 0.0)
    assert ground.top_m[1] == pytest.approx(0.004)


def test_back_and_forth_across_an_edge_lowers_nothing() -> None:
    ground = _map(side_reach_m=0.0)
    for k in range(50):
        ground.track(1.0045 if k % 2 else 1.0055, 0.0)
    assert ground.top_m == pytest.approx([CEILING_M] * 11)


def _limiter(ground: GroundMap) -> DescentLimiter:
    return DescentLimiter(ground, 1e-3)


def test_the_limiter_passes_what_the_floor_allows_and_holds_the_rest() -> None:
    ground = _map()
    limiter = _limiter(ground)
    limiter.reset()
    # the tip where the reference is (no lead, no offset): above the floor, untouched
    assert limiter.clip(-0.06, 1.02, 1.02, -0.06, 0.0) == -0.06
    # below it: held 48 mm up (ceiling less the step), less the tracking margin
    assert limiter.clip(0.0, 1.02, 1.02, -0.048 - MARGIN, 0.0) == pytest.approx(-0.048 - MARGIN)
    assert limiter.clipped == 1
    for i in range(11):
        ground.lower(i, 0.0)
    assert limiter.clip(0.01, 1.02, 1.02, 0.002 - MARGIN, 0.0) == pytest.approx(0.002 - MARGIN)
    # the reference's reach and the measured one: the higher floor of the two
    for i in (8, 9, 10):
        ground.lower(i, -0.02)
    assert limiter.clip(0.05, 1.049, 1.02, 0.002 - MARGIN, 0.0) == pytest.approx(0.002 - MARGIN)


def test_a_held_reference_leads_the_tip_down_by_a_millimetre_at_most() -> None:
    limiter = _limiter(_map())
    limiter.reset()
    assert limiter.clip(0.0, 1.02, 1.02, -0.09, 0.0) == pytest.approx(-0.09 + LEAD_M)
    assert limiter.clip(-0.095, 1.02, 1.02, -0.09, 0.0) == -0.095  # not held: as it is


def test_a_descending_tip_is_held_its_braking_distance_above_the_floor() -> None:
    limiter = _limiter(_map())
    braking = 0.1 ** 2 / (2.0 * BRAKE_M_PER_S2)
    assert braking == pytest.approx(0.01)
    tip = -0.048 - MARGIN - 0.005  # 5 mm above the hold, descending at 0.1 m/s
    assert limiter.clip(0.0, 1.02, 1.02, tip, 0.1) == pytest.approx(-0.048 - MARGIN - braking)
    assert limiter.clip(0.0, 1.02, 1.02, tip, -0.1) == pytest.approx(tip + LEAD_M)  # rising


def test_the_hold_rises_while_the_tip_is_below_the_floor_and_settles_back() -> None:
    limiter = _limiter(_map())
    limiter.reset()
    floor_depth = -0.048 - MARGIN
    sag = 0.0004
    out = limiter.clip(0.0, 1.02, 1.02, floor_depth + sag, 0.0)
    assert out == pytest.approx(floor_depth - OFFSET_GAIN_PER_S * 1e-3 * sag)
    for _ in range(2000):  # a tip that stays below whatever the hold: the offset's cap
        out = limiter.clip(0.0, 1.02, 1.02, floor_depth + sag, 0.0)
    assert limiter.offset_m == pytest.approx(OFFSET_MAX_M)
    assert out == pytest.approx(floor_depth - OFFSET_MAX_M)
    for _ in range(2000):  # on the floor's hold again, above the floor: back to none
        out = limiter.clip(0.0, 1.02, 1.02, floor_depth - 0.001, 0.0)
    assert limiter.offset_m == 0.0
    assert out == pytest.approx(floor_depth)


def test_tines_below_a_floor_that_rose_are_raised_to_it() -> None:
    ground = _map()
    for i in range(11):
        ground.lower(i, -0.03)
    limiter = _limiter(ground)
    assert limiter.clip(0.04, 1.02, 1.02, 0.032 - MARGIN, 0.0) == pytest.approx(0.032 - MARGIN)
    ground.reset()  # the floor back at 48 mm above level 0, the tip 32 mm below it
    out = limiter.clip(0.04, 1.02, 1.02, 0.032 - MARGIN, 0.0)
    assert out < -0.048 - MARGIN  # held at the floor, raised further by the offset
    assert limiter.offset_m > 0.0


def test_a_limiter_never_reset_holds_the_floor() -> None:
    hold = -0.048 - MARGIN
    assert _limiter(_map()).clip(0.0, 1.02, 1.02, hold, 0.0) == pytest.approx(hold)


@settings(max_examples=200, deadline=None)
@given(refs=st.lists(st.tuples(st.floats(-0.08, 0.08), st.floats(0.99, 1.06),
                               st.floats(0.99, 1.06), st.floats(-0.08, 0.08),
                               st.floats(-1.0, 1.0)),
                     min_size=1, max_size=60),
       lowered=st.lists(st.tuples(st.integers(0, 10), st.floats(-0.05, 0.05)), max_size=20))
def test_no_output_is_deeper_than_the_floor_or_a_lead_below_the_tip(
        refs: list[tuple[float, float, float, float, float]], lowered: list[tuple[int, float]]
        ) -> None:
    ground = _map()
    limiter = _limiter(ground)
    limiter.reset()
    for k, (depth, reach_ref, reach, tip, rate) in enumerate(refs):
        if k < len(lowered):
            ground.lower(*lowered[k])
        out = limiter.clip(depth, reach_ref, reach, tip, rate)
        floor_depth = -max(ground.floor_at_m(reach_ref), ground.floor_at_m(reach)) - MARGIN
        assert out <= depth
        assert out <= floor_depth + 1e-15
        assert out <= tip + LEAD_M + 1e-15 or out == depth


def test_a_map_that_cannot_be_is_refused() -> None:
    for args in ((1.0, 1.0, 0.0, 0.001, 0.01), (1.0, 1.1, 0.0, 0.0, 0.01),
                 (1.0, 1.1, math.nan, 0.001, 0.01), (1.0, 1.1, 0.0, 0.001, -0.01)):
        with pytest.raises(ValueError):
            GroundMap(*args)


def test_a_survey_is_the_top_where_it_spans_a_cell_and_the_ceiling_elsewhere() -> None:
    """Points at 1.012, 1.018, 1.024, 1.031 m over cells of 5 mm from 1.0 m: cells 3–5
    (1.015–1.030) are spanned whole, cell 3 by the points from 1.012 to 1.024, cell 4 from
    1.018 to 1.031, cell 5 by 1.024 and 1.031; cell 2 (1.010–1.015) starts before the
    survey, cell 6 ends after it. By hand: the highest point bracketing or within a
    spanned cell, the ceiling elsewhere."""
    survey = [(1.012, 0.010), (1.018, 0.014), (1.024, 0.011), (1.031, 0.013)]
    ground = GroundMap(1.0, 1.05, CEILING_M, STEP_M, 0.01, survey)
    tops = [CEILING_M] * 3 + [0.014, 0.014, 0.013] + [CEILING_M] * 5
    assert ground.top_m == pytest.approx(tops)
    assert ground.floor_m == pytest.approx(
        [max(tops[max(0, i - 2):i + 3]) - STEP_M for i in range(11)])
    ground.lower(3, 0.0)
    ground.reset()  # the survey again, not the ceiling
    assert ground.top_m == pytest.approx(tops)
    # a lone point spans no cell; a point above the ceiling is held to it
    assert GroundMap(1.0, 1.05, CEILING_M, STEP_M, 0.01, [(1.02, 0.0)]).top_m == \
        [CEILING_M] * 11
    high = GroundMap(1.0, 1.05, CEILING_M, STEP_M, 0.01, [(1.0, 0.0), (1.05, 0.09)])
    assert high.top_m == [CEILING_M] * 11
