"""Excavation benchmark: how fast each controller rakes a lane to depth, within the bound.

Three reference soils (``config/scenarios/excavate-{sand,loam,clay}.yaml``: a
1 m lane to 100 mm in 10 mm cuts, two sentinel mines under the target depth)
and three controllers, run the same way: the full simulated chain of
:class:`~rakectl.sim.rake_plant.RakeLoop` (the daemon's controller, clamp and
supervision, the one-tick bus delay, drivers/ physics), the lane planner
stepped as the daemon steps it (:func:`rakectl.sim.simulate.advance_reference`):

* ``adaptive``: the scenario as written, ``lane.adaptive`` on (rakectl.core.governor).
* ``position``: pure position control, α = 0 everywhere (F̂ ≡ 0, the impedance
  does nothing), strokes at the adaptive controller's top speed. The clamp and
  the current-based supervision stay: they are not the controller.
* ``fixed-safe``: a fixed stroke speed, the largest of a descending sweep in
  clay (a 3-cycle lane) whose run reaches its depth with no stall, no force
  stop, the supervised estimate never above the caution level, no tick over
  90 N and no mine fired.

Each run reports the time until the last stroke at the target depth ends, the
largest true vertical force (per tick, the in-tick peak), the ticks above
90 N and the mines fired. Runs go to an executor (rakectl.sim.parallel: local
worker processes, or a Dask cluster); each run is deterministic in its job, so
whoever runs it, the figures are the same but the wall times. Pure computation:
the caller prints, plots and writes.
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivers.objects import Contact
from drivers.soil import Soil
from rakectl.config.files import config_dir
from rakectl.config.loader import load_settings
from rakectl.config.settings import LaneSettings
from rakectl.core.lane import LanePhase, LanePlanner
from rakectl.core.supervision import ForceLevel
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.parallel import Executor, LocalExecutor
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import Scenario
from rakectl.sim.simulate import advance_reference, build_reference

SOILS = ("sand", "loam", "clay")
HARDEST_SOIL = "clay"
SPEEDUP_GOAL = 2.0  # over fixed-safe, in sand and loam
# Stroke speeds tried for the fixed-safe baseline, fastest first (capped at the adaptive
# controller's top speed).
SWEEP_SPEEDS_M_PER_S = (0.6, 0.5, 0.4, 0.3, 0.25, 0.2, 0.15, 0.1, 0.07, 0.05, 0.03, 0.02,
                        0.01)
SWEEP_CYCLES = 3
SERIES_WINDOW_S = 0.01  # the plots' time step: forces are the window's peak


class Controller(enum.StrEnum):
    ADAPTIVE = "adaptive"
    POSITION = "position"
    FIXED_SAFE = "fixed-safe"


@dataclass(frozen=True)
class LaneShape:
    """The lane each run rakes; None keeps the scenario's value."""

    reach_far_m: float | None = None
    reach_near_m: float | None = None
    target_depth_m: float | None = None

    def overrides(self) -> tuple[str, ...]:
        given = (("reach_far_m", self.reach_far_m), ("reach_near_m", self.reach_near_m),
                 ("target_depth_m", self.target_depth_m))
        return tuple(f"lane.{key}={value:g}" for key, value in given if value is not None)


FULL = LaneShape()
QUICK = LaneShape(reach_far_m=1.4, reach_near_m=1.0, target_depth_m=0.02)


def scenario_path(soil: str) -> Path:
    return config_dir() / "scenarios" / f"excavate-{soil}.yaml"


@dataclass(frozen=True)
class Job:
    soil: str
    controller: str  # a Controller, or "sweep"
    overrides: tuple[str, ...]
    keep_series: bool = True


@dataclass
class Series:
    """Per SERIES_WINDOW_S: time, true tip depth, depth raked, peak true and estimated force."""

    t_s: NDArray[np.float32]
    tip_depth_m: NDArray[np.float32]
    floor_m: NDArray[np.float32]
    f_true_z_n: NDArray[np.float32]
    f_estimate_n: NDArray[np.float32]


