"""The lane's depth of cut, planned per bin of reach (pure).

A lane is not equally hard everywhere: far from the robot the arm holds the
tine down well, near it the clamp caps the hold-down and the tine rides up.
So the depth the next stroke goes to is planned per 20 mm of reach, from the
force, the lag and the floor the last stroke really met there (see
:class:`CutProfile`); the lane planner (:mod:`rakectl.core.lane`) follows it.
"""

from __future__ import annotations

import math

from rakectl.config.settings import LaneSettings
from rakectl.core.governor import next_depth_step_m

# The lane's depths are planned per bin of reach this wide (about two tine widths), in at
# most MAX_BINS bins (wider on a long lane): planning the next stroke takes ~3 µs per bin,
# in the daemon's tick where a stroke ends.
BIN_M = 0.02
MAX_BINS = 64
# An adaptive stroke's reference never descends toward the robot (a descent in soil reads as
# force, K_e·α·v: 2000 N per m/s) and rises at most this much per metre of reach (0.025 m/s
# at the top stroke speed: the tip follows without lag).
RISE_PER_M = 0.1
# A bin's next cut is the smallest of its own and of this many bins on either side: the
# force and lag met in one bin are a sample of the soil around it.
WINDOW_BINS = 2
# An adaptive cut that would leave less than this share of depth_step_m above the target
# goes to the target: a whole cycle for a sliver costs more than the sliver's load.
SLIVER_SHARE = 0.5
# An adaptive lane's bin is done once a stroke at the target depth went through it and the
# tip really was within this of the target there, or after a second stroke at the target
# (the tine rides up where the clamp caps its hold-down: one more pass, not a loop).
FLOOR_TOLERANCE_M = 0.003
# A bin is done to its descent cap (CutProfile.apply_caps) when it is within this of it and
# the cap deepened by no more than this since the last stroke.
STUCK_M = 1e-4


