"""Campaign scenes that can stand: objects laid in the soil from its surface, nothing
floating (rakectl.sim.scene), against hand-computed depths."""

from __future__ import annotations

import math

import pytest

from drivers.ground_params import BuriedObjects, MineParams, RootParams, StoneParams
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


def test_bodies_overlap_by_hand() -> None:
    """Extents along the reach and in depth, both overlapping by more than touching; a
    root's is the square about its section."""
    mine = MineParams(reach_m=1.0, depth_m=0.02, width_m=0.08, thickness_m=0.05)  # 0.96–1.04
    inside = StoneParams(reach_m=1.0437, depth_m=0.03, width_m=0.01, thickness_m=0.02)
    beside = StoneParams(reach_m=1.045, depth_m=0.03, width_m=0.01, thickness_m=0.02)
    under = StoneParams(reach_m=1.0, depth_m=0.07, width_m=0.1, thickness_m=0.02)
    root = RootParams(reach_m=0.95, depth_m=0.06)  # 0.94–0.96 along, 60–80 mm down
    assert scene.overlap(mine, inside) and scene.overlap(inside, mine)
    assert not scene.overlap(mine, beside)  # touching at 1.04 m: apart
    assert not scene.overlap(mine, under)  # its top at the mine's bottom, 70 mm
    assert not scene.overlap(mine, root)  # beside it, touching at 0.96 m
    assert scene.overlap(under, RootParams(reach_m=1.0, depth_m=0.08))


def test_bodies_are_drawn_apart_mines_kept_first() -> None:
    """A stone inside a mine and a root inside the stone: the mine is kept (mines first),
    the stone left out, and the root, now beside nothing kept, kept. A mine given first
    is kept before one drawn earlier that overlaps it."""
    mine = MineParams(reach_m=1.0, depth_m=0.02, width_m=0.08, thickness_m=0.05)
    stone = StoneParams(reach_m=1.06, depth_m=0.03, width_m=0.05, thickness_m=0.04)
    root = RootParams(reach_m=1.07, depth_m=0.04)  # inside the stone, clear of the mine
    drawn = BuriedObjects(stones=(stone,), roots=(root,), mines=(mine,))
    assert scene.apart(drawn) == BuriedObjects(stones=(), roots=(root,), mines=(mine,))
    at_cut = MineParams(reach_m=1.05, depth_m=0.04, width_m=0.06, thickness_m=0.04)
    two = BuriedObjects(mines=(mine, at_cut))
    assert scene.apart(two) == BuriedObjects(mines=(mine,))
    assert scene.apart(two, first=at_cut) == BuriedObjects(mines=(at_cut,))
    clear = BuriedObjects(stones=(StoneParams(reach_m=0.8),), mines=(mine,))
    assert scene.apart(clear) == clear


def test_no_scene_lays_two_bodies_in_one_place() -> None:
    """The random family's first 400 scenes and 7116 of seed 20261128, which laid a
    stone's end 4.2 mm inside a mine: no two bodies overlap; most mines are kept (417
    of the 492 drawn here), and every plunge aimed at a mine keeps it (27 here)."""
    drawn = [cases.generate(20261128, i) for i in (*range(400), 7116)]

    def overlapping(objects: BuriedObjects) -> bool:
        bodies = (*objects.stones, *objects.roots, *objects.mines)
        return any(scene.overlap(a, b) for k, a in enumerate(bodies) for b in bodies[k + 1:])

    assert [c.index for c in drawn if overlapping(c.ground.objects)] == []
    assert sum(len(c.ground.objects.mines) for c in drawn) > 200  # mines still drawn
    above = [c for c in drawn if c.command.kind is cases.CommandKind.PLUNGE
             and any(m.reach_m == c.command.reach_far_m for m in c.ground.objects.mines)]
    assert len(above) > 20  # the plunges aimed at a mine keep it
