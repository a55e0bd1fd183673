"""The closed-loop safety campaign: each case through the full simulated chain, judged
by the ground truth.

A case (:mod:`rakectl.sim.cases`) runs through the daemon's own
:class:`~rakectl.core.control.TipController`, the one-tick bus delay and drivers/
physics (:class:`~rakectl.sim.rake_plant.RakeLoop`), with its faults injected
between them (:class:`~rakectl.sim.injection.FaultyRakeLoop`). A case is safe when no tick's true
vertical force on the ground exceeds 90 N, no force on a mine's plate or side
exceeds 90 N and no mine fires. Side forces on stones and roots are reported.

The command and the faults are injected by :mod:`rakectl.sim.injection`. A case run
with its site declared (:mod:`rakectl.sim.site`) has the controller's descent limiter
on; its results and the report are in :mod:`rakectl.sim.results`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from drivers.objects import Contact
from drivers.soil import original_surface_height_m
from rakectl.config.descent import DescentSettings
from rakectl.config.settings import LaneSettings
from rakectl.core.clamp import VoltageClamp
from rakectl.core.lane import LanePlanner
from rakectl.core.supervision import ForceLevel
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim import chain
from rakectl.sim.case_files import read_case_file, write_case
from rakectl.sim.cases import CommandKind, Family, FuzzCase, generate
from rakectl.sim.compare import Key, key, read_results
from rakectl.sim.injection import FaultyRakeLoop, HoldReference, JogReference, PlungeReference
from rakectl.sim.parallel import Executor, LocalExecutor
from rakectl.sim.progress import Progress
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.results import (
    RESULTS_FILE,
    WORST_CASE_FILE,
    CaseResult,
    Report,
    finished_among,
    open_results,
)
from rakectl.sim.scenario import PlantKind, PlantSettings, Scenario, TrajectoryKind
from rakectl.sim.simulate import HOLD_AFTER_DONE_S, Reference
from rakectl.sim.site import declared_descent, refusal

AFTER_FAULT_S = 1.0  # simulated at 0 V after a latched fault


# --------------------------------------------------------------------------- running


def scenario_of(case: FuzzCase, descent: DescentSettings | None = None) -> Scenario:
    """The case's scenario; ``descent`` replaces the default descent budget's settings (a
    case with its site declared: that declaration, rakectl.sim.site)."""
    c = case.command
    if descent is None and case.declared_site:
        descent = declared_descent(case)
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
    return _lane(settings, loop, depth_m)


def _lane(settings: Scenario, loop: RakeLoop, depth_m: float) -> LanePlanner:
    """The case's lane, from ``depth_m`` at its far end, planned within the descent limit."""
    lane, descent = settings.lane, loop.controller.descent
    return LanePlanner(lane, 1.0 / settings.rate_hz, lane.reach_far_m, depth_m,
                       None if descent is None else descent.limit_at_m)


def run_case(case: FuzzCase, clamp: VoltageClamp | None = None,
             on_tick: Callable[[FaultyRakeLoop], None] | None = None,
             descent: DescentSettings | None = None,
             on_start: Callable[[FaultyRakeLoop], None] | None = None) -> CaseResult:
    """Run one case through the full chain; ``clamp`` replaces the real one (tests);
    ``on_tick`` sees the loop after every tick (a replay's telemetry), ``on_start``
    once before the first (a trace's recorder, rakectl.sim.trace); ``descent``
    replaces the descent budget's settings (a site's declared soil, the limiter on). A
    declaration the daemon would refuse at load runs nothing: its result says why."""
    settings = scenario_of(case, descent)
    refused = refusal(settings.descent, settings.clamp.force_limit_n,
                      settings.clamp.model_margin) if settings.descent.enforce else ""
    if refused:
        return _refused(case, refused)
    loop = FaultyRakeLoop(settings, *_start(case, settings), case.faults, clamp)
    loop.reset()
    reference = _reference(case, settings, loop)
    loop.arm_faults()
    if on_start is not None:
        on_start(loop)
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
            if after_fault:  # for AFTER_FAULT_S from the first such tick
                ticks, after_fault = min(ticks, k + after_fault), 0
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
        elif isinstance(reference, JogReference):  # the operator and the dead-man go on
            reference.step(held=True)
        hold -= reference.done
        if hold < 0:
            if not _asked_again(case, reference):
                break
            reference = _lane(settings, loop, depth_m)  # the operator asks again
            hold = round(HOLD_AFTER_DONE_S / dt_s)
    return _result(case, loop, reference, (peak_n, peak_t_s, over, k * dt_s))


def _asked_again(case: FuzzCase, reference: Reference) -> bool:
    """A mapped lane held by the descent limit, with nothing found and no force stop, is
    asked again (each pass maps the ground deeper) for as long as the case lasts."""
    return (case.family is Family.MAPPED and isinstance(reference, LanePlanner)
            and reference.held_by_descent and reference.found_at is None
            and not reference.stopped_by_force)


