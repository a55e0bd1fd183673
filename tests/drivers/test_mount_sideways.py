"""The tine mount's sideways solve against hand-worked balances (backward Euler, massless
tines): the mount relaxing, a side pressing (elastic, then capped), the soil's drag
(against a bisection of the balance, also where the drag turns over just as an edge lets
go), an edge the arm moves away from, and the laws taken again where the tines are."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from drivers.mount_sideways import SETTLED_M, Coupled, Drag, offset, read_as_assumed, relinearized
from drivers.objects import NormalLaw

K_H, C_H, H_S = 5000.0, 7.5, 1e-4  # the mount's default, a 0.1 ms substep
STIFF = K_H + C_H / H_S  # 80 000 N/m: what the mount opposes to e within one substep
NO_DRAG = Drag(0.0, 0.01)


def _side(depth_m: float, cap_n: float = math.inf, n_reach: float = -1.0) -> NormalLaw:
    """A rigid-ish side (10⁶ N/m, undamped) whose outward normal points along the reach."""
    return NormalLaw(depth_m, n_reach, 0.0, 1e6, 0.0, cap_n)


def _bisected(residual: Callable[[float], float], lo: float, hi: float) -> float:
    """The root of a rising residual in [lo, hi], by bisection alone."""
    assert residual(lo) < 0.0 < residual(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if residual(mid) < 0.0 else (lo, mid)
    return 0.5 * (lo + hi)


def test_with_nothing_pressing_the_mount_relaxes() -> None:
    """k·e + c·(e − e0)/h = 0: e = c·e0/(c + h·k)."""
    e0 = 1e-3
    e = offset(K_H, C_H, H_S, e0, [], NO_DRAG, 0.0, 0.0, e0)
    assert e == pytest.approx(C_H * e0 / (C_H + H_S * K_H), rel=1e-12)


def test_a_side_pressing_balances_the_mount() -> None:
    """A side 0.1 mm into the tines, pushing them toward the robot: S·e + K·(p0 + e) = 0,
    so e = −K·p0/(S + K), and the side carries what the mount does."""
    p0, k = 1e-4, 1e6
    coupled = [Coupled(0, _side(p0), (0.0, 0.0), (0.0, 0.0), 0.0, 0.0, H_S)]
    e = offset(K_H, C_H, H_S, 0.0, coupled, NO_DRAG, 0.0, 0.0, 0.0)
    assert e == pytest.approx(-k * p0 / (STIFF + k), rel=1e-12)
    assert k * coupled[0].penetration_m(e, 0.0) == pytest.approx(-STIFF * e, rel=1e-9)
    assert -STIFF * e == pytest.approx(7.407, abs=1e-3)


def test_a_capped_side_pushes_with_its_cap() -> None:
    """The same side yielding at 2 N (its elastic part would be 75 N): S·e = −2 N."""
    coupled = [Coupled(0, _side(1e-4, cap_n=2.0), (0.0, 0.0), (0.0, 0.0), 0.0, 0.0, H_S)]
    e = offset(K_H, C_H, H_S, 0.0, coupled, NO_DRAG, 0.0, 0.0, 0.0)
    assert e == pytest.approx(-2.0 / STIFF, rel=1e-12)


def test_the_drag_balances_the_mount_as_a_bisection_finds() -> None:
    """The arm moving at 0.1 m/s along the reach through soil resisting with 10 N
    (tanh over 0.01 m/s): S·e − c·e0/h + H·tanh((v + (e − e0)/h)/v_s) = 0, the root
    bracketed and bisected here on its own."""
    resist_n, smooth, v, e0 = 10.0, 0.01, 0.1, 2e-5
    drag = Drag(resist_n, smooth)

    def residual(e: float) -> float:
        return STIFF * e - C_H * e0 / H_S + resist_n * math.tanh((v + (e - e0) / H_S) / smooth)

    e = offset(K_H, C_H, H_S, e0, [], drag, v, 0.0, e0)
    assert e == pytest.approx(_bisected(residual, -1.0, 1.0), abs=1e-15)
    assert abs(residual(e)) < 1e-6


def test_where_the_drag_turns_over_as_an_edge_lets_go_the_balance_is_still_found() -> None:
    """20261128/6387's substep, as its solve met it: tines on a stone's rounded edge
    (normal 27° from vertical, met anew: 5·10⁷ N/m), the arm moving on at 0.057 m/s, the
    soil's 4.51 N drag turning over within 0.5 µm of offset (v_s = 0.01 m/s, h = 50 µs)
    near where the edge lets go. Newton alone jumps between the two sides of the root
    for all its steps and stops 22 N out of balance with the stone pressing 39.8 N; the
    balance, bisected here on its own, has it pressing 4.0 N."""
    k, n_x, n_z, h = 5e7, 0.446476, 0.894796, 5e-5  # the arm's substep
    e0, d, v_arm, guess, drag_n = 182.0505e-6, 3456.2718e-6, 0.0568157, 177.7546e-6, 4.5079
    reference_m = 158640.82 / k  # the edge's penetration is reference − n·(e, d)
    edge = NormalLaw(reference_m, n_x, n_z, k, 0.0, math.inf)
    coupled = [Coupled(1, edge, (0.0, 0.0), (e0, d), v_arm, 0.0, h)]

    def pressing(e: float) -> float:
        return max(0.0, k * (reference_m - n_x * e - n_z * d))

    def residual(e: float) -> float:
        v = v_arm + (e - e0) / h
        return K_H * e + C_H * (e - e0) / h + drag_n * math.tanh(v / 0.01) - n_x * pressing(e)

    assert pressing(guess) == pytest.approx(39.8, abs=0.1)
    root = _bisected(residual, 170e-6, 190e-6)
    e = offset(K_H, C_H, h, e0, coupled, Drag(drag_n, 0.01), v_arm, d, guess)
    assert e == pytest.approx(root, abs=1e-12)
    assert abs(residual(e)) < 1e-4
    assert k * coupled[0].penetration_m(e, d) == pytest.approx(pressing(root), abs=1e-3)
    assert 0.0 < pressing(root) < 5.0


def test_the_laws_are_taken_again_where_the_tines_are() -> None:
    """A law read where its linearization puts the tines is settled; a new object joins,
    one the tines left keeps its last linearization, and a reading off by more than
    SETTLED_M is not settled."""
    at = (0.0, 0.0)
    left, kept = _side(1e-4), _side(2e-4, n_reach=1.0)
    coupled = [Coupled(1, left, at, at, 0.0, 0.0, H_S), Coupled(2, kept, at, at, 0.0, 0.0, H_S)]
    e = 5e-6  # the tines moved away from the robot: into side 1 (its normal toward the
    # robot) by e, out of side 2 by e
    same = {1: left._replace(depth_m=1e-4 + e), 2: kept._replace(depth_m=2e-4 - e)}
    assert read_as_assumed(coupled, same, e, 0.0)
    off = {1: left._replace(depth_m=1e-4 + e + 2 * SETTLED_M), 2: same[2]}
    assert not read_as_assumed(coupled, off, e, 0.0)
    joined = {2: same[2], 3: _side(3e-5)}
    assert not read_as_assumed(coupled, joined, e, 0.0)
    again = relinearized(coupled, joined, (e, 0.0), at, 0.0, 0.0, H_S)
    assert [c.index for c in again] == [1, 2, 3]
    assert again[0] is coupled[0]  # left: its last linearization
    assert again[1].penetration_m(e, 0.0) == pytest.approx(2e-4 - e, abs=1e-18)
    assert read_as_assumed(again, {**joined, 1: same[1]}, e, 0.0)


def test_an_edge_the_arm_leaves_along_the_reach_damps_what_the_tines_really_approach() -> None:
    """20261130/8268's substep, simplified: tines pressed 30 µm into a mine's rounded top
    edge near its side (normal 2.6° above the reach, toward the robot; 5·10⁶ N/m, B =
    1000 N·s/m), the arm descending at 0.5 m/s and moving toward the robot, away from the
    face, at 25 mm/s; no drag. The edge's force is K·p + B·(the tines' approach along its
    normal), as the ground reads it (drivers.objects.Body.touch), and the massless tines
    balance it against the mount. By hand, with d fixed at 0 and e0 = 0:

        n_x·[K·p0 − B·(n_x·v + n_z·v_z)] = (S + n_x²·(K + B/h))·e

    The linearized law once took only the arm's speed INTO the face along the reach
    (as an edge's vertical law must: drivers.objects.Body.vertical_law), so it balanced
    the edge 25 N harder than the ground then read it (the mine's side read low by B
    times the arm's speed away)."""
    k, b, p0, h = 5e6, 1000.0, 30e-6, H_S
    n_x, n_z = -math.cos(math.radians(2.6)), math.sin(math.radians(2.6))
    v, v_z = -0.025, -0.5  # the arm: toward the robot (away from the face), descending
    edge = NormalLaw(p0, n_x, n_z, k, b, math.inf)
    coupled = [Coupled(0, edge, (0.0, 0.0), (0.0, 0.0), v, v_z, h)]
    e = offset(K_H, C_H, h, 0.0, coupled, NO_DRAG, v, 0.0, 0.0)
    by_hand = n_x * (k * p0 - b * (n_x * v + n_z * v_z)) / (STIFF + n_x * n_x * (k + b / h))
    assert e == pytest.approx(by_hand, rel=1e-12)
    tine_v = v + e / h  # the tines' speed along the reach this substep (e0 = 0)
    read_n = k * (p0 - n_x * e) + b * -(n_x * tine_v + n_z * v_z)  # as the ground reads it
    assert n_x * read_n == pytest.approx(STIFF * e, rel=1e-9)  # the mount carries it
    # the law that took only a reach speed into the face: its balance, read by the ground,
    # leaves B·n_x²·v over (25 N toward the robot on the tines: the mine read that low)
    clipped = n_x * (k * p0 - b * n_z * v_z) / (STIFF + n_x * n_x * (k + b / h))
    read_clipped = k * (p0 - n_x * clipped) + b * -(n_x * (v + clipped / h) + n_z * v_z)
    assert n_x * read_clipped - STIFF * clipped == pytest.approx(-b * n_x * n_x * v, rel=1e-6)
    assert -b * n_x * n_x * v == pytest.approx(24.9, abs=0.1)
