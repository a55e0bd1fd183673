"""``rakectl bench --all``: every benchmark in one run, printed, and BENCHMARKS.md written.

In order (the loop's latency first, while nothing else of ours runs):
(a) the daemon's wake-up latency next to cyclictest's, and (c) the same
cross-process 1 kHz run's late ticks, missed feedback and bus load
(rakectl.bench.loop); (b) the per-tick compute by stage (rakectl.bench.tick);
(e) the drive client's hot path per drive profile (rakectl.bench.hot_path);
(f) the safety campaign's speed per core, its physics as Python and compiled
(rakectl.bench.throughput); (d) the
excavation benchmark (rakectl.bench.excavation), the longest, with one plot
per soil. The excavation's figures are put into words by
rakectl.bench.excavation_text (the table, the sweep, the time budget, the
goal). The Markdown file says it is generated, by which command, when and on
what machine. Figures only: nothing here
passes or fails but the excavation's stated goal, which is reported, not
enforced.
"""

from __future__ import annotations

import math
import os
import platform
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rakectl.bench.excavation import (
    FULL,
    QUICK,
    SOILS,
    Controller,
    ExcavationReport,
    run_excavation,
    scenario_path,
)
from rakectl.bench.excavation_text import (
    HEADER,
    LIMIT,
    adaptive_phases_line,
    describe_lane,
    format_excavation,
    goal_line,
    sweep_lines,
    table_rows,
    time_budget_line,
)
from rakectl.bench.hot_path import bench_hot_path, hot_path_section, write_hot_path_section
from rakectl.bench.loop import LoopFigures, format_loop, measure_loop, not_armed
from rakectl.bench.sections import markdown_table, markers, write_section
from rakectl.bench.throughput import (
    CASES,
    compare_physics,
    format_comparison,
    write_throughput_section,
)
from rakectl.bench.tick import STAGES, TickFigures, bench_tick, format_tick
from rakectl.config.loader import load_settings
from rakectl.config.settings import CYCLE_BITS
from rakectl.errors import RakeError
from rakectl.sim.parallel import executor_for
from rakectl.sim.scenario import Scenario

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS_FILE = "BENCHMARKS.md"


@dataclass(frozen=True)
class BenchOptions:
    command: str  # as typed, for the report
    seconds: float  # per phase of the loop benchmark
    ticks: int  # per phase of the tick benchmark
    quick: bool
    workers: int
    out: Path  # scratch: the loop benchmark's logs
    report: Path  # BENCHMARKS.md and the plots
    scheduler: str | None = None  # a Dask cluster for the excavation runs (else local)
    cases: int = CASES  # campaign cases timed for (f)


def machine_facts() -> dict[str, str]:
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.partition(":")[2].strip()
                break
    except OSError:
        pass
    return {"CPU": model, "cores": str(os.cpu_count()), "kernel": platform.release(),
            "OS": platform.platform(), "Python": platform.python_version(),
            "tree": git_revision()}


def git_revision() -> str:
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=True)
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain",
                                "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown (not a git checkout)"
    return head.stdout.strip() + (" with uncommitted changes" if dirty.stdout.strip() else "")


def run_all(options: BenchOptions, echo: Callable[[str], None]) -> Path:
    """Run (a)–(f), echoing as it goes; write BENCHMARKS.md and the plots; return its path."""
    started = time.strftime("%Y-%m-%d %H:%M %Z")
    echo(f"(a, c) the daemon's loop on the emulated bench, {options.seconds:g} s per phase …")
    loop: LoopFigures | None = None
    try:
        loop = measure_loop(options.seconds, options.out)
        loop_text = format_loop(loop)
    except (RakeError, OSError) as exc:
        loop_text = f"loop benchmark not run: {exc}"
    echo(loop_text)
    echo(f"(b) per-tick compute, {options.ticks} ticks per phase …")
    tick = bench_tick(options.ticks)
    echo(format_tick(tick))
    echo("(e) the drive client's hot path, per drive profile …")
    hot_path = bench_hot_path(max(1000, options.ticks))
    echo(hot_path)
    echo(f"(f) the campaign's speed per core, {options.cases} cases …")
    throughput = compare_physics(cases=options.cases, progress=echo)
    echo(format_comparison(throughput))
    echo("(d) excavation …")
    excavation = excavate(options.scheduler, options.workers, options.quick, echo)
    echo(format_excavation(excavation))
    tree = git_revision()
    options.report.mkdir(parents=True, exist_ok=True)
    plot_all(excavation, options.report)
    path = options.report / BENCHMARKS_FILE
    path.write_text(markdown(options, started, loop, loop_text, tick, excavation, tree))
    write_hot_path_section(path, hot_path_section(options.command, started, tree, hot_path))
    write_throughput_section(path, options.command, started, tree, throughput)
    echo(f"written: {path} and {len(SOILS)} plots next to it")
    return path


