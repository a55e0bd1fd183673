"""Campaign scenes that can stand: objects laid in the soil from its surface, nothing
floating (rakectl.sim.scene), against hand-computed depths."""

from __future__ import annotations

import math

import pytest

from drivers.ground_params import BuriedObjects, MineParams, StoneParams
from drivers.soil_params import SoilLayer, SoilParams, SurfaceWave
from rakectl.sim import cases, scene

LAYER = SoilLayer(stiffness_n_per_m=1e5, collapse_force_n=20.0, cohesion_pa=5e3)
# a 10 % slope about the lane's centre, 1.0 m (lane_reach 0.6–1.4 m): −0.02 m at 0.8 m
SLOPED = SoilParams(layers=(LAYER,), surface_slope=0.1, stiffness_rel_std=0.0,
                    strength_rel_std=0.0, lane_reach_min_m=0.6, lane_reach_max_m=1.4)


def test_the_lowest_surface_across_a_body_by_hand() -> None:
    """On a plain slope the lowest point is the body's low end; with an 8 mm wave 0.1 m
    long, a sampling a hundred times denser (1 µm) finds the same within 0.1 µm."""
    stone = StoneParams(reach_m=0.8, depth_m=0.0, width_m=0.1, thickness_m=0.05)
    assert scene.lowest_surface_m(SLOPED, stone) == pytest.approx(0.1 * (0.75 - 1.0))
    wavy = SoilParams(layers=(LAYER,), surface_slope=0.02, stiffness_rel_std=0.0,
                      strength_rel_std=0.0, lane_reach_min_m=0.6, lane_reach_max_m=1.4,
                      surface_waves=(SurfaceWave(0.008, 0.1, 1.0),))
    dense = min(0.02 * (x - 1.0) + 0.008 * math.sin(2 * math.pi * x / 0.1 + 1.0)
                for x in (0.75 + 0.1 * k / 100_000 for k in range(100_001)))
    assert scene.lowest_surface_m(wavy, stone) == pytest.approx(dense, abs=1e-7)


def test_depths_are_laid_in_from_the_surface_and_a_mine_at_a_cut_is_sunk_to_stand() -> None:
    """A stone drawn 30 mm deep and a mine drawn 20 mm out of the soil (30 mm tall), at
    0.6 m on the 10 % slope, where the surface's lowest point under them (at 0.55 m) is
    45 mm below level 0: their tops 75 mm and 25 mm below level 0, the mine's bottom
    10 mm in the soil. A mine at a 5 mm cut counted from level 0 would float there by
    10 mm; sunk until its bottom is 10 mm in, its top is 25 mm below level 0."""
    stone = StoneParams(reach_m=0.6, depth_m=0.03, width_m=0.1, thickness_m=0.05)
    mine = MineParams(reach_m=0.6, depth_m=-0.02, width_m=0.1, thickness_m=0.03)
    laid = scene.laid_in(BuriedObjects(stones=(stone,), mines=(mine,)), SLOPED)
    assert laid.stones[0].depth_m == pytest.approx(0.075)
    assert laid.mines[0].depth_m == pytest.approx(0.025)
    assert scene.floating_m(SLOPED, laid.mines[0]) == pytest.approx(-0.01)
    at_cut = MineParams(reach_m=0.6, depth_m=0.005, width_m=0.1, thickness_m=0.03)
    assert scene.floating_m(SLOPED, at_cut) == pytest.approx(0.01)
    assert scene.standing(at_cut, SLOPED).depth_m == pytest.approx(0.025)
    deep = MineParams(reach_m=0.6, depth_m=0.08, width_m=0.1, thickness_m=0.03)
    assert scene.standing(deep, SLOPED) == deep  # in the soil already: as it was


@pytest.mark.parametrize("family", [cases.Family.RANDOM, cases.Family.EDGE])
def test_no_drawn_body_floats_and_some_stand_out_of_the_soil(family: cases.Family) -> None:
    """Every body the campaign draws has its bottom at least 10 mm in the soil at the
    surface's lowest point across it; some stones and mines stand out of it (their tops
    above that point). 20261130/2428, the case that drew a mine floating 5–14 mm above
    a 9 % slope, draws none now."""
    drawn = [cases.generate(20261130, i, family) for i in range(400)]
    drawn.append(cases.generate(20261130, 2428, family))
    floating = [(c.index, round(scene.floating_m(c.ground.soil, b), 4)) for c in drawn
                for b in (*c.ground.objects.stones, *c.ground.objects.roots,
                          *c.ground.objects.mines)
                if scene.floating_m(c.ground.soil, b) > -scene.BURIED_BOTTOM_M + 1e-12]
    assert floating == []
    if family is cases.Family.RANDOM:
        for bodies in ("stones", "mines"):
            out = [c.index for c in drawn for b in getattr(c.ground.objects, bodies)
                   if -b.depth_m > scene.lowest_surface_m(c.ground.soil, b)]
            assert len(out) > 10, bodies
