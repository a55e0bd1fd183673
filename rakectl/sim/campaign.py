"""The closed-loop safety campaign: each case through the full simulated chain, judged
by the ground truth.

A case (:mod:`rakectl.sim.cases`) runs through the daemon's own
:class:`~rakectl.core.control.TipController`, the one-tick bus delay and drivers/
physics (:class:`~rakectl.sim.rake_plant.RakeLoop`), with its faults injected
between them (:class:`~rakectl.sim.injection.FaultyRakeLoop`). A case is safe when no tick's true
vertical force on the ground exceeds 90 N, no force on a mine's plate or side
exceeds 90 N and no mine fires. Side forces on stones and roots are reported.

The command and the faults are injected by :mod:`rakectl.sim.injection`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from drivers.objects import Contact
from drivers.soil import original_surface_height_m
from rakectl.config.descent import DescentSettings
from rakectl.config.settings import LaneSettings
from rakectl.core.clamp import VoltageClamp
from rakectl.core.lane import LanePlanner
from rakectl.core.supervision import ForceLevel
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.cases import CommandKind, Family, FuzzCase, case_from_dict, from_plain, generate
from rakectl.sim.injection import FaultyRakeLoop, HoldReference, JogReference, PlungeReference
from rakectl.sim.parallel import Executor, LocalExecutor
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import PlantKind, PlantSettings, Scenario, TrajectoryKind
from rakectl.sim.simulate import HOLD_AFTER_DONE_S, Reference

WORST_CASE_FILE = "worst-case.json"
RESULTS_FILE = "results.jsonl"  # one case's result a line, appended as cases finish
AFTER_FAULT_S = 1.0  # simulated at 0 V after a latched fault


@dataclass(frozen=True)
class CaseResult:
    seed: int
    index: int
    kind: str
    f_true_z_max_n: float  # largest per-tick peak of the true vertical force
    f_true_z_max_t_s: float
    ticks_over_limit: int  # ticks whose true vertical force peak exceeds 90 N
    mine_activated: bool
    object_found: bool
    duration_s: float
    faults: tuple[str, ...]
    feedback_lost_ticks: int
    commands_lost_ticks: int
    drive_fault_ticks: int
    clamped_ticks: int
    controller_fault: str
    f_mine_plate_max_n: float = 0.0
    f_mine_side_max_n: float = 0.0
    f_stone_side_max_n: float = 0.0
    f_root_side_max_n: float = 0.0
    supervised: bool = False
    stalled_ticks: int = 0  # ticks the controller did not run (stall, kill)
    watchdog_tripped: bool = False
    family: str = str(Family.RANDOM)  # how the case was drawn (rakectl.sim.cases.Family)

    @property
    def safe(self) -> bool:
        """No vertical force over 90 N, none on a mine from any side, no mine fired."""
        return (self.ticks_over_limit == 0 and not self.mine_activated
                and max(self.f_mine_plate_max_n, self.f_mine_side_max_n) <= FORCE_LIMIT_N)

    @property
    def f_mine_max_n(self) -> float:
        return max(self.f_mine_plate_max_n, self.f_mine_side_max_n)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def result_from_dict(data: dict[str, Any]) -> CaseResult:
    result: CaseResult = from_plain(CaseResult, data)
    return result


# --------------------------------------------------------------------------- running


def scenario_of(case: FuzzCase, descent: DescentSettings | None = None) -> Scenario:
    """The case's scenario; ``descent`` replaces the default descent budget's settings."""
    c = case.command
    base = Scenario() if descent is None else dataclasses.replace(Scenario(), descent=descent)
    lane = LaneSettings(reach_far_m=c.reach_far_m, reach_near_m=min(c.reach_near_m,
                                                                      c.reach_far_m - 0.01),
                        depth_step_m=c.depth_step_m if c.depth_step_m > 0 else 0.01,
                        target_depth_m=c.target_depth_m if c.target_depth_m > 0 else 0.05,
                        clearance_m=max(0.005, c.start_height_m),
                        stroke_speed_m_per_s=min(max(c.speed_m_per_s, 1e-3), 1.0),
                        plunge_speed_m_per_s=max(c.plunge_speed_m_per_s, 1e-3))
    if c.travel_speed_m_per_s > 0.0:
        lane = dataclasses.replace(lane, travel_speed_m_per_s=c.travel_speed_m_per_s)
    if c.adaptive:  # the case's speed is the top one, if above the default's
        defaults = LaneSettings()
        lane = dataclasses.replace(
            lane, adaptive=True,
            max_stroke_speed_m_per_s=max(defaults.max_stroke_speed_m_per_s,
                                         lane.stroke_speed_m_per_s),
            max_plunge_speed_m_per_s=max(defaults.max_plunge_speed_m_per_s,
                                         lane.plunge_speed_m_per_s),
            max_depth_step_m=max(defaults.max_depth_step_m, lane.depth_step_m))
    emulator = dataclasses.replace(base.emulator, ground=case.ground, seed=case.ground_seed)
    return dataclasses.replace(base, plant=PlantSettings(kind=PlantKind.RAKE), lane=lane,
                               trajectory=dataclasses.replace(base.trajectory,
                                                              kind=TrajectoryKind.LANE),
                               duration_s=case.duration_s, emulator=emulator)


def _start(case: FuzzCase, settings: Scenario) -> tuple[float, float]:
    """The start pose (reach, depth) above (or, for a jog, maybe in) the local surface."""
    c = case.command
    surface_m = original_surface_height_m(case.ground.soil, c.reach_far_m)
    return c.reach_far_m, -(surface_m + c.start_height_m)


def _reference(case: FuzzCase, settings: Scenario, loop: RakeLoop) -> Reference:
    c, dt_s = case.command, 1.0 / settings.rate_hz
    reach_m, depth_m = loop.start
    if c.kind is CommandKind.PLUNGE:
        return PlungeReference(reach_m, depth_m, c.target_depth_m, c.speed_m_per_s, dt_s,
                               c.contact)
    if c.kind is CommandKind.JOG:
        m = loop.arm.measure()
        return JogReference(case, settings, loop.workspace, m.r_m, m.theta_rad)
    lane = settings.lane
    descent = loop.controller.descent
    return LanePlanner(lane, dt_s, lane.reach_far_m, depth_m,
                       None if descent is None else descent.limit_at_m)


def run_case(case: FuzzCase, clamp: VoltageClamp | None = None,
             on_tick: Callable[[FaultyRakeLoop], None] | None = None,
             descent: DescentSettings | None = None) -> CaseResult:
    """Run one case through the full chain; ``clamp`` replaces the real one (tests);
    ``on_tick`` sees the loop after every tick (a replay's telemetry); ``descent``
    replaces the descent budget's settings (a site's declared soil, the limiter on)."""
    settings = scenario_of(case, descent)
    loop = FaultyRakeLoop(settings, *_start(case, settings), case.faults, clamp)
    loop.reset()
    reference = _reference(case, settings, loop)
    loop.arm_faults()
    dt_s = loop.dt_s
    peak_n, peak_t_s, over, hold = 0.0, 0.0, 0, round(HOLD_AFTER_DONE_S / dt_s)
    after_fault = round(AFTER_FAULT_S / dt_s)
    back_off_m = settings.supervision.back_off_m
    ticks = round(case.duration_s / dt_s)
    k = 0
    while k < ticks:
        loop.step(reference.reach_m, reference.depth_m, reference.contact)
        if on_tick is not None:
            on_tick(loop)
        f_n = loop.contact.peak_down_n
        over += f_n > FORCE_LIMIT_N
        if f_n > peak_n:
            peak_n, peak_t_s = f_n, k * dt_s
        k += 1
        if loop.fault or loop.latched:  # 0 V from now on: see where the rake falls
            ticks = min(ticks, k + after_fault) if after_fault else k
            after_fault = 0
            continue
        reach_m, depth_m = loop.measured_tip()
        reference.observe(reach_m, depth_m)
        level = loop.force_level if case.supervised else ForceLevel.OK
        if level is ForceLevel.HARD and not isinstance(reference, HoldReference):
            if isinstance(reference, LanePlanner):
                reference.force_stop(reach_m, depth_m)
            else:
                reference = HoldReference(reach_m, depth_m - back_off_m)
        if isinstance(reference, LanePlanner):  # an adaptive lane's governor (else: nothing)
            reference.govern(loop.force_estimate_n, loop.caution_n)
        if level is not ForceLevel.CAUTION:  # caution holds the reference where it is
            reference.step()
        hold -= reference.done
        if hold < 0:
            break
    return _result(case, loop, reference, (peak_n, peak_t_s, over, k * dt_s))


def _result(case: FuzzCase, loop: FaultyRakeLoop, reference: Reference,
            figures: tuple[float, float, int, float]) -> CaseResult:
    found = isinstance(reference, LanePlanner) and reference.found_at is not None
    kind = str(case.command.kind) + (" (adaptive)" if case.command.adaptive else "")

    def peak(kind: Contact, attribute: str) -> float:
        return max((getattr(b, attribute) for b in loop.ground.bodies if b.kind is kind),
                   default=0.0)

    return CaseResult(case.seed, case.index, kind, figures[0], figures[1],
                      figures[2], loop.ground.truth.mine_activated, found, figures[3],
                      case.faults.kinds(), loop.feedback_lost, loop.commands_lost,
                      loop.drive_fault_ticks, loop.controller.clamp.clamped, loop.fault,
                      f_mine_plate_max_n=peak(Contact.MINE, "peak_down_n"),
                      f_mine_side_max_n=peak(Contact.MINE, "peak_side_n"),
                      f_stone_side_max_n=peak(Contact.STONE, "peak_side_n"),
                      f_root_side_max_n=peak(Contact.ROOT, "peak_side_n"),
                      supervised=case.supervised, stalled_ticks=loop.stalled_ticks,
                      watchdog_tripped=loop.watchdog_tripped, family=str(case.family))


# --------------------------------------------------------------------------- campaign


@dataclass(frozen=True)
class Report:
    scenarios: int
    results: tuple[CaseResult, ...]
    worst: CaseResult  # the largest force on the ground or a mine
    worst_case: FuzzCase
    wall_time_s: float
    worst_case_path: str = ""
    resumed: int = 0  # cases read back from an earlier run's results, not run again

    @property
    def f_true_z_max_n(self) -> float:
        return max(r.f_true_z_max_n for r in self.results)

    @property
    def f_mine_max_n(self) -> float:
        return max(r.f_mine_max_n for r in self.results)

    @property
    def ticks_over_limit(self) -> int:
        return sum(r.ticks_over_limit for r in self.results)

    @property
    def mine_activations(self) -> int:
        return sum(r.mine_activated for r in self.results)

    @property
    def unsafe(self) -> tuple[CaseResult, ...]:
        return tuple(r for r in self.results if not r.safe)

    @property
    def safe(self) -> bool:
        return not self.unsafe

    def by_kind(self) -> dict[str, dict[str, float | int]]:
        """Per command kind, fault kind and supervision: cases, worst forces, unsafe."""
        out: dict[str, dict[str, float | int]] = {}
        for r in self.results:
            groups = [r.kind, *(f"fault: {f}" for f in r.faults or ("none",)),
                      "supervision on" if r.supervised else "supervision off"]
            for group in groups:
                k = out.setdefault(group, {"cases": 0, "f_true_z_max_n": 0.0,
                                           "f_mine_max_n": 0.0, "f_stone_side_max_n": 0.0,
                                           "unsafe": 0})
                k["cases"] += 1
                k["f_true_z_max_n"] = max(k["f_true_z_max_n"], r.f_true_z_max_n)
                k["f_mine_max_n"] = max(k["f_mine_max_n"], r.f_mine_max_n)
                k["f_stone_side_max_n"] = max(k["f_stone_side_max_n"], r.f_stone_side_max_n)
                k["unsafe"] += not r.safe
        return dict(sorted(out.items(), key=lambda item: (item[0].startswith(("fault", "super")),
                                                          item[0])))

    def over_limit(self) -> list[str]:
        """Every unsafe case: 'seed/index kind ground F N, mine F N [mine fired]'."""
        return [f"{self.worst_case.seed}/{r.index} {r.kind} ground {r.f_true_z_max_n:.1f} N, "
                f"mine {r.f_mine_max_n:.1f} N" + (" mine fired" if r.mine_activated else "")
                for r in self.unsafe]

    def summary(self) -> dict[str, Any]:
        results = self.results
        return {"scenarios": self.scenarios, "f_true_z_max_n": self.f_true_z_max_n,
                "f_mine_max_n": self.f_mine_max_n,
                "f_mine_side_max_n": max(r.f_mine_side_max_n for r in results),
                "f_mine_plate_max_n": max(r.f_mine_plate_max_n for r in results),
                "f_stone_side_max_n": max(r.f_stone_side_max_n for r in results),
                "f_root_side_max_n": max(r.f_root_side_max_n for r in results),
                "ticks_over_limit": self.ticks_over_limit,
                "unsafe_cases": len(self.unsafe), "over_limit": self.over_limit(),
                "mine_activations": self.mine_activations,
                "controller_faults": sum(bool(r.controller_fault) for r in results),
                "watchdog_trips": sum(r.watchdog_tripped for r in results),
                "by_kind": self.by_kind(),
                "worst": self.worst.to_dict(), "worst_case": self.worst_case.describe(),
                "worst_case_path": self.worst_case_path, "wall_time_s": self.wall_time_s,
                "resumed": self.resumed,  # read back, not run: the rate counts the others
                "scenarios_per_min": 60.0 * (self.scenarios - self.resumed)
                / max(self.wall_time_s, 1e-9)}


def _run_index(job: tuple[int, int, str]) -> CaseResult:
    seed, index, family = job
    return run_case(generate(seed, index, Family(family)))


def _severity(r: CaseResult) -> float:
    return max(r.f_true_z_max_n, r.f_mine_max_n)


def campaign(scenarios: int, seed: int, workers: int = 1, out_dir: Path | None = None,
             progress: Callable[[int, int], None] | None = None, first: int = 0,
             executor: Executor | None = None, family: Family = Family.RANDOM) -> Report:
    """Run cases ``first`` … ``first + scenarios − 1`` of ``seed``; write the worst one
    (the largest force on the ground or on a mine) to ``out_dir``.

    With ``out_dir``, each case's result is appended to :data:`RESULTS_FILE` there as it
    finishes, and a case already in that file (same seed and index) is not run again: an
    interrupted campaign resumes where it stopped, and a long one can be run in parts into
    one directory. Cases are deterministic from (seed, index), so the report is the same
    whichever run computed each case, and whatever ran it: ``executor`` (a Dask cluster,
    rakectl.sim.parallel) instead of ``workers`` local processes. ``family``: how the
    cases are drawn (the random campaign, or the edge cases of rakectl.sim.cases)."""
    if scenarios < 1:
        raise ValueError("scenarios must be >= 1")
    started = time.perf_counter()
    wanted = range(first, first + scenarios)
    done = _finished(out_dir / RESULTS_FILE, seed, wanted, family) \
        if out_dir is not None else {}
    results: list[CaseResult] = list(done.values())
    jobs = [(seed, i, str(family)) for i in wanted if i not in done]
    sink = _open_results(out_dir) if out_dir is not None and jobs else None
    try:
        if progress is not None and results:
            progress(len(results), scenarios)
        pool = executor if executor is not None else LocalExecutor(workers)
        for result in pool.map_unordered(_run_index, jobs):
            results.append(result)
            if sink is not None:
                sink.write(json.dumps(result.to_dict()) + "\n")
                sink.flush()
            if progress is not None:
                progress(len(results), scenarios)
    finally:
        if sink is not None:
            sink.close()
    results.sort(key=lambda r: r.index)
    worst = max(results, key=_severity)
    report = Report(scenarios, tuple(results), worst, generate(seed, worst.index, family),
                    time.perf_counter() - started, resumed=len(done))
    if out_dir is None:
        return report
    path = write_case(out_dir / WORST_CASE_FILE, report.worst_case, worst)
    return dataclasses.replace(report, worst_case_path=str(path))


def _finished(path: Path, seed: int, wanted: range, family: Family = Family.RANDOM
              ) -> dict[int, CaseResult]:
    """The results already in ``path`` for these cases of ``family`` (a line cut short by
    an interruption is ignored: that case runs again)."""
    done: dict[int, CaseResult] = {}
    if not path.is_file():
        return done
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            result = result_from_dict(json.loads(line))
        except (ValueError, TypeError, KeyError):
            continue
        if result.seed == seed and result.index in wanted and result.family == family:
            done[result.index] = result
    return done


def _open_results(out_dir: Path) -> TextIO:
    """The results file, for appending; a line an interruption left unfinished is ended
    first, so that the next result starts a line of its own."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / RESULTS_FILE
    unfinished = path.is_file() and path.stat().st_size > 0 and \
        path.read_bytes()[-1:] != b"\n"
    sink = open(path, "a", encoding="utf-8")  # noqa: SIM115 (closed by the caller)
    if unfinished:
        sink.write("\n")
    return sink


def write_case(path: Path, case: FuzzCase, result: CaseResult) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"case": case.to_dict(), "result": result.to_dict()},
                               indent=2) + "\n")
    return path


def replay(path: Path, on_tick: Callable[[FaultyRakeLoop], None] | None = None
           ) -> tuple[CaseResult, CaseResult | None]:
    """Re-run a case file (a campaign's worst case, or a regression case): (result now,
    result recorded in the file, if any)."""
    case, recorded = read_case_file(path)
    return run_case(case, on_tick=on_tick), recorded


def read_case_file(path: Path) -> tuple[FuzzCase, CaseResult | None]:
    """The case a case file holds, and the result recorded with it, if any."""
    data = json.loads(Path(path).read_text())
    recorded = result_from_dict(data["result"]) if "result" in data else None
    return case_from_dict(data["case"]), recorded