def excavate(scheduler: str | None, workers: int, quick: bool,
             echo: Callable[[str], None]) -> ExcavationReport:
    """Part (d)'s runs on the executor ``scheduler`` names (else ``workers`` local
    processes), closed afterwards; progress to ``echo`` as each run ends."""
    executor = executor_for(scheduler, workers)
    try:
        echo(f"    on {executor.describe()}")
        return run_excavation(QUICK if quick else FULL,
                              progress=lambda line: echo(f"  {line}"), executor=executor)
    finally:
        executor.close()


def plot_all(excavation: ExcavationReport, report: Path) -> None:
    """One plot per soil, ``report/excavation-SOIL.png``."""
    from rakectl.bench.plot import plot_excavation

    for soil in SOILS:
        plot_excavation(excavation, soil, report / f"excavation-{soil}.png")


def write_excavation(excavation: ExcavationReport, report: Path, command: str,
                     started: str, tree: str) -> Path:
    """Part (d) run alone: its plots, and its section of ``report/BENCHMARKS.md`` in place
    of the last one (the rest of the file as ``rakectl bench --all`` wrote it)."""
    report.mkdir(parents=True, exist_ok=True)
    plot_all(excavation, report)
    path = report / BENCHMARKS_FILE
    write_section(path, EXCAVATION_START, EXCAVATION_END,
                  _excavation_section(excavation, command, started, tree))
    return path


# --------------------------------------------------------------------------- Markdown


def markdown(options: BenchOptions, started: str, loop: LoopFigures | None, loop_text: str,
             tick: TickFigures, excavation: ExcavationReport, tree: str) -> str:
    facts = machine_facts()
    lines = ["# Benchmarks", "",
             f"Generated by `{options.command}` on {started}: do not edit, re-run it. "
             "Figures, not pass/fail: these machines are shared and noisy, and timing is "
             "never asserted in tests.", "",
             *(f"- **{key}**: {value}" for key, value in facts.items()), ""]
    lines += _loop_section(loop, loop_text, options.command, started, tree)
    lines += _tick_section(tick, options.command, started, tree)
    lines += _excavation_section(excavation, options.command, started, tree)
    return "\n".join(lines) + "\n"


def _us(ns: float) -> str:
    return f"{ns / 1e3:.0f}"


LOOP_START, LOOP_END = markers("loop", "rakectl bench --loop")


def write_loop_section(path: Path, loop: LoopFigures, text: str, command: str, started: str,
                       tree: str) -> None:
    """Parts (a) and (c) run alone, into ``path`` in place of their last version; the rest
    of the file as ``rakectl bench --all`` wrote it."""
    write_section(path, LOOP_START, LOOP_END, _loop_section(loop, text, command, started, tree))


