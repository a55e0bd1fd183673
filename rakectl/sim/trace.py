"""One campaign case traced substep by substep: where an object pushed the tines
hardest along the reach, and what pushed back.

The tines are massless (drivers.mount): along the reach, what an object pushes them
with, the soil and the mount push back with, in every substep. Where an object's
rounded edge forces descending tines sideways, the soil's share is its cutting
resistance H at the tines' cut (docs/safety.md, "Not covered"); a substep that does
not balance, or a share the soil's resistance cannot account for, is the emulator's
to explain, not the controller's.

:class:`TracingRecorder` stands in for the loop's
:class:`~rakectl.sim.rake_plant.PeakRecorder` (the ground as the arm meets it, once per
part of a substep) and reads, after each call in which an object pushes the tines:
where the tines are and how fast, each object's force on them (a row per object, with
what the others push in the same call), the soil's, and the
mount's (its spring k_h·e and damper c_h·ė on the sideways offset e, as
``drivers.mount.TineMount.commit`` sets them), with the soil's cut ahead of them.
It also keeps, call by call, the ground's vertical reading (the truth the campaign
judges: what an object and the soil push the tines up with, at least what the mount
carried into the ground, ``Ground.transmitted``) beside what the mount carried: massless
tines press the ground with what their mount carries, so a reading well over it is the
emulator's, not the controller's. Around the largest reading it shows the parts, and
whether the soil was pressed by the tines or by an object that hides it from them
(``Body.hides_soil_from``: the soil is then pressed by the object's surface at the tines'
reach, as ``Ground.step`` takes it).
It only reads: a traced case runs exactly as the campaign runs it, to the same
result, compiled physics or not.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque

from drivers.arm import ArmPlant
from drivers.ground import Ground
from rakectl.sim import campaign
from rakectl.sim.cases import FuzzCase
from rakectl.sim.edge import resistance_n
from rakectl.sim.injection import FaultyRakeLoop
from rakectl.sim.rake_plant import PeakRecorder
from rakectl.sim.results import CaseResult

WINDOW = 4  # substeps shown on either side of the largest push


@dataclasses.dataclass(frozen=True, slots=True)
class SubstepForces:
    """One call of the ground in which object ``body`` pushed the tines. Forces are ON
    the tines, along the reach (> 0 away from the robot) and up; heights and speeds
    up positive."""

    time_s: float  # the tick's start, from the case's (as CaseResult.f_true_z_max_t_s)
    part: int  # the call within the tick (a substep, or a part of one)
    body: int  # index in Ground.bodies
    tine_reach_m: float
    tine_height_m: float
    tine_reach_vel_m_per_s: float
    tine_height_vel_m_per_s: float
    body_reach_n: float
    body_up_n: float
    others_reach_n: float  # the other objects pushing the tines in the same call
    soil_reach_n: float
    soil_up_n: float
    mount_reach_n: float
    cut_m: float  # the soil's cut ahead of the tines (drivers.soil.Soil.cut_depth_m)

    @property
    def residual_n(self) -> float:
        """What the massless tines' balance along the reach leaves over (0 when it holds)."""
        return self.body_reach_n + self.others_reach_n + self.soil_reach_n + self.mount_reach_n


@dataclasses.dataclass(frozen=True, slots=True)
class GroundReading:
    """One call of the ground: its vertical reading and its parts. Forces up on the tines."""

    time_s: float  # as SubstepForces.time_s
    part: int
    tine_height_m: float
    tine_height_vel_m_per_s: float
    reading_n: float  # the truth's vertical force after the call (the campaign's judge)
    soil_up_n: float
    bodies_up_n: float  # the objects' tops and edges pushing the tines up
    hidden_by: int  # the object whose surface pressed the soil in the tines' place (-1: none)
    mount_n: float  # what the mount carried into the ground (NaN: none said: rigid
    # tines, or tines an object's bottom holds)

    @property
    def excess_n(self) -> float:
        """The reading less what the mount carried (0 where it said nothing)."""
        return 0.0 if math.isnan(self.mount_n) else self.reading_n - self.mount_n


def hidden_by(ground: Ground, reach_m: float, height_m: float) -> int:
    """The object that hides the soil from tines here, so that the soil is pressed by its
    surface instead (as ``Ground.step`` decides it), or -1."""
    found, shield_m = -1, -math.inf
    for i, body in enumerate(ground.bodies):
        if (not body.broken and body.left_m < reach_m < body.right_m
                and height_m > body.bottom_m and body.hides_soil_from(reach_m, height_m)
                and body.shield_m(reach_m) > shield_m):
            found, shield_m = i, body.shield_m(reach_m)
    return found if height_m < shield_m else -1


