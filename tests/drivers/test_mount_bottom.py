"""Tines held at an object's bottom, against hand-computed references: what holds them
there and what keeps them in balance along the reach."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from drivers.ground import Ground
from drivers.ground_params import BuriedObjects, GroundParams, MineParams, StoneParams
from drivers.mount import TineMount
from drivers.soil_params import SoilLayer, SoilParams

AIR = SoilParams(layers=(SoilLayer(stiffness_n_per_m=1.0, collapse_force_n=1e-3,
                                   cohesion_pa=0.0, unit_weight_n_per_m3=1.0),),
                 surface_slope=0.0, stiffness_rel_std=0.0, strength_rel_std=0.0,
                 lane_reach_max_m=2.0)


def _bisect(residual: Callable[[float], float], low: float, high: float) -> float:
    """The root of ``residual`` between ``low`` and ``high`` (signs differ there)."""
    f_low = residual(low)
    for _ in range(200):
        mid = 0.5 * (low + high)
        f_mid = residual(mid)
        if (f_mid > 0.0) == (f_low > 0.0):
            low, f_low = mid, f_mid
        else:
            high = mid
    return 0.5 * (low + high)


def test_tines_a_bottom_holds_over_an_edge_stay_in_balance_along_the_reach() -> None:
    """Massless tines pushed up a stone's rounded corner (5 mm) into a mine's bottom just
    above it, 20 µm into the corner, the arm rising at 0.02 m/s, the mount at rest. The
    bottom holds them just under it (flat: it pushes only down), so along the reach
    they must balance the mount against the corner's push at that height. By hand, at
    the bottom's height z_b: k_h·e + c_h·ė = n_x·(K·p + B·ṗ) with p = ρ − |(x, z_b) − c|
    (c the corner's centre, n its outward normal there), solved by bisection; the
    ground's own reading then equals what the mount carries. Left at the offset solved
    for the tines inside the bottom, the corner reads 16.9 N here against the mount's
    0.3 N; in the campaign it read 1165 N against 17 N (20261130/2428)."""
    k_v, c_v, k_h, c_h, h = 5e3, 7.5, 5e3, 7.5, 5e-5
    rho = 0.005
    mine = MineParams()
    bottom_m = -(mine.depth_m + mine.thickness_m)
    stone = StoneParams(reach_m=0.99, depth_m=-(bottom_m + 0.001), width_m=0.05,
                        thickness_m=0.03, edge_radius_m=rho)  # its corner 1 mm into the mine
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,),
                                                                 mines=(mine,))), seed=0)
    body = ground.bodies[0]
    x_c, z_c = body.right_m - rho, body.top_m - rho
    z0 = bottom_m - 2e-6
    x0 = x_c + math.sqrt((rho - 2e-5) ** 2 - (z0 - z_c) ** 2)  # 20 µm into the corner
    body.touching = True  # in it at the last reading
    e0, d0, rise = 0.0, 0.0, 0.02
    arm_reach, arm_height = x0 - e0, z0 - d0
    mount = TineMount(k_v, c_v, k_h, c_h, h)
    mount.offset_m, mount.compression_m = e0, d0

    e, d = mount.solve(ground, arm_reach, arm_height, 0.0, rise)
    assert arm_height + d > bottom_m  # solved against the corner alone: inside the mine
    held = mount.hooked(ground, arm_reach + e, arm_height, rise, d)
    assert mount.resting_under == 1  # the mine's bottom holds them
    assert 0.0 <= bottom_m - (arm_height + held) < 1e-15
    e = mount.rebalanced(ground, arm_reach, arm_height, 0.0, rise, e, held)

    k_s, b_s = stone.stiffness_n_per_m, stone.stiffness_n_per_m * stone.damping_time_s
    z, d_rate = arm_height + held, rise + (held - d0) / h

    def residual(offset_m: float) -> float:
        q_x, q_z = arm_reach + offset_m - x_c, z - z_c
        dist = math.hypot(q_x, q_z)
        n_x, n_z = q_x / dist, q_z / dist
        e_rate = (offset_m - e0) / h
        normal_n = max(0.0, k_s * (rho - dist) - b_s * (n_x * e_rate + n_z * d_rate))
        return k_h * offset_m + c_h * e_rate - n_x * normal_n

    exit_m = x_c + math.sqrt(rho ** 2 - (z - z_c) ** 2) - arm_reach
    expected = _bisect(residual, e0, exit_m)
    assert e == pytest.approx(expected, abs=2e-8)

    side_n, _ = mount.commit(e, held, 0.0)
    ground.step(arm_reach + e, z, (e - e0) / h, d_rate, h)
    drag_n = ground.drag_law(arm_reach + e, z, (e - e0) / h)[0]
    assert abs(drag_n) < 0.01  # the air around them drags next to nothing
    assert side_n > 0.1
    assert ground.truth.force_drag_n == pytest.approx(side_n, rel=0.01)  # in balance