def _loop_section(loop: LoopFigures | None, text: str, command: str, started: str,
                  tree: str) -> list[str]:
    lines = [LOOP_START, "## (a) The loop's wake-up latency, next to cyclictest", "",
             f"`{command}` on {started}, tree {tree}.", ""]
    if loop is None:
        return [*lines, text, "", "## (c) Cross-process 1 kHz run", "", text, LOOP_END, ""]
    rows: list[tuple[str, ...]] = []
    if loop.cyclictest is not None:
        p = loop.cyclictest["latency_ns"]
        rows.append((loop.cyclictest["label"], _us(p["p50"]), _us(p["p99"]), _us(p["p99.9"]),
                     _us(p["max"]), "—", "1×"))
    for name, phase in loop.phases():
        t = phase["status"]["timing"]
        p = t["oversleep_ns"]
        ratio = loop.wakeup_ratio(phase)
        label = f"daemon, {name}" + (" (NOT ARMED: see the printout)" if not_armed(phase)
                                     else "")
        rows.append((label, _us(p["p50"]), _us(p["p99"]), _us(p["p99.9"]),
                     _us(p["max"]), str(t["overruns"]),
                     f"{ratio:.2f}×" if math.isfinite(ratio) else "—"))
    if loop.cyclictest is None:
        reasons = "; ".join(loop.cyclictest_reasons) or "unavailable"
        lines += [f"cyclictest was not measured: {reasons}.", ""]
    daemon = (f"daemon SCHED_FIFO {loop.priority}" if loop.priority is not None else
              "daemon NOT real-time" + (f" ({'; '.join(loop.rt_problems)})"
                                        if loop.rt_problems else ""))
    lines += [f"{loop.seconds:g} s per phase, {daemon}, emulator SCHED_FIFO 70, "
              "both as separate processes over udp_multicast in a private network namespace. "
              "The daemon's figure is how late its sleep woke before the spin (what compares "
              "with cyclictest's clock_nanosleep); late ticks are ticks that began after "
              "their deadline's slack.", "",
              *markdown_table(("wake-up latency (µs)", "p50", "p99", "p99.9", "max",
                               "late ticks", "p99 / cyclictest p99"), rows), ""]
    missed, expected = loop.tpdo_missed()
    bus = loop.bus
    lines += ["## (c) Cross-process 1 kHz run (udp_multicast, private namespace)", "",
              f"- late ticks: {loop.idle['status']['timing']['overruns']} idle, "
              f"{loop.loaded['status']['timing']['overruns']} with status at 100 Hz",
              f"- missed feedback: {missed} of {expected} TPDO1 missed their tick; "
              f"SYNC → TPDO1 p50 {bus.get('sync_to_tpdo_p50_us', math.nan)} µs, p99 "
              f"{bus.get('sync_to_tpdo_p99_us', math.nan)} µs, max "
              f"{bus.get('sync_to_tpdo_max_us', math.nan)} µs",
              f"- bus load at 1 Mbit/s: {loop.bits_per_cycle():.0f} bits per 1 ms cycle = "
              f"{loop.bits_per_cycle() / 10:.1f} % before bit stuffing, from the frames the "
              f"daemon counted (design: SYNC + 2 TPDO1 + 2 RPDO1 = {CYCLE_BITS} bits, "
              f"{CYCLE_BITS / 10:.1f} %)", "",
              "The whole printout:", "", "```text", text, "```", LOOP_END, ""]
    return lines


TICK_START, TICK_END = markers("tick", "rakectl bench --tick")


def write_tick_section(path: Path, tick: TickFigures, command: str, started: str,
                       tree: str) -> None:
    """Part (b) run alone, into ``path`` in place of its last version."""
    write_section(path, TICK_START, TICK_END, _tick_section(tick, command, started, tree))


def _tick_section(tick: TickFigures, command: str, started: str, tree: str) -> list[str]:
    rows = [(name, f"{tick.stages_us[name][0]:.1f}", f"{tick.stages_us[name][1]:.1f}", what)
            for name, what in STAGES]
    rows.append(("rest", f"{tick.rest_us[0]:.1f}", f"{tick.rest_us[1]:.1f}",
                 "the tick less the stages: states, checks, the timers' own calls"))
    rows.append(("**whole tick**", f"{tick.tick_us[0]:.1f}", f"{tick.tick_us[1]:.1f}",
                 f"Daemon.tick without timers (max {tick.tick_us[2]:.0f} µs)"))
    return [TICK_START, "## (b) Per-tick compute, by stage", "",
            f"`{command}` on {started}, tree {tree}.", "",
            f"The real `Daemon.tick` in lock-step with the emulated drives on python-can's "
            f"`virtual` bus, raking loam with the adaptive lane, {tick.ticks} ticks timed "
            "whole, then as many with each stage timed inside its own object (the real "
            f"methods, not copies; {tick.timer_overhead_ns:.0f} ns of timer per call "
            "subtracted). Decode and encode include python-can's `VirtualBus` (about 6 µs "
            "per frame sent), which a SocketCAN bus replaces.", "",
            *markdown_table(("stage", "p50 µs", "p99 µs", "what"), rows), TICK_END, ""]


EXCAVATION_START, EXCAVATION_END = markers("excavation", "rakectl bench --excavation")