class TracingRecorder(PeakRecorder):
    """The loop's ground, passed through as :class:`PeakRecorder` does, recording each
    call in which an object pushes the tines, and the ground's vertical readings around
    the largest and where one most exceeds what the mount carried (see the module)."""

    __slots__ = ("_arm", "_c_h", "_call", "_collecting", "_k_h", "_open", "_open_mount_n",
                 "_peak_n", "_recent", "_start_s", "_tick_s", "excess", "peak_window", "rows")

    def __init__(self, ground: Ground, arm: ArmPlant, k_h: float, c_h: float) -> None:
        super().__init__(ground)
        self._arm, self._k_h, self._c_h = arm, k_h, c_h
        self._tick_s, self._call = -1.0, 0
        self._start_s = arm.time_s  # the case starts here, after the loop's settling
        self.rows: list[SubstepForces] = []
        self._open: GroundReading | None = None  # this call's, read in full at the next
        self._open_mount_n = math.nan  # what the mount carried in this call
        self._recent: deque[GroundReading] = deque(maxlen=WINDOW + 1)
        self._collecting = 0  # readings still to keep after the largest
        self._peak_n = -math.inf
        self.peak_window: list[GroundReading] = []  # around the largest reading
        self.excess: GroundReading | None = None  # the reading most over the mount's

    def transmitted(self, force_down_n: float) -> None:
        super().transmitted(force_down_n)
        self._open_mount_n = force_down_n

    def close(self) -> None:
        """Keep the last call's reading (its transmitted force comes after it)."""
        if self._open is None:
            return
        row = dataclasses.replace(self._open, reading_n=self.truth.force_down_n,
                                  mount_n=self._open_mount_n)
        self._open = None
        self._recent.append(row)
        if row.reading_n > self._peak_n:
            self._peak_n, self.peak_window, self._collecting = (row.reading_n,
                                                                list(self._recent), WINDOW)
        elif self._collecting:
            self.peak_window.append(row)
            self._collecting -= 1
        if row.excess_n > (self.excess.excess_n if self.excess is not None else 0.0):
            self.excess = row

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        self.close()
        force = super().step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, dt_s)
        arm = self._arm
        if arm.time_s != self._tick_s:
            self._tick_s, self._call = arm.time_s, 0
        self._call += 1
        bodies = self.ground.bodies
        self._open = GroundReading(
            self._tick_s - self._start_s, self._call, height_m, height_vel_m_per_s, math.nan,
            self.ground.soil.force_up_n, sum(b.force_up_n for b in bodies if b.force_up_n > 0.0),
            hidden_by(self.ground, reach_m, height_m), math.nan)
        self._open_mount_n = math.nan
        pushed = [(i, body) for i, body in enumerate(bodies)
                  if body.force_reach_n != 0.0 or body.force_up_n != 0.0]
        if not pushed:
            return force
        tip_reach_vel = arm.tip_vel_m_per_s()[0]
        mount_n = -(self._k_h * arm.mount_offset_m
                    + self._c_h * (reach_vel_m_per_s - tip_reach_vel))
        soil = self.ground.soil
        bodies_n = sum(body.force_reach_n for _, body in pushed)
        for i, body in pushed:
            self.rows.append(SubstepForces(
                self._tick_s - self._start_s, self._call, i, reach_m, height_m, reach_vel_m_per_s,
                height_vel_m_per_s, body.force_reach_n, body.force_up_n,
                bodies_n - body.force_reach_n, soil.force_reach_n, soil.force_up_n, mount_n,
                soil.cut_depth_m))
        return force


