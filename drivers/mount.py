"""The tines' compliant mount: massless tines on springs, solved implicitly each substep.

The tines hang below the arm's tip on a spring-damper vertically (k_v, c_v: pushed up
or pulled down alike, a hardware requirement since a lift into an object's bottom
must meet it through the mount too, ``TineMount.hooked``) and,
as a hardware requirement like the vertical one, sideways (k_h, c_h): whatever
they press, they press through the mount, so no contact is stiffer than the
mount along its normal (rakectl.core.clamp relies on it). The tines are
massless: the mount's force equals the ground's, k·δ + c·δ̇, and the arm feels
exactly what the mount carries.

Vertically the compression d is solved against the ground's piecewise-linear
laws (``drivers.soil.VerticalLaw``: the soil's interface with its saw-tooth
collapse, objects' tops with their yield), backward Euler, with an active set
(:func:`drivers.mount_vertical.compression`).

Sideways the tines' offset e along the reach is solved with it: the soil's drag
−H·tanh(v/v_s) on the tines (linearized at their last speed: one Newton step of a
monotone law, so implicit and stable) and every object whose side or rounded edge
the tines are in (``drivers.objects.NormalLaw``, F = K·p + B·ṗ along the normal n;
:func:`drivers.mount_sideways.offset`). An edge couples the two: eliminating e from
the sideways balance leaves, for each such object, a vertical law whose stiffness
and damping are scaled by γ = 1 − n_reach·E₁/n_up (E₁: how e moves with d), which
the vertical solve takes as it takes any other; e then follows exactly from the
sideways balance at the solved d (objects piecewise linear, never pulling). Objects
the solution reaches that were not in the set join it and the substep is solved
again (a side met within a substep is never read as a penetration spike). A side
stiffness of 0 keeps the tines rigid sideways (the model before it).

Massless tines on a lightly damped mount move fast once let go (F/c: a few m/s
sideways); the laws are linearized where the tines were, and a rounded edge
curves away from that line by s²/2ρ over a slide s. So a substep in which the
tines slide more than ``MAX_SLIDE_M`` relative to the arm is solved again in as
many parts (the arm's tip moving on at its speed), each met by the ground.
"""

from __future__ import annotations

import math
from typing import Any

from drivers.mount_sideways import SETTLED_M, Coupled, Drag, offset, read_as_assumed, relinearized
from drivers.mount_vertical import compression
from drivers.objects import NormalLaw
from drivers.soil import VerticalLaw

# Largest slide of the tines relative to the arm in one solve (a 20 µm slide strays
# 0.07 µm off a 3 mm edge: under 1 N on a stone).
MAX_SLIDE_M = 2e-5
MAX_PARTS = 64
# Rounds of taking the objects' laws again where the sideways solution put the tines.
_SIDE_ROUNDS = 6
# The drag's linearization is taken as settled once the tines' speed moved less than this
# between rounds (the laws' penetrations: mount_sideways.SETTLED_M).
_SETTLED_M_PER_S = 1e-4
# The least force the laws below must put on the mount for tines in an object's bottom to
# be pushed there by them rather than pulled up by the extended mount alone.
_PUSHED_N = 1e-6


def _bottom_of(law: tuple[int, float, float, float]) -> float:
    """A bottom law's height (``Ground.bottom_laws``: index, bottom, K, B)."""
    return law[1]


