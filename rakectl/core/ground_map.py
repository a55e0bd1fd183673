"""What the controller knows of the soil along the reach, and how low the tines may go (pure).

The descent budget (:mod:`rakectl.core.descent`): wherever the tines are, the soil
beside them within ``side_reach_m`` (as far as an object's edge can push them) must
not stand more than that soil's step d* above them, or an edge forcing them into it
meets more cutting resistance than the clamp leaves for it. So the lowest height the
tines may take at cell i is

    floor_i = max over |j − i| ≤ side cells of top_j − d*,

``top_j`` the highest the soil can stand in cell j and d* the cut at which the
declared soil's resistance reaches the budget (a step below the deepest cut meets a
layer no stroke has measured, so no step measured from the strokes may replace it).

``top`` starts at the surveyed surface where a survey covers the cell (the higher of
the two survey points bracketing each part of it), at the configured ceiling (the
highest the surface stands anywhere in the workspace) elsewhere, and only comes down,
one way: tines that crossed a whole cell, in one
pass from one of its edges to the other, cut away every soil above the highest point
of that pass (:meth:`GroundMap.track`). A vertical plunge lowers nothing: the soil
beside a tine's path stays. Heights are above ground level 0 (up positive); the
caller adds to the tip's height what the tines may stand above it (the mount's
deflection) before handing it in.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

from rakectl.core.descent import TRACKING_MARGIN_M

CELL_M = 0.005  # the map's resolution along the reach: the width of an edge's sideways push


class GroundMap:
    """Per cell of CELL_M along the reach: the highest soil (``top_m``) and the lowest
    height the tines may take (``floor_m``), ``first_step_m`` (d*) below it."""

    __slots__ = ("_cell", "_entered_from", "_highest_m", "_initial_top_m", "_reach_min_m",
                 "_side_cells", "ceiling_m", "first_step_m", "floor_m", "n_cells", "top_m")

    def __init__(self, reach_min_m: float, reach_max_m: float, ceiling_m: float,
                 first_step_m: float, side_reach_m: float,
                 survey: Sequence[tuple[float, float]] = ()) -> None:
        """``survey``: (reach, height) points of the surface in increasing reach, none
        above ``ceiling_m`` (rakectl.config.descent checks both)."""
        if not (reach_max_m > reach_min_m and first_step_m > 0.0 and side_reach_m >= 0.0
                and math.isfinite(ceiling_m)):
            raise ValueError("GroundMap: needs reach_max_m > reach_min_m, first_step_m > 0, "
                             "side_reach_m >= 0 and a finite ceiling_m")
        self._reach_min_m = reach_min_m
        self.n_cells = math.ceil((reach_max_m - reach_min_m) / CELL_M - 1e-9) + 1
        self._side_cells = math.ceil(side_reach_m / CELL_M - 1e-9)
        self.ceiling_m = ceiling_m
        self.first_step_m = first_step_m
        self._initial_top_m = self._surveyed(survey)
        self.top_m, self.floor_m = [0.0] * self.n_cells, [0.0] * self.n_cells
        self.reset()  # both from the survey (or the ceiling)

    def _surveyed(self, survey: Sequence[tuple[float, float]]) -> list[float]:
        """Each cell's top before any pass: the highest survey point within it or
        bracketing it, where the survey spans the whole cell; the ceiling elsewhere."""
        reaches = [reach_m for reach_m, _ in survey]
        tops = [self.ceiling_m] * self.n_cells
        for i in range(self.n_cells):
            low_m = self._reach_min_m + i * CELL_M
            high_m = low_m + CELL_M
            if not reaches or low_m < reaches[0] or high_m > reaches[-1]:
                continue
            first = max(0, bisect.bisect_right(reaches, low_m) - 1)
            last = min(len(reaches) - 1, bisect.bisect_left(reaches, high_m))
            tops[i] = min(self.ceiling_m, max(h for _, h in survey[first:last + 1]))
        return tops

    def reset(self) -> None:
        """Forget every pass (the platform may have moved): the survey, or the ceiling."""
        self.top_m[:] = self._initial_top_m
        for i in range(self.n_cells):
            self._refresh_floor(i)
        self._cell = -1  # the cell the tines are in, -1 before the first track()
        self._entered_from = 0  # -1: from the cell below, +1: from above, 0: not by an edge
        self._highest_m = -math.inf

    def cell(self, reach_m: float) -> int:
        """The cell at ``reach_m`` (the end cells beyond the map)."""
        i = math.floor((reach_m - self._reach_min_m) / CELL_M)
        return 0 if i < 0 else self.n_cells - 1 if i >= self.n_cells else i

    def floor_at_m(self, reach_m: float) -> float:
        """The lowest height the tines may take at ``reach_m``."""
        return self.floor_m[self.cell(reach_m)]

    def track(self, reach_m: float, height_m: float) -> None:
        """The tines are at (``reach_m``, ``height_m``) this tick; a cell they have just
        crossed whole, in one pass, is lowered to the highest point of that pass."""
        i = self.cell(reach_m)
        if i == self._cell:
            if height_m > self._highest_m:
                self._highest_m = height_m
            return
        step = i - self._cell
        if self._cell >= 0 and abs(step) == 1:
            if self._entered_from == -step:  # in by one edge, out by the other
                self.lower(self._cell, self._highest_m)
            self._entered_from = -step
            self._highest_m = height_m
        else:  # the first tick, or a jump: no pass to count
            self._entered_from = 0
            self._highest_m = height_m
        self._cell = i

    def lower(self, i: int, height_m: float) -> None:
        """No soil stands above ``height_m`` in cell ``i``."""
        if height_m < self.top_m[i]:
            self.top_m[i] = height_m
            self._refresh(i)

    def _refresh(self, i: int) -> None:
        side = self._side_cells
        for k in range(max(0, i - side), min(self.n_cells, i + side + 1)):
            self._refresh_floor(k)

    def _refresh_floor(self, k: int) -> None:
        side = self._side_cells
        self.floor_m[k] = max(self.top_m[max(0, k - side):k + side + 1]) - self.first_step_m


# The joint loops hold the tip up to about 0.4 mm below a still reference (their
# proportional term carries the load until the integrator takes it over): the limiter
# raises its hold by an integral of how far the measured tip is below the floor, at this
# rate (well under the loops' bandwidth), at most OFFSET_MAX_M.
OFFSET_GAIN_PER_S = 30.0
OFFSET_MAX_M = 0.005
# A reference held at the floor leads the measured tip down by at most this much, and is
# held above it by the distance the tip needs to stop from its measured descent at
# BRAKE_M_PER_S2: the tip, however fast it came, approaches the floor in small steps.
LEAD_M = 0.001
BRAKE_M_PER_S2 = 0.5


class DescentLimiter:
    """Holds a depth reference above the map's floor, at the reference's reach and at the
    measured one (the higher of the two); tines below it, where the floor rose under them
    (a pass moving toward higher soil, a map reset), are raised to it."""

    __slots__ = ("_gain", "clipped", "map", "offset_m")

    def __init__(self, ground: GroundMap, dt_s: float) -> None:
        self.map = ground
        self._gain = OFFSET_GAIN_PER_S * dt_s
        self.offset_m = 0.0  # how far above the floor the hold is raised
        self.clipped = 0  # ticks whose reference was held up

    def reset(self) -> None:
        """Start afresh (arming)."""
        self.offset_m = 0.0
        self.clipped = 0

    def limit_at_m(self, reach_m: float) -> float:
        """The deepest the floor allows at one reach, less the tracking margin: where a
        planner plans (a depth: below level 0, down positive)."""
        return -self.map.floor_at_m(reach_m) - TRACKING_MARGIN_M

    def limit_depth_m(self, reach_ref_m: float, reach_m: float) -> float:
        """The deepest the floor allows at both reaches, less the tracking margin (depth:
        below level 0, down positive)."""
        return -max(self.map.floor_at_m(reach_ref_m),
                    self.map.floor_at_m(reach_m)) - TRACKING_MARGIN_M

    def clip(self, depth_ref_m: float, reach_ref_m: float, reach_m: float,
             depth_m: float, depth_rate_m_per_s: float) -> float:
        """``depth_ref_m`` or the deepest allowed: the floor's, raised by the offset that
        keeps the measured tip (``depth_m``) on it and by the tip's braking distance from
        its descent (``depth_rate_m_per_s``, > 0 down), and at most LEAD_M below the tip."""
        limit_m = self.limit_depth_m(reach_ref_m, reach_m)
        offset_m = self.offset_m + self._gain * (depth_m - limit_m)
        self.offset_m = 0.0 if offset_m < 0.0 else min(offset_m, OFFSET_MAX_M)
        allowed_m = limit_m - self.offset_m
        if depth_rate_m_per_s > 0.0:
            allowed_m -= depth_rate_m_per_s * depth_rate_m_per_s / (2.0 * BRAKE_M_PER_S2)
        if depth_ref_m > allowed_m:
            self.clipped += 1
            depth_ref_m = allowed_m if allowed_m < depth_m + LEAD_M else depth_m + LEAD_M
        return depth_ref_m