def _excavation_section(report: ExcavationReport, command: str, started: str,
                        tree: str) -> list[str]:
    """Section (d), between its markers; ``command`` ran it on ``started``, on ``tree``."""
    scenarios = {soil: load_settings(scenario_path(soil), root=Scenario) for soil in SOILS}
    collapse = ", ".join(f"{s.emulator.ground.soil.layers[0].collapse_force_n:g}"
                         for s in scenarios.values())
    lane, supervision = scenarios["clay"].lane, scenarios["clay"].supervision
    position = [report.result(soil, Controller.POSITION) for soil in SOILS]
    over = [r for r in position if r.ticks_over_limit > 0 or r.mines_activated > 0]
    worst = max(r.f_true_z_max_n for r in position)
    lines = [EXCAVATION_START, f"## (d) Excavation: time to rake a lane to depth, within {LIMIT}",
             "", f"`{command}` on {started}, tree {tree}; {report.wall_s / 60:.0f} min of wall "
             "time.", ""]
    if report.shape != FULL:
        lines += ["**A shorter, shallower lane than the reference (`--quick`): not the "
                  "benchmark's figures.**", ""]
    chosen, *tried = sweep_lines(report)
    chosen = chosen.removeprefix("fixed-safe stroke speed: ")
    lines += [f"The lane: {describe_lane(report)}, in three reference soils "
              "(`config/scenarios/excavate-{sand,loam,clay}.yaml`: parameters and their "
              "sources in the files; two 80 N mines lie 15 mm under the target depth). Each "
              "run is the full simulated chain: the daemon's controller, clamp and force "
              "supervision, the bus's one-tick delay, drivers/ physics; time is until the "
              "last stroke at the target depth ends (an adaptive lane's last one may be a "
              "partial stroke, or a second pass where the tine rode up); forces are the "
              "ground truth's.", "",
              "- **adaptive**: `lane.adaptive` (rakectl.core.governor): the stroke's speed follows "
              f"the larger force estimate toward {lane.force_target_share:g} × the "
              f"{supervision.caution_force_n:g} N caution level, and the tip's lag under half "
              f"the stall error, within {lane.min_stroke_speed_m_per_s:g}–"
              f"{report.top_speed_m_per_s:g} m/s; per 20 mm of reach, each cut is the one "
              "the last stroke really took there times its margin there under those set "
              f"points (at most doubled), from {lane.depth_step_m * 1e3:g} to "
              f"{lane.max_depth_step_m * 1e3:g} mm, deeper far from the robot, and strokes "
              "start where the lane is not yet done (`rakectl.core.cut_profile.CutProfile`); the "
              "plunge's speed follows the same "
              f"force set point from {lane.plunge_speed_m_per_s * 1e3:g} up to "
              f"{lane.max_plunge_speed_m_per_s * 1e3:g} mm/s.",
              "- **position**: pure position control, α = 0 everywhere (F̂ ≡ 0: the impedance "
              f"does nothing), strokes at the adaptive top speed ({report.top_speed_m_per_s:g} "
              "m/s). The clamp and the current-based supervision stay on: they are not the "
              "controller.",
              f"- **fixed-safe**: one stroke speed for every soil, {chosen}",
              *(f"  - {line.strip()}" for line in tried), "",
              *markdown_table(HEADER, table_rows(report)), "", f"**{goal_line(report)}**", "",
              time_budget_line(report) + ". The free-space return runs at the same speed "
              "for every controller (`lane.travel_speed_m_per_s`), and so do the baselines' "
              "plunges (`lane.plunge_speed_m_per_s`): the stroke's and the plunge's speeds can "
              "only win back their shares, and fewer, deeper cuts (adaptive) the per-cycle "
              "rest.", "", adaptive_phases_line(report) + ".", ""]
    if over:
        lines += [f"Pure position control exceeded the bound in "
                  f"{', '.join(r.job.soil for r in over)}: largest true force {worst:.0f} N.",
                  ""]
    else:
        lines += [f"Pure position control did **not** exceed {LIMIT} here (largest true force "
                  f"{worst:.0f} N). The emulated soil gives way at its collapse force (the "
                  f"paper's saw-tooth: {collapse} N in sand, loam and clay, ±20 % per cell), "
                  "so a tip driven into it does not build force without bound, and the clamp "
                  "limits how hard "
                  "the motors can push in any case. The paper's point, that position control "
                  "on a stiff contact presses as hard as the motors allow, shows against a "
                  "contact that does not give way (a stone, a mine's plate): the safety "
                  "campaign (`rakectl fuzz`) covers those, with and without the clamp.", ""]
    lines += ["Reproduce one run: `rakectl simulate config/scenarios/excavate-SOIL.yaml --out "
              "DIR --plot` plus the controller's overrides: position `--set "
              "estimator.delay_s=0 --set lane.adaptive=false --set "
              f"lane.stroke_speed_m_per_s={report.top_speed_m_per_s:g}`, fixed-safe `--set "
              "lane.adaptive=false --set lane.stroke_speed_m_per_s=SPEED`.", ""]
    lines += [f"![{soil}](excavation-{soil}.png)" for soil in SOILS]
    return [*lines, EXCAVATION_END, ""]


__all__ = ["BenchOptions", "excavate", "machine_facts", "markdown", "run_all", "write_excavation"]