@dataclass
class RunResult:
    job: Job
    reached: bool  # the last stroke at the target depth was completed
    time_s: float  # when it ended (nan if not reached)
    depth_reached_m: float
    f_true_z_max_n: float
    ticks_over_limit: int
    mines_activated: int
    object_found: bool
    stopped_by_force: bool
    caution_ticks: int  # ticks with the supervised estimate above the caution level
    f_estimate_max_n: float  # max(F̂, current-based), the supervised estimate
    stroke_speed_mean_m_per_s: float  # the reference's mean speed over the strokes
    simulated_s: float
    wall_s: float
    phase_s: dict[str, float]  # time spent in each lane phase
    fault: str = ""
    series: Series | None = field(default=None, repr=False)
    cycles: int = 0  # lane cycles begun
    floor_true_m: float = math.nan  # the emulated soil's shallowest floor along the lane

    @property
    def safe(self) -> bool:
        """The fixed-safe sweep's criterion (see the module docstring)."""
        return (self.reached and not self.fault and self.caution_ticks == 0
                and self.ticks_over_limit == 0 and self.mines_activated == 0)


class _Recorder:
    """Per-tick figures of one run; the series in windows of SERIES_WINDOW_S."""

    def __init__(self, max_ticks: int, window_ticks: int, keep: bool) -> None:
        self.window = window_ticks
        n = max_ticks // window_ticks + 1 if keep else 0
        self.columns = np.zeros((5, n), dtype=np.float32)
        self.f_max_n = self.estimate_max_n = 0.0
        self.over = self.caution = self.stroke_ticks = 0
        self.stroke_speed_sum = 0.0
        self.phase_ticks = {phase.name.lower(): 0 for phase in LanePhase}

    def add(self, k: int, loop: RakeLoop, planner: LanePlanner) -> None:
        f_n, estimate_n = loop.contact.peak_down_n, loop.force_estimate_n
        self.over += f_n > FORCE_LIMIT_N
        self.caution += loop.force_level is not ForceLevel.OK
        self.f_max_n = max(self.f_max_n, f_n)
        self.estimate_max_n = max(self.estimate_max_n, estimate_n)
        self.phase_ticks[planner.phase.name.lower()] += 1
        if planner.phase is LanePhase.STROKE:
            self.stroke_ticks += 1
            self.stroke_speed_sum += planner.speed_m_per_s
        if self.columns.shape[1]:
            i, c = k // self.window, self.columns
            c[0, i] = (i + 1) * self.window * loop.dt_s
            c[1, i] = -loop.arm.tip_m()[1]
            c[2, i] = planner.floor_m
            c[3, i] = max(c[3, i], f_n)
            c[4, i] = max(c[4, i], estimate_n)

    def series(self, ticks: int) -> Series | None:
        if not self.columns.shape[1]:
            return None
        c = self.columns[:, : (ticks + self.window - 1) // self.window]
        return Series(c[0], c[1], c[2], c[3], c[4])


def run_job(job: Job) -> RunResult:
    """One lane through the full chain, as the daemon would rake it."""
    started = time.perf_counter()
    settings = load_settings(scenario_path(job.soil), job.overrides, root=Scenario)
    planner = build_reference(settings)
    if not isinstance(planner, LanePlanner):
        raise TypeError(f"{scenario_path(job.soil)} is not a lane scenario")
    loop = RakeLoop(settings, planner.reach_m, planner.depth_m)
    if loop.controller.descent is not None:
        planner.plan_within(loop.controller.descent.limit_at_m)
    loop.reset()
    dt_s, target_m = loop.dt_s, settings.lane.target_depth_m
    max_ticks = round(settings.duration_s / dt_s)
    record = _Recorder(max_ticks, max(1, round(SERIES_WINDOW_S / dt_s)), job.keep_series)
    time_s, ticks = math.nan, max_ticks
    for k in range(max_ticks):
        loop.step(planner.reach_m, planner.depth_m, planner.contact)
        record.add(k, loop, planner)
        if loop.fault:
            ticks = k + 1
            break
        advance_reference(planner, loop)
        if math.isnan(time_s) and planner.floor_m >= target_m - 1e-9:
            time_s = (k + 1) * dt_s
        if planner.done:
            ticks = k + 1
            break
    mines = sum(b.activated for b in loop.ground.bodies if b.kind is Contact.MINE)
    return RunResult(
        job, not math.isnan(time_s), time_s, planner.floor_m, record.f_max_n, record.over,
        mines, planner.found_at is not None, planner.stopped_by_force, record.caution,
        record.estimate_max_n,
        record.stroke_speed_sum / record.stroke_ticks if record.stroke_ticks else math.nan,
        ticks * dt_s, time.perf_counter() - started,
        {name: n * dt_s for name, n in record.phase_ticks.items()}, loop.fault,
        record.series(ticks), planner.cycle, true_floor_m(loop.ground.soil, settings.lane))


def true_floor_m(soil: Soil, lane: LaneSettings) -> float:
    """The shallowest depth of the soil's surface over the lane's cells, after the run: how
    deep the lane really is where it is least deep (the reference's depth is what it asked)."""
    heights = soil.surface_heights_m()
    inside = [h for j, h in enumerate(heights)
              if lane.reach_near_m <= soil.cell_centre_m(j) <= lane.reach_far_m]
    return -max(inside) if inside else math.nan


# --------------------------------------------------------------------------- the campaign


def controller_overrides(controller: Controller, fixed_speed_m_per_s: float,
                         top_speed_m_per_s: float) -> tuple[str, ...]:
    """The --set overrides that turn the scenario (adaptive) into each controller."""
    if controller is Controller.ADAPTIVE:
        return ()
    if controller is Controller.POSITION:
        return ("estimator.delay_s=0", "lane.adaptive=false",
                f"lane.stroke_speed_m_per_s={top_speed_m_per_s:g}")
    return ("lane.adaptive=false", f"lane.stroke_speed_m_per_s={fixed_speed_m_per_s:g}")


@dataclass
class Sweep:
    """The fixed-safe speed: the fastest sweep speed whose clay run was safe."""

    speed_m_per_s: float  # nan if none was
    tried: list[RunResult]


@dataclass
class ExcavationReport:
    shape: LaneShape
    sweep: Sweep
    top_speed_m_per_s: float
    results: list[RunResult]
    wall_s: float

    def result(self, soil: str, controller: Controller) -> RunResult:
        return next(r for r in self.results
                    if r.job.soil == soil and r.job.controller == controller)

    def speedup(self, soil: str) -> float:
        """fixed-safe time / adaptive time (nan if either did not reach the depth)."""
        fixed = self.result(soil, Controller.FIXED_SAFE).time_s
        adaptive = self.result(soil, Controller.ADAPTIVE).time_s
        return fixed / adaptive if adaptive > 0 else math.nan

    def stroke_bound(self, soil: str) -> float:
        """The most any stroke speed could gain over fixed-safe here: its time over its time
        less its strokes (nan if it did not reach the depth)."""
        fixed = self.result(soil, Controller.FIXED_SAFE)
        stroke_s = fixed.phase_s.get("stroke", 0.0)
        return fixed.time_s / (fixed.time_s - stroke_s) if fixed.reached else math.nan

    def goal_met(self) -> bool:
        fast = all(self.speedup(soil) >= SPEEDUP_GOAL for soil in ("sand", "loam"))
        bounded = all(self.result(soil, Controller.ADAPTIVE).ticks_over_limit == 0
                      for soil in SOILS)
        return fast and bounded


Echo = Callable[[str], None]  # one line of progress


def _run_numbered(item: tuple[int, Job]) -> tuple[int, RunResult]:
    return item[0], run_job(item[1])


def run_jobs(executor: Executor, jobs: Sequence[Job],
             each: Callable[[Job, RunResult], None] | None = None) -> list[RunResult]:
    """Every job's result in the order of ``jobs``; ``each`` is told of each as it ends."""
    results: dict[int, RunResult] = {}
    for i, result in executor.map_unordered(_run_numbered, list(enumerate(jobs))):
        results[i] = result
        if each is not None:
            each(jobs[i], result)
    return [results[i] for i in range(len(jobs))]


def find_fixed_safe_speed(shape: LaneShape, speeds: Iterable[float], executor: Executor,
                          progress: Echo | None = None) -> Sweep:
    """Try ``speeds`` fastest first in clay, as many at a time as ``executor`` runs; stop
    at the first safe."""
    settings = load_settings(scenario_path(HARDEST_SOIL), shape.overrides(), root=Scenario)
    lane = settings.lane
    depth_m = min(lane.target_depth_m, SWEEP_CYCLES * lane.depth_step_m)
    base = (*shape.overrides(), f"lane.target_depth_m={depth_m:g}")
    ordered = sorted(set(speeds), reverse=True)
    tried: list[RunResult] = []

    def tell(job: Job, result: RunResult) -> None:
        if progress is not None:
            progress(f"sweep in {HARDEST_SOIL}: {speed_of(job):g} m/s "
                     f"{'safe' if result.safe else 'not safe'} ({why(result)})")

    batch_size = executor.slots()
    for i in range(0, len(ordered), batch_size):
        batch = [Job(HARDEST_SOIL, "sweep",
                     (*base, *controller_overrides(Controller.FIXED_SAFE, v, math.nan)),
                     keep_series=False)
                 for v in ordered[i:i + batch_size]]
        tried += run_jobs(executor, batch, tell)
        safe = [speed_of(r.job) for r in tried if r.safe]
        if safe:
            return Sweep(max(safe), tried)
    return Sweep(math.nan, tried)


def speed_of(job: Job) -> float:
    for item in job.overrides:
        if item.startswith("lane.stroke_speed_m_per_s="):
            return float(item.partition("=")[2])
    return math.nan


def why(r: RunResult) -> str:
    """What a run met, in a few words."""
    parts = [f"est. max {r.f_estimate_max_n:.0f} N", f"true max {r.f_true_z_max_n:.0f} N"]
    if r.object_found:
        parts.append("stalled (taken for an object)")
    if r.stopped_by_force:
        parts.append("hard force stop")
    if r.caution_ticks:
        parts.append(f"{r.caution_ticks} ticks at caution")
    if r.fault:
        parts.append(f"fault: {r.fault}")
    if not r.reached and not (r.object_found or r.stopped_by_force or r.fault):
        parts.append("depth not reached in time")
    return ", ".join(parts)


def run_excavation(shape: LaneShape = FULL, workers: int = 2,
                   sweep_speeds: Iterable[float] = SWEEP_SPEEDS_M_PER_S,
                   progress: Echo | None = None, executor: Executor | None = None
                   ) -> ExcavationReport:
    """The sweep, then every (soil, controller) run: on ``executor``, or on ``workers``
    local processes."""
    started = time.perf_counter()
    executor = LocalExecutor(workers) if executor is None else executor
    top = load_settings(scenario_path(HARDEST_SOIL), shape.overrides(),
                        root=Scenario).lane.max_stroke_speed_m_per_s
    sweep = find_fixed_safe_speed(shape, [v for v in sweep_speeds if v <= top + 1e-12],
                                  executor, progress)
    fixed = sweep.speed_m_per_s if math.isfinite(sweep.speed_m_per_s) else min(sweep_speeds)
    jobs = [Job(soil, controller, (*shape.overrides(),
                                   *controller_overrides(controller, fixed, top)))
            for soil in SOILS for controller in Controller]

    def tell(job: Job, result: RunResult) -> None:
        if progress is not None:
            progress(f"{job.soil}, {job.controller}: "
                     + (f"{result.time_s:.1f} s to depth" if result.reached else "not reached")
                     + f" ({why(result)}; {result.wall_s:.0f} s wall)")

    results = run_jobs(executor, jobs, tell)
    return ExcavationReport(shape, sweep, top, results, time.perf_counter() - started)

