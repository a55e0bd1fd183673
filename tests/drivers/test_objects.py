"""Buried objects and the combined Ground: felt only where they are; stones, roots, mines."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from drivers.ground import Ground
from drivers.ground_params import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.objects import Body, Contact
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.errors import NonFiniteError

DT_S = 1e-4
QUIET_SOIL = SoilParams(layers=(SoilLayer(damping_time_s=0.0),), stiffness_rel_std=0.0,
                        strength_rel_std=0.0)


def ground(*, stones: tuple[StoneParams, ...] = (), roots: tuple[RootParams, ...] = (),
           mines: tuple[MineParams, ...] = (), soil: SoilParams = QUIET_SOIL) -> Ground:
    return Ground(GroundParams(soil=soil, objects=BuriedObjects(stones, roots, mines)), seed=0)


def press(g: Ground, reach_m: float, start_m: float, stop_m: float,
          step_m: float = 2e-6) -> tuple[np.ndarray, np.ndarray]:
    """Descend quasi-statically at reach_m: (heights, vertical force on the tip)."""
    heights = np.arange(start_m, stop_m, -step_m)
    forces = np.array([g.step(reach_m, h, 0.0, 0.0, DT_S)[1] for h in heights])
    return heights, forces


# The object below spans reach 0.95–1.05 m and heights −0.13 to −0.05 m; each case
# puts the tip a distance outside one face and level with (or across) the others.
gap = st.floats(0.0, 0.3)
outside = st.one_of(
    st.tuples(gap.map(lambda d: 0.95 - d), st.floats(-0.13, -0.05)),  # nearer the robot
    st.tuples(gap.map(lambda d: 1.05 + d), st.floats(-0.13, -0.05)),  # beyond it
    st.tuples(st.floats(0.95, 1.05), gap.map(lambda d: -0.05 + d)),  # above its top
    st.tuples(st.floats(0.95, 1.05), gap.map(lambda d: -0.13 - d)),  # below its bottom
    st.tuples(st.floats(0.3, 1.7), st.floats(-0.2, 0.1)).filter(  # anywhere else
        lambda p: not (0.95 < p[0] < 1.05 and -0.13 < p[1] < -0.05)),
)
kinds = st.sampled_from(["stones", "roots", "mines"])


@settings(max_examples=150, deadline=None)
@given(outside, kinds, st.floats(-1, 1), st.floats(-1, 1))
def test_an_object_is_felt_only_where_it_is(at: tuple[float, float], kind: str, vr: float,
                                            vh: float) -> None:
    reach_m, height_m = at
    body = dict(reach_m=1.0, depth_m=0.05, width_m=0.1, thickness_m=0.08)
    objects = {"stones": BuriedObjects(stones=(StoneParams(**body),)),
               "roots": BuriedObjects(roots=(RootParams(**body),)),
               "mines": BuriedObjects(mines=(MineParams(**body),))}[kind]
    with_object = Ground(GroundParams(soil=QUIET_SOIL, objects=objects), seed=0)
    without = ground()
    forces = with_object.step(reach_m, height_m, vr, vh, DT_S)
    obj = with_object.bodies[0]
    assert obj.force_reach_n == 0.0 and obj.force_up_n == 0.0
    assert forces == without.step(reach_m, height_m, vr, vh, DT_S)
    assert with_object.truth.contact in (Contact.NONE, Contact.SOIL)
    if height_m > 0.0:
        assert with_object.truth.contact is Contact.NONE and forces == (0.0, 0.0)


def test_an_object_is_felt_inside_its_extent() -> None:
    body = Body(Contact.STONE, StoneParams(reach_m=1.0, depth_m=0.05, width_m=0.1))
    # met anew: its damping acts on the 0.1 mm gained over the step, not on the speed
    assert body.touch(1.02, -0.0501, 0.0, -0.01, DT_S)
    assert body.force_up_n == pytest.approx(1e7 * 1e-4 + 1e7 * 2e-4 * 1e-4 / DT_S)
    assert body.touch(1.02, -0.0501, 0.0, -0.01, DT_S)  # in it since: K·p + B·v
    assert body.force_up_n == pytest.approx(1e7 * 1e-4 + 1e7 * 2e-4 * 0.01)
    assert not body.touch(1.06, -0.0501, 0.0, -0.01, DT_S) and body.force_up_n == 0.0
    assert not body.touching


def test_a_stone_stays_rigid() -> None:
    g = ground(stones=(StoneParams(depth_m=0.002),))
    heights, force = press(g, 1.0, 0.001, -0.00215)
    on = heights < -0.002
    assert np.all(np.diff(force[on]) > 0.0)  # grows, never collapses
    assert force[-1] > 1000.0 and g.truth.contact is Contact.STONE
    soil_part = force[on] - 1e7 * (-0.002 - heights[on])  # shielded: the soil stops changing
    assert np.ptp(soil_part) < 1e-6 and 0.0 <= soil_part[0] <= 10.0
    surface = np.array(g.soil.surface_heights_m())
    assert surface.min() >= -0.002  # the soil under the stone is shielded


def test_a_stone_side_is_a_rigid_wall() -> None:
    g = ground(stones=(StoneParams(reach_m=1.0, depth_m=0.01, width_m=0.1),))
    g.step(1.2, -0.02, 0.0, 0.0, DT_S)
    reach = np.arange(1.2, 1.0495, -5e-6)
    f = np.array([g.step(r, -0.02, -0.05, 0.0, DT_S)[0] for r in reach])
    against = reach < 1.05
    assert np.all(f[against] > 0.0)  # pushes the tip back, away from the robot
    assert f[-1] > 1e7 * 0.0004 and g.truth.contact is Contact.STONE


@pytest.mark.parametrize("activation_n", [80.0, 90.0, 100.0])
def test_a_mine_fires_exactly_when_its_plate_force_exceeds_activation(
        activation_n: float) -> None:
    g = ground(mines=(MineParams(depth_m=0.003, activation_force_n=activation_n),))
    mine = g.bodies[0]
    g.step(1.0, 0.001, 0.0, 0.0, DT_S)
    fired_at = None
    for h in np.arange(-0.0025, -0.004, -1e-7):
        g.step(1.0, float(h), 0.0, -0.001, DT_S)
        if fired_at is None:
            assert mine.activated == (mine.force_up_n > activation_n) == g.truth.mine_activated
            fired_at = h if mine.activated else None
    assert fired_at is not None
    assert mine.peak_down_n > activation_n
    for h in np.arange(-0.003, 0.01, 1e-4):  # lift off: latched
        g.step(1.0, float(h), 0.0, 0.01, DT_S)
        assert mine.activated and g.truth.mine_activated
    assert g.truth.contact is Contact.NONE


def test_a_push_on_a_mine_side_does_not_fire_it_but_is_recorded() -> None:
    g = ground(mines=(MineParams(reach_m=1.0, depth_m=0.01, width_m=0.08),))
    mine = g.bodies[0]
    for r in np.arange(1.1, 1.0395, -5e-6):
        g.step(float(r), -0.03, -0.05, 0.0, DT_S)
    assert mine.peak_side_n > 1000.0 and not mine.activated and not g.truth.mine_activated
    assert g.truth.contact is Contact.MINE and g.truth.force_drag_n > 1000.0


def test_a_root_yields_then_breaks() -> None:
    root = RootParams(depth_m=0.003, yield_force_n=400.0, break_displacement_m=0.01)
    g = ground(roots=(root,))
    body = g.bodies[0]
    heights, force = press(g, 1.0, 0.001, -0.02, step_m=2e-5)
    touching = (heights < -0.003) & ~np.isclose(force, 0.0)
    assert force.max() <= 400.0 + QUIET_SOIL.layers[0].collapse_force_n
    assert np.any(force[touching] > 399.0)
    assert body.broken and body.moved_m > 0.01
    assert g.truth.contact is not Contact.ROOT and force[-1] < 20.0


def test_ground_record_and_interface() -> None:
    g = ground(mines=(MineParams(reach_m=1.4),))
    f_reach, f_up = g.step(1.0, -0.01, -0.05, -0.007, DT_S)
    t = g.truth
    assert (f_reach, f_up) == (t.force_drag_n, t.force_down_n)
    assert t.contact is Contact.SOIL and t.cut_depth_m == pytest.approx(0.01)
    assert t.surface_height_m == 0.0 and t.interface_height_m == pytest.approx(-0.01)
    g.step(1.0, -0.01002, 0.0, 0.0, DT_S)
    assert t.force_down_n > 0.0 and t.max_force_down_n >= t.force_down_n
    for bad in (math.nan, math.inf):
        with pytest.raises(NonFiniteError):
            g.step(1.0, bad, 0.0, 0.0, DT_S)


def test_max_force_down_includes_the_peak_inside_a_step() -> None:
    g = ground()
    g.step(1.0, 0.001, 0.0, 0.0, DT_S)
    g.step(1.0, -0.000149, 0.0, -1.0, DT_S)  # two collapses inside one step
    assert g.truth.force_down_n < 10.0
    assert g.truth.max_force_down_n == pytest.approx(10.0)


def test_a_tine_meeting_a_root_under_its_top_rides_up_it() -> None:
    """A root is round. Dragged toward the robot 1.3 mm under its top, the tip meets its
    curved upper surface: the force grows with the overlap, upward and pushing the tip
    back along the slope, with no jump. As a rectangle the root was pushed sideways until
    the top face was the nearer one, then read its whole overlap upward at once
    (K·1.3 mm = 182 N), which the safety campaign saw as 110–140 N on the ground."""
    root = Body(Contact.ROOT, RootParams(reach_m=1.0, depth_m=0.01))
    height_m = -0.0113
    ups, backs = [], []
    for reach_m in np.arange(1.0101, 1.0, -2e-6):  # up the far slope to its crest
        root.touch(float(reach_m), height_m, 0.0, 0.0, DT_S)  # quasi-static
        ups.append(root.force_up_n)
        backs.append(root.force_reach_n)
    up, back = np.array(ups), np.array(backs)
    assert up[0] < 1.0 and up.max() == pytest.approx(root.stiffness_n_per_m * 0.0013, rel=0.01)
    assert np.all(np.diff(up[up > 0.0]) > 0.0)  # grows as the tip goes in
    assert np.abs(np.diff(up)).max() < 1.0  # no jump at any 2 µm step
    on_far_slope = up > 0.0
    assert np.all(back[on_far_slope] > 0.0)  # pushed back, away from the robot
    assert root.peak_down_n == pytest.approx(up.max())


@settings(max_examples=200, deadline=None)
@given(st.floats(0.991, 1.009), st.floats(-0.0299, -0.0101), st.floats(-0.5, 0.5),
       st.booleans())
@example(0.998046875, -0.010100000000000001, -0.5, True)  # above its curve, falling (CI)
def test_a_roots_law_for_the_tine_mount_is_what_it_reads(reach_m: float, height_m: float,
                                                         height_vel: float, touching: bool
                                                         ) -> None:
    """Where the root gives the tine mount a vertical law, that law's force at the tip is the
    vertical force the root itself reads there (the mount carries what the ground reads).
    Above its curved top, within its box, the root reads nothing; the law, judged on its
    surface, may already carry the damping of the fall into it (B·n_up²·v: the force of
    the contact about to begin; its elastic part is ≤ 0 above the surface), as a mine's
    rim does. The same whether the tip was in it at the last reading or meets it anew
    (then elastic: K + B/h, no damping on the speed)."""
    root = Body(Contact.ROOT, RootParams(reach_m=1.0, depth_m=0.01))
    root.touching = touching
    law = root.vertical_law(reach_m, height_m, height_m, DT_S)
    touching = root.touch(reach_m, height_m, 0.0, height_vel, DT_S)
    if law is None:
        contact = root._contact(reach_m, height_m)
        if contact is not None and contact[2] < 0.0:  # nearest its bottom: it pushes the
            assert root.force_up_n <= 0.0  # tines down, onto the mount's stop, not a law
            return
        assert root.force_up_n == 0.0
        return
    elastic_n = min(law.stiffness_n_per_m * (law.ref_m - height_m), law.cap_n)
    expected_n = max(0.0, elastic_n - law.damping_ns_per_m * height_vel)
    if root._contact(reach_m, height_m) is None:
        assert not touching and root.force_up_n == 0.0
        assert expected_n <= law.damping_ns_per_m * max(0.0, -height_vel) + 1e-6
        return
    assert touching or expected_n == 0.0
    assert root.force_up_n == pytest.approx(expected_n, rel=1e-9, abs=1e-9)



@settings(max_examples=200, deadline=None)
@given(st.floats(0.9601, 1.0399), st.floats(-0.0139, -0.0101), st.floats(-0.5, 0.5),
       st.floats(-0.5, 0.5), st.booleans())
@example(0.9601, -0.012116264112207219, 0.5, 0.0, True)  # above the rim, moving into it (CI)
def test_a_mines_law_for_the_tine_mount_is_what_it_reads(
        reach_m: float, height_m: float, reach_vel: float, height_vel: float,
        touching: bool) -> None:
    """The same on a mine's top and by its rounded rim, the tip moving along the reach too.
    Moving into the rim or along the top, the law reads what the mine reads. Moving away
    from the rim, the mine reads less by the separating speed's damping, which the law
    leaves out: folded in, it put the law's reference below the surface, where the mount
    rested its tines inside the rim (seed 7's plunges 277, 442, 514, 595, 688: 97–120 N)."""
    mine = Body(Contact.MINE, MineParams(reach_m=1.0, depth_m=0.01, width_m=0.08))
    mine.touching = touching
    law = mine.vertical_law(reach_m, height_m, height_m, DT_S, reach_vel)
    mine.touch(reach_m, height_m, reach_vel, height_vel, DT_S)
    if law is None:
        assert mine.force_up_n == 0.0
        return
    expected_n = max(0.0, law.stiffness_n_per_m * (law.ref_m - height_m)
                     - law.damping_ns_per_m * height_vel)
    contact = mine._contact(reach_m, height_m)
    if contact is None:  # above the rounded rim, beside the top: the mine reads nothing;
        # the law, judged on the rim's surface, may already carry the damping of the speed
        # into the rim (B·n_up·n_reach·v along the reach, B·n_up²·v falling: the force of
        # the contact about to begin; its elastic part is ≤ 0 above the surface)
        assert mine.force_up_n == 0.0
        damping = mine.stiffness_n_per_m * mine.damping_s
        assert expected_n <= damping * (abs(reach_vel) + max(0.0, -height_vel)) + 1e-6
    elif contact[1] * reach_vel <= 0.0:  # into the rim, or along the top (n_reach = 0)
        assert mine.force_up_n == pytest.approx(expected_n, rel=1e-9, abs=1e-6)
    else:
        assert mine.force_up_n <= expected_n + 1e-6


@settings(max_examples=200, deadline=None)
@given(st.floats(0.965, 1.035), st.floats(-0.05, 0.05), st.floats(1e-12, 1e-3))
@example(1.0, -0.013953458466873759, 1e-9)  # the plate of 20261125/5, judged 1 nm under it
def test_tines_put_on_a_flat_tops_reference_are_not_inside_it(
        reach_m: float, top_m: float, under_m: float) -> None:
    """A flat top's law puts its reference on the surface exactly, never a rounding below:
    tines resting there read no contact, so not the damping at the speed they arrived with
    (the reference came out 2e-18 m under a mine's plate, read 238 N for one substep while
    the mount carried nothing)."""
    mine = Body(Contact.MINE, MineParams(reach_m=1.0, depth_m=-top_m, width_m=0.08))
    height_m = top_m - under_m
    law = mine.vertical_law(reach_m, height_m, height_m, DT_S)
    assert law is not None and law.ref_m >= mine.top_m
    assert mine._contact(reach_m, law.ref_m) is None
    assert not mine.touch(reach_m, law.ref_m, 0.0, -0.24, DT_S) and mine.force_up_n == 0.0


def test_a_tine_under_a_mine_rising_into_it_presses_its_bottom() -> None:
    """Inside a mine nearer its bottom than its top or sides, the tine presses the bottom:
    K·(height above the bottom) downward on the tine, recorded on the mine's body (not its
    plate: it does not fire), the ground's vertical reading untouched, ``lift_n`` set."""
    mine = MineParams(reach_m=1.0, depth_m=0.0, width_m=0.1, thickness_m=0.04,
                      activation_force_n=50.0)
    ground = Ground(GroundParams(objects=BuriedObjects(mines=(mine,))), seed=0)
    body = ground.bodies[0]
    above_bottom_m = 2e-5
    ground.step(1.01, -0.04 + above_bottom_m, 0.0, 0.0, 1e-3)  # met: K + B/h, then held
    force = ground.step(1.01, -0.04 + above_bottom_m, 0.0, 0.0, 1e-3)
    assert body._contact(1.01, -0.04 + above_bottom_m) == pytest.approx(
        (above_bottom_m, 0.0, -1.0))
    expected_n = mine.stiffness_n_per_m * above_bottom_m  # 100 N: over its fuse's 50 N
    assert body.force_up_n == pytest.approx(-expected_n)
    met_n = (mine.stiffness_n_per_m * (1.0 + mine.damping_time_s / 1e-3)) * above_bottom_m
    assert body.peak_side_n == pytest.approx(met_n) and body.peak_down_n == 0.0
    assert not body.activated and not ground.truth.mine_activated
    assert ground.truth.lift_n == pytest.approx(expected_n)
    assert force[1] == pytest.approx(ground.truth.force_down_n - expected_n)


def test_a_tine_in_a_roots_side_presses_the_soil_there_at_its_own_height() -> None:
    """A tine beside a root, below its rounded top, pushed 54 µm into its side: it is in the
    soil beside the root, so it meets that soil at its own height (the law the tine mount
    solves against, Soil.vertical_law), not the soil the root's top hides, 1 mm higher
    there: held at that height, the soil read 274.6 N with the mount carrying 21.4 N
    (20261128 edge 3311). Dropping 2 µm into the soil it carried down, it presses it by
    K·(interface − tine), the saw-tooth's remainder, by hand."""
    root = RootParams(reach_m=1.162, depth_m=0.029, width_m=0.02, thickness_m=0.02)
    g = ground(roots=(root,))
    body = g.bodies[0]
    z0_m = body.top_m - 0.0113  # below the root's centre line: its side is straight there
    outside_m, inside_m = body.right_m + 1e-6, body.right_m - 54e-6
    assert g.soil.cell_index(outside_m) == g.soil.cell_index(inside_m)
    g.step(outside_m, z0_m, 0.0, 0.0, DT_S)  # in the soil beside it: carried down to here
    interface_m = g.soil.interface_height_m
    contact = body._contact(inside_m, z0_m - 2e-6)
    assert contact is not None and contact[1:] == (1.0, 0.0)  # its side
    assert contact[0] == pytest.approx(54e-6)
    assert z0_m - 2e-6 < body.shield_m(inside_m) - 5e-4  # its top hides the soil 1 mm up
    assert not body.hides_soil_from(inside_m, z0_m - 2e-6)
    law = g.soil.vertical_law(inside_m, z0_m - 2e-6)
    g.step(inside_m, z0_m - 2e-6, 0.0, 0.0, DT_S)
    layer = SoilLayer()
    elastic_n = layer.stiffness_n_per_m * (interface_m - (z0_m - 2e-6))
    elastic_n -= math.floor(elastic_n / layer.collapse_force_n) * layer.collapse_force_n
    assert law is not None and law.ref_m == interface_m  # what the mount solves against
    assert g.soil.force_up_n == pytest.approx(elastic_n, rel=1e-6)
    assert g.truth.force_down_n == pytest.approx(elastic_n, rel=1e-6)  # the root: sideways


def test_a_tine_sliding_in_a_bottom_presses_the_soil_under_it_at_its_own_height() -> None:
    """A tine under a stone, 1 µm into its bottom (the mount pulling it up there), slides
    along the reach into the next soil cell: it is under the stone, so the soil it meets is
    the soil under it, at the tine's own height, not the soil the stone's top hides 30 mm
    higher (seen there, the soil's interface under it jumped up to the top and pushed the
    tines back into the bottom with a fresh saw-tooth: 20261128/2199). Dropping 2 µm there,
    it presses that soil by 2 µm: K·2 µm."""
    stone = StoneParams(reach_m=1.0, depth_m=0.02, width_m=0.1, thickness_m=0.03)
    g = ground(stones=(stone,))
    body, bottom_m = g.bodies[0], g.bodies[0].bottom_m
    g.step(1.0, bottom_m - 1e-6, 0.0, 0.0, DT_S)  # under it
    g.step(1.0, bottom_m + 1e-6, 0.0, 0.0, DT_S)  # 1 µm into its bottom
    assert not body.hides_soil_from(1.0, bottom_m + 1e-6)
    # the stone holds it down; met anew, elastic: (K + B/h)·1 µm
    assert g.truth.lift_n == pytest.approx((1e7 + 1e7 * 2e-4 / DT_S) * 1e-6)
    next_cell_m = 1.0 + 1.2 * g.soil.cell_m
    assert g.soil.cell_index(next_cell_m) != g.soil.cell_index(1.0)
    g.step(next_cell_m, bottom_m + 1e-6, 0.0, 0.0, DT_S)  # slid along, still in it
    law = g.soil.vertical_law(next_cell_m, bottom_m - 1e-6)
    assert law is not None and law.ref_m == bottom_m + 1e-6  # the interface: the tine's
    g.step(next_cell_m, bottom_m - 1e-6, 0.0, 0.0, DT_S)
    assert body._contact(next_cell_m, bottom_m - 1e-6) is None  # out of it again
    stiffness = SoilLayer().stiffness_n_per_m
    assert g.truth.force_down_n == pytest.approx(stiffness * 2e-6, rel=1e-6)
    assert body.hides_soil_from(1.0, body.top_m - 1e-6)  # just under its top: on it
    # held at its bottom by a mount pulling 20 N, the tine is held down with the soil's
    # push and that pull: the stone carries both (its record's peak so far, the meeting's
    # 30 N, cleared to read this one)
    body.peak_side_n = 0.0
    g.lifted(0, -20.0)
    assert body.peak_side_n == pytest.approx(20.0 + stiffness * 2e-6, rel=1e-9)
    assert g.truth.lift_n == body.peak_side_n