@dataclasses.dataclass(frozen=True)
class Trace:
    """A case's result and the substeps in which objects pushed its tines."""

    case: FuzzCase
    result: CaseResult
    body_kinds: tuple[str, ...]  # "stone", "root" or "mine", by Ground.bodies index (Body.kind)
    rows: tuple[SubstepForces, ...]
    ground: tuple[GroundReading, ...] = ()  # around the largest vertical reading
    excess: GroundReading | None = None  # the reading most over what the mount carried

    @property
    def ground_peak(self) -> GroundReading | None:
        """The largest vertical reading (the result's ``f_true_z_max_n``)."""
        return max(self.ground, key=lambda row: row.reading_n, default=None)

    @property
    def peak(self) -> int:
        """Index in ``rows`` of the largest push along the reach (-1: none, or objects
        that pushed the tines only up: tops)."""
        if not self.rows:
            return -1
        k = max(range(len(self.rows)), key=lambda k: abs(self.rows[k].body_reach_n))
        return k if self.rows[k].body_reach_n != 0.0 else -1

    @property
    def largest_residual(self) -> SubstepForces:
        """The traced call whose balance along the reach leaves the most over."""
        return max(self.rows, key=lambda row: abs(row.residual_n))

    def window(self, around: int, width: int = WINDOW) -> list[SubstepForces]:
        """The rows of the same object from ``width`` before ``around`` to ``width`` after."""
        body = self.rows[around].body
        before = [k for k in range(around) if self.rows[k].body == body][-width:]
        after = [k for k in range(around + 1, len(self.rows))
                 if self.rows[k].body == body][:width]
        return [self.rows[k] for k in (*before, around, *after)]

    def resistance_n(self, row: SubstepForces) -> float:
        """H at the row's cut, in the case's soil (:func:`rakectl.sim.edge.resistance_n`)."""
        return resistance_n(self.case.ground.soil, row.cut_m)


def trace_case(case: FuzzCase) -> Trace:
    """Run ``case`` as the campaign does (:func:`rakectl.sim.campaign.run_case`), its
    ground traced (a site the daemon would refuse runs nothing: no rows)."""
    recorders: list[TracingRecorder] = []

    arm = campaign.scenario_of(case).emulator.arm

    def traced(loop: FaultyRakeLoop) -> None:
        recorder = TracingRecorder(loop.ground, loop.arm, arm.tine_mount_side_stiffness_n_per_m,
                                   arm.tine_mount_side_damping_ns_per_m)
        loop.contact = recorder
        recorders.append(recorder)

    result = campaign.run_case(case, on_start=traced)
    if not recorders:
        return Trace(case, result, (), ())
    recorder = recorders[0]
    recorder.close()
    kinds = tuple(str(body.kind.value) for body in recorder.ground.bodies)
    return Trace(case, result, kinds, tuple(recorder.rows), tuple(recorder.peak_window),
                 recorder.excess)


def describe(trace: Trace) -> list[str]:
    """The trace as lines: the result, the largest push and the substeps around it."""
    r = trace.result
    lines = [f"{trace.case.describe()} ({r.family})",
             f"result: ground {r.f_true_z_max_n:.1f} N, mine plate {r.f_mine_plate_max_n:.1f} N,"
             f" mine side {r.f_mine_side_max_n:.1f} N, stone side "
             f"{r.f_stone_side_max_n:.1f} N, root side {r.f_root_side_max_n:.1f} N"]
    return [*lines, *_along_the_reach(trace), *_vertical(trace)]


def _along_the_reach(trace: Trace) -> list[str]:
    peak = trace.peak
    if peak < 0:
        up_n = max((row.body_up_n for row in trace.rows), default=0.0)
        return ["no object pushed the tines along the reach" + (
            f" (tops only: {up_n:.1f} N up at most)" if trace.rows else "")]
    p = trace.rows[peak]
    h_n = trace.resistance_n(p)
    worst = trace.largest_residual
    lines = [
        f"largest push along the reach: the {trace.body_kinds[p.body]} (body {p.body}), "
        f"{p.body_reach_n:+.1f} N at t = {p.time_s:.3f} s (call {p.part} of the tick); the soil "
        f"{p.soil_reach_n:+.1f} N, the mount {p.mount_reach_n:+.1f} N, left over "
        f"{p.residual_n:+.2f} N",
        f"the soil's cut there {p.cut_m * 1e3:.1f} mm: H = {h_n:.1f} N (strongest layer, a "
        f"mean cell); the soil's share {abs(p.soil_reach_n) / h_n:.2f} H" if h_n > 0.0 else
        f"the soil's cut there {p.cut_m * 1e3:.1f} mm: no resistance",
        f"largest imbalance over the {len(trace.rows)} traced calls: {worst.residual_n:+.2f} N "
        f"at t = {worst.time_s:.3f} s",
        "     t s call   tine reach m  height mm  v_reach mm/s  v_up mm/s  object N (reach, up)"
        "  others N  soil N (reach, up)  mount N  left N  cut mm"]
    for row in trace.window(peak):
        lines.append(
            f"{row.time_s:8.3f} {row.part:4d} {row.tine_reach_m:14.5f} "
            f"{row.tine_height_m * 1e3:10.2f} {row.tine_reach_vel_m_per_s * 1e3:13.1f} "
            f"{row.tine_height_vel_m_per_s * 1e3:10.1f} {row.body_reach_n:+9.1f} "
            f"{row.body_up_n:+8.1f} {row.others_reach_n:+9.1f}   {row.soil_reach_n:+9.1f} "
            f"{row.soil_up_n:+8.1f} "
            f"{row.mount_reach_n:+8.1f} {row.residual_n:+7.2f} {row.cut_m * 1e3:7.1f}")
    return lines