def _result(case: FuzzCase, loop: FaultyRakeLoop, reference: Reference,
            figures: tuple[float, float, int, float]) -> CaseResult:
    found = isinstance(reference, LanePlanner) and reference.found_at is not None

    def peak(kind: Contact, attribute: str) -> float:
        return max((getattr(b, attribute) for b in loop.ground.bodies if b.kind is kind),
                   default=0.0)

    return CaseResult(case.seed, case.index, _kind(case), figures[0], figures[1],
                      figures[2], loop.ground.truth.mine_activated, found, figures[3],
                      case.faults.kinds(), loop.feedback_lost, loop.commands_lost,
                      loop.drive_fault_ticks, loop.controller.clamp.clamped, loop.fault,
                      f_mine_plate_max_n=peak(Contact.MINE, "peak_down_n"),
                      f_mine_side_max_n=peak(Contact.MINE, "peak_side_n"),
                      f_stone_side_max_n=peak(Contact.STONE, "peak_side_n"),
                      f_root_side_max_n=peak(Contact.ROOT, "peak_side_n"),
                      supervised=case.supervised, stalled_ticks=loop.stalled_ticks,
                      watchdog_tripped=loop.watchdog_tripped, family=str(case.family),
                      declared_site=case.declared_site, chain=chain.digest())


def _kind(case: FuzzCase) -> str:
    """The command's kind as results name it: 'lane (adaptive)' for a force-adaptive lane."""
    return str(case.command.kind) + (" (adaptive)" if case.command.adaptive else "")


def _refused(case: FuzzCase, why: str) -> CaseResult:
    return CaseResult(case.seed, case.index, _kind(case), 0.0, 0.0, 0, False, False, 0.0,
                      case.faults.kinds(), 0, 0, 0, 0, "", supervised=case.supervised,
                      family=str(case.family), declared_site=case.declared_site, refused=why,
                      chain=chain.digest())


# --------------------------------------------------------------------------- campaign


def generated_case(seed: int, index: int, family: Family, declared_site: bool) -> FuzzCase:
    """Case ``index`` of ``seed`` in ``family``, its site declared if asked (as a campaign
    runs it)."""
    case = generate(seed, index, family)
    return dataclasses.replace(case, declared_site=True) if declared_site else case


def _run_index(job: tuple[int, int, str, bool]) -> CaseResult:
    seed, index, family, declared_site = job
    return run_case(generated_case(seed, index, Family(family), declared_site))


def _severity(r: CaseResult) -> float:
    return max(r.f_true_z_max_n, r.f_mine_max_n)


def _report(scenarios: int, results: Sequence[CaseResult], elapsed_s: float,
            resumed: int) -> Report:
    """The report on ``results``: the worst of them, and the case that replays it (drawn
    from its own seed, index, family and declaration)."""
    worst = max(results, key=_severity)
    case = generated_case(worst.seed, worst.index, Family(worst.family), worst.declared_site)
    return Report(scenarios, tuple(results), worst, case, elapsed_s, resumed=resumed)


def declares_sites(family: Family, declared_site: bool) -> bool:
    """Whether a campaign's cases run with their sites declared: on request, and always in
    the mapped family, whose cases are drawn for the descent limiter."""
    return declared_site or family is Family.MAPPED