class TineMount:
    """The mount's state (compression d, sideways offset e) and its implicit solves."""

    def __init__(self, k_v: float, c_v: float, k_h: float, c_h: float, step_s: float
                 ) -> None:
        self.k_v, self.c_v, self.k_h, self.c_h = k_v, c_v, k_h, c_h
        self.step_s = step_s  # the solves' time step: the arm's substep, or a part of it
        self.compression_m = 0.0  # d > 0: tines pushed up; d < 0: pulled down (extended)
        self.offset_m = 0.0  # e > 0: tines pushed away from the robot
        self.tine_reach_vel_m_per_s = 0.0  # the tines' last speed along the reach
        self.hooked_on = -1  # the object whose bottom the last solve pressed (-1: none)
        self.resting_under = -1  # the object the laws below pressed the tines up to

    @property
    def vertical(self) -> bool:
        return self.k_v > 0.0

    @property
    def sideways(self) -> bool:
        return self.k_h > 0.0

    @property
    def under(self) -> int:
        """The object whose bottom holds the tines after the last solve (-1: none): pulled
        up to it by the extended mount (``hooked_on``) or pushed up to it by the ground
        below (``resting_under``). Massless, they are in balance: it carries what the
        ground below pushes plus what the mount pulls."""
        return self.hooked_on if self.hooked_on >= 0 else self.resting_under

    def reset(self) -> None:
        self.compression_m = self.offset_m = self.tine_reach_vel_m_per_s = 0.0
        self.hooked_on = self.resting_under = -1

    def solve(self, ground: Any, reach_m: float, height_m: float, reach_vel: float,
              height_vel: float) -> tuple[float, float]:
        """(e, d) at the end of this substep; the state is not yet updated (see commit)."""
        e0, d0, h = self.offset_m, self.compression_m, self.step_s
        start = (e0, d0)
        coupled = [Coupled(i, law, start, start, reach_vel, height_vel, h)
                   for i, law in ground.normal_laws(reach_m + e0, height_m + d0, h)]
        v_lin = self.tine_reach_vel_m_per_s
        d, e = d0, e0
        laws_at = math.nan  # where the vertical laws were taken (the tines' reach)
        for _ in range(_SIDE_ROUNDS):
            drag = Drag(*ground.drag_law(reach_m + e, height_m + d, v_lin))
            a_e, b_e = drag.balance(self.k_h, self.c_h, e0, reach_vel, v_lin, h)
            if math.isnan(laws_at):  # first round: where the linear solve puts the tines
                e_0, e_1 = self._elimination(coupled, a_e, b_e)
                laws_at = reach_m + e_0 - e_1 * d0
            else:
                laws_at = reach_m + e
            d = self._coupled_vertical(ground, coupled, a_e, b_e, laws_at, height_m,
                                       reach_vel, height_vel)
            e = offset(self.k_h, self.c_h, h, e0, coupled, drag, reach_vel, d, e)
            v_new = reach_vel + (e - e0) / h
            same_cell = ground.soil.cell_index(laws_at) == ground.soil.cell_index(reach_m + e)
            # the edges are curved and the drag is not linear: take every law again where
            # the tines now are (objects they reach join; ones they left keep their last
            # linearization) until what the solve assumed is what the ground will read
            inside = {i: law for i, law in ground.normal_laws(reach_m + e, height_m + d, h)}
            if (same_cell and abs(v_new - v_lin) < _SETTLED_M_PER_S
                    and read_as_assumed(coupled, inside, e, d)):
                break
            coupled = relinearized(coupled, inside, (e, d), start, reach_vel, height_vel, h)
            v_lin = v_new
        else:  # not settled: the tines sit on a soil cell's edge; hold them in the laws' cell
            soil = ground.soil
            low_m, high_m = soil.cell_edges_m(soil.cell_index(laws_at))
            e = min(max(e, low_m - reach_m), math.nextafter(high_m, -math.inf) - reach_m)
            d = self._held(ground, reach_m, height_m, reach_vel, height_vel, e)
        return e, d

    def _held(self, ground: Any, reach_m: float, height_m: float, reach_vel: float,
              height_vel: float, held_m: float) -> float:
        """d for tines held at offset ``held_m`` (a soil cell's edge), solved against every
        law there, the objects' laws taken again where the solution puts the tines until
        they read what it assumed.

        Where the drag jumps between two cells and the solve settles in neither, the tines
        stay on the edge between them, the drag taking any value between the two cells'
        (a sliding mode, as for Coulomb friction at rest): it takes what the sideways
        balance leaves, so the offset is held and only the vertical balance is solved,
        implicitly as any other, an object's edge as its face along the vertical (its
        height at this offset; n_up²·K, n_up²·B). The objects' edges then read exactly
        what the mount carries vertically (the holds before it: docs/safety-log.md,
        2026-11-28). The sliding mode holds only while what the balance leaves lies
        between the two cells' drags; where an edge's push exceeds both (a steep edge
        over weak soil, 20261128 edge 2761: 82.1 N on a mine's side, the drag 1.3 N),
        the held tines read more than they would sliding off it."""
        h, e0 = self.step_s, self.offset_m
        reach_rate_m_per_s = reach_vel + (held_m - e0) / h  # the tines' along the reach
        d = self.compression_m
        # each object's law as last read, and the compression it was read at
        read: dict[int, tuple[NormalLaw, float]] = {
            i: (law, d) for i, law in ground.normal_laws(reach_m + held_m, height_m + d, h)
            if law.n_up > 0.0}
        # the soil's and the tops' laws there: the same in every round (the offset is held)
        others: list[VerticalLaw] = ground.vertical_laws(
            reach_m + held_m, height_m, height_m + d, h, reach_vel, edges=False)
        for _ in range(_SIDE_ROUNDS):
            laws = list(others)
            for law, at_m in read.values():
                # the face's height at this offset, where the tines at compression
                # ``at_m`` read law.depth_m; its push along the reach folded in (a
                # constant: the offset is held)
                into_m_per_s = max(0.0, -law.n_reach * reach_rate_m_per_s)
                ref_m = (height_m + at_m + law.depth_m / law.n_up
                         + law.damping_ns_per_m * into_m_per_s
                         / (law.n_up * law.stiffness_n_per_m))
                n2 = law.n_up * law.n_up
                laws.append(VerticalLaw(ref_m, n2 * law.stiffness_n_per_m,
                                        n2 * law.damping_ns_per_m, law.cap_n * law.n_up,
                                        False))
            d_new = self._vertical(laws, height_m, height_vel)
            inside = {i: law for i, law in ground.normal_laws(reach_m + held_m,
                                                              height_m + d_new, h)
                      if law.n_up > 0.0}
            settled = read.keys() == inside.keys() and all(
                abs(law.depth_m - (read[i][0].depth_m - read[i][0].n_up * (d_new - read[i][1])))
                < SETTLED_M for i, law in inside.items())
            d = d_new
            if settled:
                break
            read.update({i: (law, d) for i, law in inside.items()})
        return d

    def hooked(self, ground: Any, tine_reach_m: float, height_m: float, height_vel: float,
               d: float) -> float:
        """d with the bottoms of the objects the tines are under, if any at the solved d:
        they push the tines down and the mount extends, a balance solved as the others
        (backward Euler, massless tines): −(k·d + c·ḋ) = K·(z − z_b) + B·ż, z the tines'
        height, if nothing else presses them.

        Tines the laws below (the soil, what ``d`` was solved against) pushed up into a
        bottom (rising: tines descending along a side into the corner where the bottom is
        the nearest face are not under it) are held there: they rest just under it, as
        under a rigid face (a mine's bottom, 5·10⁶ N/m, gives 2 µm to a soil's 11 N
        collapse force), and ``resting_under`` names it. Massless, they are in balance:
        it carries what the ground below pushes less what the mount carries, which the
        arm records (:attr:`under`, :meth:`drivers.ground.Ground.lifted`). Left out of
        the balance, the soil pushed them 34 µm into a mine's bottom, read as 172 N with
        the mount carrying 1.3 N (20261128/2199)."""
        laws: list[tuple[int, float, float, float]] = (
            ground.bottom_laws(tine_reach_m, height_m + d, self.step_s) if self.vertical else [])
        h, k, c, d0 = self.step_s, self.k_v, self.c_v, self.compression_m
        self.resting_under = -1
        if (laws and height_vel + (d - d0) / h > 0.0  # rising into it, not along a side
                and k * d + c * (d - d0) / h > _PUSHED_N):
            index, bottom_m, _, _ = min(laws, key=_bottom_of)
            rest = bottom_m - height_m
            while height_m + rest > bottom_m:
                rest = math.nextafter(rest, -math.inf)
            self.hooked_on, self.resting_under = -1, index
            return rest
        while laws:
            stiff = k + (c / h)
            rhs = c * d0 / h
            for _, bottom_m, k_b, b_b in laws:
                stiff += k_b + b_b / h
                rhs += b_b * d0 / h - k_b * (height_m - bottom_m) - b_b * height_vel
            hooked = rhs / stiff
            rate_m_per_s = height_vel + (hooked - d0) / h
            # a contact only pushes: a bottom the tines leave faster than it presses (a
            # compressed mount relaxing downward) carries nothing this substep
            pulling = [law for law in laws
                       if law[2] * (height_m + hooked - law[1]) + law[3] * rate_m_per_s <= 0.0]
            if not pulling:
                self.hooked_on = laws[0][0]
                # pushed out below the bottom by its damping alone: the tines rest on it
                lowest_m = _bottom_of(min(laws, key=_bottom_of)) - height_m
                return hooked if hooked > lowest_m else lowest_m
            laws = [law for law in laws if law not in pulling]
        self.hooked_on = -1
        return d

    def rebalanced(self, ground: Any, reach_m: float, height_m: float, reach_vel: float,
                   height_vel: float, e: float, d: float) -> float:
        """e for tines an object's bottom holds at ``d`` (:meth:`hooked` moved them there
        from where :meth:`solve` balanced them sideways): the sideways balance solved
        again at this d, every side or edge law taken again where the tines are until
        they read what it assumed. A bottom is flat and pushes only down, so along the
        reach the tines stay in balance between the mount, the soil's drag and any edge
        below them; left at the offset solved for the higher d, a stone's corner under a
        mine's bottom pushed them 1165 N along the reach while the mount carried 17 N
        (20261130/2428)."""
        h, start = self.step_s, (self.offset_m, self.compression_m)
        v_lin = reach_vel + (e - self.offset_m) / h
        coupled: list[Coupled] | None = None  # None: not yet solved at this d
        for _ in range(_SIDE_ROUNDS):
            inside = {i: law for i, law in ground.normal_laws(reach_m + e, height_m + d, h)}
            if coupled is not None and read_as_assumed(coupled, inside, e, d):
                break
            coupled = relinearized(coupled or [], inside, (e, d), start, reach_vel, height_vel,
                                   h)
            drag = Drag(*ground.drag_law(reach_m + e, height_m + d, v_lin))
            e = offset(self.k_h, self.c_h, h, self.offset_m, coupled, drag, reach_vel, d, e)
            v_lin = reach_vel + (e - self.offset_m) / h
        return e

    def commit(self, e: float, d: float, reach_vel: float) -> tuple[float, float]:
        """Take (e, d) as the new state; the mount's forces (sideways, vertical) on the arm."""
        h = self.step_s
        rate_e, rate_d = (e - self.offset_m) / h, (d - self.compression_m) / h
        self.offset_m, self.compression_m = e, d
        self.tine_reach_vel_m_per_s = reach_vel + rate_e
        side_n = self.k_h * e + self.c_h * rate_e
        return side_n, self.vertical_n(self.k_v * d + self.c_v * rate_d)

    def vertical_n(self, mount_n: float) -> float:
        """The mount's vertical force as the contacts allow it: an object's bottom the
        tines are under only pulls the arm down (≤ 0), tines held between a bottom and the
        ground below pass it either way, anything else only pushes the arm up."""
        if self.hooked_on >= 0:
            return mount_n if mount_n < 0.0 else 0.0
        if self.resting_under >= 0:
            return mount_n
        return mount_n if mount_n > 0.0 else 0.0

    def _elimination(self, coupled: list[Coupled], a_e: float, b_e: float
                     ) -> tuple[float, float]:
        """(E₀, E₁) with e = E₀ − E₁·d, every coupled law taken as pressing and elastic."""
        a, b, b_d = a_e, b_e, 0.0
        for c in coupled:
            a += c.beta * c.n_reach * c.n_reach
            b += c.n_reach * c.alpha
            b_d += c.beta * c.n_reach * c.n_up
        return b / a, b_d / a

    def _coupled_vertical(self, ground: Any, coupled: list[Coupled], a_e: float, b_e: float,
                          tine_reach_m: float, height_m: float, reach_vel: float,
                          height_vel: float) -> float:
        """d, with each edge's law folded through the sideways balance into a vertical one;
        the soil's and the tops' laws where the tines are (``tine_reach_m``)."""
        if not self.vertical:
            return 0.0
        d0, h = self.compression_m, self.step_s
        e_0, e_1 = self._elimination(coupled, a_e, b_e)
        laws: list[VerticalLaw] = ground.vertical_laws(
            tine_reach_m, height_m, height_m + d0, h, reach_vel, edges=False)
        for c in coupled:
            if c.n_up <= 0.0:
                continue  # a side: only the sideways balance feels it
            gamma = 1.0 - c.n_reach * e_1 / c.n_up
            if gamma <= 0.0:
                continue
            k_z = gamma * c.n_up * c.n_up * c.stiffness_n_per_m
            b_z = gamma * c.n_up * c.n_up * c.damping_ns_per_m
            constant_n = c.n_up * (c.alpha - c.beta * c.n_reach * e_0)
            ref_m = height_m + (constant_n - b_z * (d0 / h - height_vel)) / k_z
            laws.append(VerticalLaw(ref_m, k_z, b_z, c.cap_n * c.n_up, False))
        return self._vertical(laws, height_m, height_vel)

    def _vertical(self, laws: list[VerticalLaw], height_m: float, height_vel_m_per_s: float
                  ) -> float:
        """The mount's compression at the end of this substep against ``laws``
        (:func:`drivers.mount_vertical.compression`)."""
        return compression(self.k_v, self.c_v, self.step_s, self.compression_m, laws,
                           height_m, height_vel_m_per_s)