class CutProfile:
    """The lane's depths per bin of reach, bin 0 nearest the robot (pure).

    ``plan_m`` is the next (or current) stroke's reference depth, ``done_m`` the deepest
    stroke completed, ``left_m`` the shallowest measured tip depth the last stroke through
    each bin left (ground level 0 before any). A stroke starts at the far edge of the
    farthest bin not yet done to the target depth (``start``) and ends at the lane's near end.

    After each stroke (:meth:`finish`), a fixed lane plans every bin one ``depth_step_m``
    deeper. An adaptive lane plans each bin's cut, counted from the floor the tip left there,
    by :func:`~rakectl.core.governor.next_depth_step_m` on the force and lag met in that bin and
    the cut it really took (the smallest over WINDOW_BINS on either side), and never less
    than ``depth_step_m`` below what was done. The plan is then shaped: not deeper than
    the target, not descending toward the robot, rising at most RISE_PER_M; a bin that
    would be left less than SLIVER_SHARE of a step short of the target goes to it; on an
    adaptive lane a bin at the target whose measured floor is more than FLOOR_TOLERANCE_M
    short gets one more stroke. The shaping keeps every bin not yet done at least
    ``min(target, done + depth_step_m)`` deep (the done depths are themselves
    non-descending and within the rise: each plan was), so every stroke makes progress.
    """

    __slots__ = ("_adaptive", "_at_target", "_force_n", "_lag_m", "_max_step_m", "_min_step_m",
                 "_strokes", "_stuck", "_target_m", "_tip_m", "cap_m", "done_m", "left_m", "n_bins",
                 "near_m", "plan_m", "start", "width_m")

    def __init__(self, lane: LaneSettings) -> None:
        span_m = lane.reach_far_m - lane.reach_near_m
        if not span_m > 0.0:
            raise ValueError("lane: reach_far_m must be > reach_near_m")
        self.n_bins = min(MAX_BINS, max(1, math.ceil(span_m / BIN_M - 1e-9)))
        self.width_m = span_m / self.n_bins
        self.near_m = lane.reach_near_m
        self._adaptive = lane.adaptive
        self._target_m = lane.target_depth_m
        self._min_step_m, self._max_step_m = lane.depth_step_m, lane.max_depth_step_m
        n = self.n_bins
        self.plan_m = [min(lane.depth_step_m, lane.target_depth_m)] * n
        self.done_m = [0.0] * n
        self.left_m = [0.0] * n
        self.start = n - 1
        self._at_target = [0] * n  # strokes at the target depth through each bin
        self._tip_m = [math.inf] * n  # this stroke's shallowest measured tip per bin
        self._force_n = [-math.inf] * n  # this stroke's peak force estimate per bin
        self._lag_m = [0.0] * n  # this stroke's peak lag per bin
        self.cap_m = [math.inf] * n  # the deepest the descent limiter allows per bin
        self._stuck = [False] * n  # can go no deeper within its cap (apply_caps)
        self._strokes = [0] * n  # strokes through each bin

    def apply_caps(self, cap_m: list[float]) -> None:
        """The descent limiter's deepest allowed depth per bin (the ground map's floor, as
        the strokes so far have lowered it): the plan goes no deeper. A bin that strokes
        have been through, whose cap did not deepen since the last one and whose plan,
        capped and shaped, takes it no deeper than done, can go no further (beside soil no
        stroke crosses: the lane's ends, terraced) and is finished there."""
        n = self.n_bins
        deepened = [cap_m[b] > self.cap_m[b] + STUCK_M for b in range(n)]
        self.cap_m = list(cap_m)
        self._stuck = [False] * n
        capped = [min(p, c) for p, c in zip(self.plan_m, cap_m, strict=True)]
        rise_m = RISE_PER_M * self.width_m
        for _ in range(n):
            plan = list(capped)
            start = n - 1
            while start >= 0 and self._finished(start):
                start -= 1
            for b in range(1, start + 1):  # the shaping of finish() over the stroke's bins
                plan[b] = min(plan[b], plan[b - 1] + rise_m)
            for b in range(start - 1, -1, -1):
                plan[b] = min(plan[b], plan[b + 1])
            stuck = [b for b in range(start + 1)
                     if self._strokes[b] and not deepened[b] and not self._stuck[b]
                     and plan[b] <= self.done_m[b] + STUCK_M
                     and self.done_m[b] < self._target_m - 1e-9]
            if not stuck:
                break
            for b in stuck:
                self._stuck[b] = True
        self.plan_m = plan
        self.start = start

    def bin_of(self, reach_m: float) -> int:
        b = int((reach_m - self.near_m) / self.width_m)
        return 0 if b < 0 else (self.n_bins - 1 if b >= self.n_bins else b)

    @property
    def complete(self) -> bool:
        return self.start < 0

    @property
    def held(self) -> bool:
        """Whether a bin was finished short of the target, at its descent cap."""
        return any(self._stuck)

    @property
    def start_reach_m(self) -> float:
        return self.near_m + (self.start + 1) * self.width_m

    @property
    def start_depth_m(self) -> float:
        return self.plan_m[self.start]

    def depth_and_slope_at(self, reach_m: float) -> tuple[float, float]:
        """The stroke's reference depth at ``reach_m`` and its slope d(depth)/d(reach) (≥ 0:
        the plan never descends toward the robot): linear between the bins' centres, the
        start bin's depth beyond its centre."""
        x = (reach_m - self.near_m) / self.width_m - 0.5
        plan = self.plan_m
        if x >= self.start:
            return plan[self.start], 0.0
        if x <= 0.0:
            return plan[0], 0.0
        b = int(x)
        rise_m = plan[b + 1] - plan[b]
        return plan[b] + (x - b) * rise_m, rise_m / self.width_m

    def landing_m(self, band_m: float) -> float:
        """Shallowest floor a descent at the start meets: done there, and what the tip left
        within ``band_m`` on the robot's side of the start."""
        start = self.start
        lowest = self.bin_of(self.start_reach_m - band_m + 1e-9)
        return min(self.done_m[start], min(self.left_m[lowest:start + 1]))

    def record(self, reach_m: float, depth_m: float, lag_m: float) -> None:
        """The measured tip and its lag, each tick of a stroke."""
        b = self.bin_of(reach_m)
        if depth_m < self._tip_m[b]:
            self._tip_m[b] = depth_m
        if lag_m > self._lag_m[b]:
            self._lag_m[b] = lag_m

    def record_force(self, reach_m: float, force_n: float) -> None:
        """A stroke's force estimate where the tip is (a non-finite one sticks as nan)."""
        b = self.bin_of(reach_m)
        if not math.isfinite(force_n):
            self._force_n[b] = math.nan
        elif force_n > self._force_n[b]:
            self._force_n[b] = force_n

    def finish(self, force_target_n: float, lag_target_m: float) -> None:
        """A stroke ended at the lane's near end: plan the next one (see the class)."""
        n, target = self.n_bins, self._target_m
        seen = list(range(self.start + 1))  # the stroke ran from the start to the near end
        for b in seen:
            self._strokes[b] += 1
            self.done_m[b] = max(self.done_m[b], self.plan_m[b])
            self._at_target[b] += self.plan_m[b] >= target - 1e-9
            if self._tip_m[b] == math.inf:  # not observed: taken to be on its reference
                self._tip_m[b] = self.plan_m[b]
        want = [target] * n
        if self._adaptive and math.isfinite(force_target_n):
            cut = self._next_cuts(seen, force_target_n, lag_target_m)
            sliver_m = SLIVER_SHARE * self._min_step_m
            for b in seen:
                want[b] = max(self.done_m[b] + self._min_step_m, self._tip_m[b] + cut[b])
                if want[b] > target - sliver_m:  # not a cycle for what is left
                    want[b] = target
        else:
            for b in range(n):
                want[b] = self.done_m[b] + self._min_step_m
        for b in seen:
            self.left_m[b] = self._tip_m[b]
        plan = [min(target, w) for w in want]
        rise_m = RISE_PER_M * self.width_m
        for b in range(1, n):  # rising at most RISE_PER_M away from the robot
            plan[b] = min(plan[b], plan[b - 1] + rise_m)
        for b in range(n - 2, -1, -1):  # never descending toward it
            plan[b] = min(plan[b], plan[b + 1])
        self.plan_m = plan
        start = n - 1
        while start >= 0 and self._finished(start):
            start -= 1
        self.start = start
        self._tip_m = [math.inf] * n
        self._force_n = [-math.inf] * n
        self._lag_m = [0.0] * n

    def _finished(self, b: int) -> bool:
        if self._stuck[b]:
            return True
        if self.done_m[b] < self._target_m - 1e-9:
            return False
        return (not self._adaptive or self._at_target[b] >= 2
                or self.left_m[b] >= self._target_m - FLOOR_TOLERANCE_M)

    @property
    def depth_reached_m(self) -> float:
        """The lane's depth where it is least deep: the depth done, except that a bin an
        adaptive lane has not finished counts where the tip really left it."""
        return min(d if self._finished(b) else min(d, self.left_m[b])
                   for b, d in enumerate(self.done_m))

    def _next_cuts(self, seen: list[int], force_target_n: float,
                   lag_target_m: float) -> list[float]:
        """Each seen bin's next cut (adaptive): the depth law on the cut it took."""
        n = self.n_bins
        force = list(self._force_n)
        carried = -math.inf  # a bin with no sample (the plunge's tail) takes its neighbour's
        for b in seen:
            if force[b] == -math.inf:
                force[b] = carried
            else:
                carried = force[b]
        for b in reversed(seen):
            if force[b] == -math.inf:
                force[b] = carried
            else:
                carried = force[b]
        own = [math.inf] * n
        for b in seen:
            took_m = max(self.plan_m[b] - self.left_m[b], self._min_step_m)
            peak_n = force[b] if force[b] != -math.inf else math.nan  # none: the least cut
            own[b] = next_depth_step_m(took_m, peak_n, force_target_n, self._lag_m[b],
                                       lag_target_m, self._min_step_m, self._max_step_m)
        return [min(own[max(0, b - WINDOW_BINS):b + WINDOW_BINS + 1]) for b in range(n)]