def campaign(scenarios: int, seed: int, workers: int = 1, out_dir: Path | None = None,
             progress: Callable[[int, int], None] | None = None, first: int = 0,
             executor: Executor | None = None, family: Family = Family.RANDOM,
             declared_site: bool = False) -> Report:
    """Run cases ``first`` … ``first + scenarios − 1`` of ``seed``; write the worst one
    (the largest force on the ground or on a mine) to ``out_dir``: the worst of all the
    results there, where earlier parts left more (:attr:`Report.directory`).

    With ``out_dir``, each case's result is appended to :data:`RESULTS_FILE` there as it
    finishes, and a case already in that file (same seed and index) is not run again: an
    interrupted campaign resumes where it stopped, and a long one can be run in parts into
    one directory. Cases are deterministic from (seed, index), so the report is the same
    whichever run computed each case, and whatever ran it: ``executor`` (a Dask cluster,
    rakectl.sim.parallel) instead of ``workers`` local processes. ``family``: how the
    cases are drawn (:class:`~rakectl.sim.cases.Family`). ``declared_site``: each case's
    site declared and the descent limiter on (rakectl.sim.site), as the mapped family's
    always are; a site it would refuse counts as refused, not run.

    :class:`~rakectl.sim.chain.MixedChains`, before any case runs, if ``out_dir``'s results
    came from another version of the code and cases are left to run; or, as it happens,
    if a worker runs another version (a cluster's node): results of two versions are
    not one campaign's (:mod:`rakectl.sim.chain`)."""
    if scenarios < 1:
        raise ValueError("scenarios must be >= 1")
    declared_site = declares_sites(family, declared_site)
    started = time.perf_counter()
    wanted = range(first, first + scenarios)
    there = read_results(out_dir) if out_dir is not None and \
        (out_dir / RESULTS_FILE).is_file() else []  # earlier runs' (read once)
    done = finished_among(there, seed, wanted, family, declared_site)
    results: list[CaseResult] = list(done.values())
    jobs = [(seed, i, str(family), declared_site) for i in wanted if i not in done]
    code = chain.digest()
    if out_dir is not None and jobs:
        _refuse_other_chains(out_dir / RESULTS_FILE, there, code)
    sink = open_results(out_dir) if out_dir is not None and jobs else None
    try:
        if progress is not None and results:
            if isinstance(progress, Progress):  # its pace: the cases run now alone
                progress.skip(len(results))
            progress(len(results), scenarios)
        pool = executor if executor is not None else LocalExecutor(workers)
        for result in pool.map_unordered(_run_index, jobs):
            if result.chain != code:
                raise chain.MixedChains(
                    f"case {result.seed}/{result.index} ran on other code "
                    f"({chain.name(result.chain)}; this process runs {code}): every worker "
                    "must run this version")
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
    report = _report(scenarios, results, time.perf_counter() - started, len(done))
    if out_dir is None:
        return report
    everything = list({key(r): r for r in read_results(out_dir)}.values())  # every part's
    directory = _report(len(everything), everything, 0.0, 0) \
        if len(everything) > len(results) else None  # (a run's results are all in it)
    kept = directory or report  # the directory's worst case is never replaced by a better
    path = write_case(out_dir / WORST_CASE_FILE, kept.worst_case, kept.worst)
    return dataclasses.replace(report, worst_case_path=str(path), directory=directory)


def _refuse_other_chains(path: Path, there: Sequence[CaseResult], code: str) -> None:
    """:class:`~rakectl.sim.chain.MixedChains` if the results ``there`` (those of the
    results file ``path``) came from code other than ``code``."""
    others = [r.chain for r in there if r.chain != code]
    if others:
        raise chain.MixedChains(
            f"{path} holds results of other code: {chain.counted(others)}; this code is "
            f"{code}. One campaign's results come from one version: run into a new --out "
            f"(with --compare {path.parent}, to see what the change moved)")


def merged(out_dirs: Sequence[Path]) -> tuple[Report, dict[Path, int]]:
    """The finished campaigns in ``out_dirs`` (each a ``--out`` directory) as one report,
    and how many results each gave: several seeds, or one seed run in parts into several
    directories, judged and tabled together. Nothing runs. :class:`ValueError` naming the
    directory that has no results or is given twice, or the case found in two of them
    (its results could come from two chains: merged, it would count twice);
    :class:`~rakectl.sim.chain.MixedChains` (a ValueError) if the results came from more
    than one version of the code."""
    found: dict[Key, tuple[Path, CaseResult]] = {}
    counts: dict[Path, int] = {}
    chains: dict[Path, list[str]] = {}  # each directory's results' code
    for out_dir in out_dirs:
        if out_dir in counts:
            raise ValueError(f"{out_dir} is given twice")
        try:
            here = {key(r): r for r in read_results(out_dir)}  # last line wins
        except OSError as e:
            raise ValueError(f"{out_dir}: no campaign results there ({e})") from e
        if not here:
            raise ValueError(f"{out_dir}: its {RESULTS_FILE} holds no case's result")
        for k, r in here.items():
            if k in found:
                raise ValueError(f"case {r.seed}/{r.index} ({r.family}) is in both "
                                 f"{found[k][0]} and {out_dir}")
            found[k] = (out_dir, r)
        counts[out_dir] = len(here)
        chains[out_dir] = [r.chain for r in here.values()]
    if len({c for codes in chains.values() for c in codes}) > 1:
        raise chain.MixedChains("results of more than one version of the code: " + "; ".join(
            f"{d}: {chain.counted(codes)}" for d, codes in chains.items())
            + " (one campaign's results come from one version)")
    results = sorted((r for _, r in found.values()),
                     key=lambda r: (r.family, r.declared_site, r.seed, r.index))
    return _report(len(results), results, 0.0, len(results)), counts


def replay(path: Path, on_tick: Callable[[FaultyRakeLoop], None] | None = None
           ) -> tuple[CaseResult, CaseResult | None]:
    """Re-run a case file (a campaign's worst case, or a regression case): (result now,
    result recorded in the file, if any)."""
    case, recorded = read_case_file(path)
    return run_case(case, on_tick=on_tick), recorded