def _mount(row: GroundReading) -> str:
    return ("not said (rigid tines, or tines held at an object's bottom)"
            if math.isnan(row.mount_n) else f"{row.mount_n:.1f} N")


def _presser(trace: Trace, row: GroundReading) -> str:
    """What pressed the soil: "tines", or the kind of the object hiding it."""
    return "tines" if row.hidden_by < 0 else trace.body_kinds[row.hidden_by]


def _pressed(trace: Trace, row: GroundReading) -> str:
    if row.hidden_by < 0:
        return "by the tines"
    return (f"by the {_presser(trace, row)}'s surface (body {row.hidden_by}), "
            "which hides it from the tines")


def _vertical(trace: Trace) -> list[str]:
    """The largest vertical reading against what the mount carried, and the calls around it."""
    p = trace.ground_peak
    if p is None or p.reading_n <= 0.0:
        return ["the ground read no vertical force"]
    lines = [f"largest vertical reading: {p.reading_n:.1f} N at t = {p.time_s:.3f} s (call "
             f"{p.part} of the tick); the mount carried {_mount(p)} into the ground; the soil "
             f"{p.soil_up_n:.1f} N up, pressed {_pressed(trace, p)}; the objects "
             f"{p.bodies_up_n:.1f} N up"]
    if (worst := trace.excess) is not None:
        lines.append(f"largest reading over what the mount carried: {worst.excess_n:+.1f} N "
                     f"at t = {worst.time_s:.3f} s ({worst.reading_n:.1f} N against "
                     f"{_mount(worst)}; the soil pressed {_pressed(trace, worst)})")
    lines.append("     t s call  height mm  v_up mm/s  reading N  mount N  soil N  objects N"
                 "  over N  soil pressed by")
    for row in trace.ground:
        by = _presser(trace, row) + ("" if row.hidden_by < 0 else f" {row.hidden_by}")
        lines.append(f"{row.time_s:8.3f} {row.part:4d} {row.tine_height_m * 1e3:10.2f} "
                     f"{row.tine_height_vel_m_per_s * 1e3:10.1f} {row.reading_n:10.1f} "
                     f"{row.mount_n:8.1f} {row.soil_up_n:7.1f} {row.bodies_up_n:10.1f} "
                     f"{row.excess_n:+7.1f}  {by}")
    return lines


def summary(trace: Trace) -> dict[str, float | int | str]:
    """The largest push's figures, for --json."""
    peak = trace.peak
    out: dict[str, float | int | str] = {"index": trace.result.index, "seed": trace.result.seed,
                                         "family": trace.result.family,
                                         "traced_calls": len(trace.rows)}
    g = trace.ground_peak
    if g is not None:
        out.update({"ground_n": g.reading_n, "ground_time_s": g.time_s,
                    "ground_soil_up_n": g.soil_up_n, "ground_bodies_up_n": g.bodies_up_n,
                    "ground_soil_pressed_by": _presser(trace, g)})
        if not math.isnan(g.mount_n):
            out["ground_mount_n"] = g.mount_n
    if trace.excess is not None:
        out["largest_ground_excess_n"] = trace.excess.excess_n
    if peak < 0:
        return out
    p = trace.rows[peak]
    worst = abs(trace.largest_residual.residual_n)
    out.update({"body": trace.body_kinds[p.body], "time_s": p.time_s,
                "body_reach_n": p.body_reach_n, "body_up_n": p.body_up_n,
                "soil_reach_n": p.soil_reach_n, "mount_reach_n": p.mount_reach_n,
                "residual_n": p.residual_n, "cut_m": p.cut_m,
                "resistance_n": trace.resistance_n(p), "largest_residual_n": worst,
                "tine_height_vel_m_per_s": p.tine_height_vel_m_per_s,
                "tine_reach_vel_m_per_s": p.tine_reach_vel_m_per_s})
    return out
