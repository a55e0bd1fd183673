"""The benchmark's machinery on small inputs: structure and finite figures, never timing."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rakectl.bench import loop as loop_module
from rakectl.bench.excavation import SOILS, Controller, LaneShape, RunResult, run_excavation
from rakectl.bench.excavation_text import format_excavation
from rakectl.bench.hot_path import hot_path_section, write_hot_path_section
from rakectl.bench.loop import DAEMON_SETTINGS, LoopFigures, format_loop
from rakectl.bench.report import (
    BENCHMARKS_FILE,
    EXCAVATION_END,
    EXCAVATION_START,
    LOOP_END,
    LOOP_START,
    TICK_END,
    TICK_START,
    BenchOptions,
    _loop_section,
    machine_facts,
    markdown,
    write_excavation,
    write_loop_section,
)
from rakectl.bench.tick import STAGES, bench_tick, format_tick
from rakectl.cli.main import main as rakectl_main
from rakectl.config.files import config_dir
from rakectl.config.loader import load_settings
from rakectl.config.service import RtModeSetting
from rakectl.config.settings import CYCLE_BITS, held_command_gap
from rakectl.errors import RakeError
from rakectl.sim.parallel import DaskExecutor

TINY = LaneShape(reach_far_m=1.3, reach_near_m=1.15, target_depth_m=0.005)  # clay stalls at 10 mm


def _timing(p50_ns: int) -> dict[str, Any]:
    p = {"p50": p50_ns, "p99": 2 * p50_ns, "p99.9": 3 * p50_ns, "max": 4 * p50_ns}
    return {"oversleep_ns": p, "latency_ns": p, "exec_ns": p, "overruns": 1,
            "longest_gap_ns": 5 * p50_ns}


def _loop_figures(cyclictest: bool) -> LoopFigures:
    ticks = 10_000
    bus = {"syncs": ticks, "sends": 3 * ticks + ticks // 100, "tpdo_received_r": ticks - 3,
           "tpdo_received_theta": ticks, "tpdo_missed_r": 3, "tpdo_missed_theta": 0,
           "tpdo2_received_r": ticks // 100, "tpdo2_received_theta": ticks // 100,
           "heartbeats_received": ticks // 50, "sync_to_tpdo_p50_us": 55.0}
    ct = ({"label": "cyclictest -m -p 80 -i 1000", "samples": 5000,
           "latency_ns": {"p50": 10_000, "p99": 40_000, "p99.9": 80_000, "max": 90_000}}
          if cyclictest else None)
    phase = {"status": {"timing": _timing(20_000), "state": "armed"}, "gc_gen2": 0,
             "start_state": "armed"}
    reasons = () if cyclictest else ("cyclictest not found: apt-get install -y rt-tests",)
    return LoopFigures(5.0, ct, reasons, phase, phase, bus)


def test_loop_figures_bus_load_and_ratio() -> None:
    figures = _loop_figures(cyclictest=True)
    assert figures.tpdo_missed() == (3, 20_000)
    # the design's 435 bits, plus heartbeats and TPDO2 refreshes, less 3 missed TPDO1s
    assert CYCLE_BITS < figures.bits_per_cycle() < CYCLE_BITS + 5
    assert figures.wakeup_ratio(figures.idle) == pytest.approx(1.0)
    assert "p99 OS wake-up / cyclictest p99: 1.00×" in format_loop(figures)


def test_a_phase_the_daemon_did_not_spend_armed_is_named() -> None:
    """A drive's 3 ms watchdog tripped by a stall of the machine faults the daemon, whose
    loop then ticks with less to do: its figures are not the armed loop's."""
    figures = _loop_figures(cyclictest=True)
    assert "NOT ARMED" not in format_loop(figures)
    status = {"timing": _timing(20_000), "state": "fault",
              "fault": "r drive (node 1): EMCY 0x8250 COMMAND_WATCHDOG_TIMEOUT"}
    faulted = dataclasses.replace(
        figures, loaded={"status": status, "gc_gen2": 0, "start_state": "armed"},
        viewed={"status": status, "gc_gen2": 0, "start_state": "fault",
                "viewer_messages": 10})
    text = format_loop(faulted)
    assert ("NOT ARMED by the phase's end (fault: r drive (node 1): EMCY 0x8250 "
            "COMMAND_WATCHDOG_TIMEOUT): these figures are not the armed loop's") in text
    assert "NOT ARMED throughout the phase (fault: " in text
    assert text.count("NOT ARMED") == 2  # the idle phase was armed
    rows = [line for line in _loop_section(faulted, text, "rakectl bench --loop", "now", "t")
            if line.startswith("| daemon,")]
    assert [row.split(" | ")[0] for row in rows] == [
        "| daemon, idle", "| daemon, status at 100 Hz (NOT ARMED: see the printout)",
        "| daemon, rakectl view at 50 Hz, watched (NOT ARMED: see the printout)"]


class _ScriptedBench:
    """The daemon's states as a bench's status replies give them, one per request, and
    the requests it was sent."""

    def __init__(self, states: list[str], out: Path) -> None:
        self.states, self.out, self.sent = states, out, []  # type: list[str]

    def request(self, cmd: str) -> dict[str, object]:
        self.sent.append(cmd)
        if cmd == "reset":
            self.states.insert(0, "disarmed")
        return {"state": self.states.pop(0) if len(self.states) > 1 else self.states[0]}

    def wait_for_state(self, states: list[str], timeout_s: float) -> dict[str, object]:
        return self.request("status")

    def arm_when_timed(self, timeout_s: float) -> dict[str, object]:
        self.states.insert(0, "checking")
        return self.request("arm")


def test_a_fault_while_arming_is_reset_and_armed_again(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The first arming runs the weight check; a drive watchdog tripped meanwhile (a stall
    of the machine) leaves the daemon in FAULT, not ARMED: the benchmark resets it and arms
    again instead of timing out on 'armed'."""
    monkeypatch.setattr(loop_module.time, "sleep", lambda s: None)
    bench = _ScriptedBench(["checking", "fault", "armed"], tmp_path)
    loop_module._armed(bench)  # type: ignore[arg-type]
    assert bench.sent == ["status", "status", "reset", "status", "arm", "status"]


def test_a_daemon_that_never_arms_is_named(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(loop_module.time, "sleep", lambda s: None)
    with pytest.raises(RakeError) as raised:
        loop_module._armed(_ScriptedBench(["checking"], tmp_path), 0.0)  # type: ignore[arg-type]
    assert str(raised.value) == (f"the loop benchmark could not arm the daemon within 0 s "
                                 f"(last: checking); see {tmp_path}/daemon.log")


def test_a_missing_cyclictest_says_how_to_install_it() -> None:
    figures = _loop_figures(cyclictest=False)
    assert math.isnan(figures.wakeup_ratio(figures.idle))
    assert "apt-get install -y rt-tests" in format_loop(figures)


def test_the_loop_benchmarks_daemon_is_real_time_and_arms() -> None:
    """The loop benchmark's daemon sets itself up real-time (its failures reported, not
    refused) with the bench file's 100 ms drive watchdog: enforce would refuse to arm with
    it (every `rakectl bench --loop` was refused), and the robot's 3 ms is tripped by the
    stalls of a shared machine."""
    s = load_settings(config_dir() / "rakectl-emulated.yaml", DAEMON_SETTINGS)
    assert s.daemon.rt_mode is RtModeSetting.IGNORE
    assert s.drives.watchdog_timeout_ms == 100 and held_command_gap(s)


def test_the_loop_benchmark_says_when_the_daemon_was_not_real_time() -> None:
    figures = dataclasses.replace(_loop_figures(cyclictest=True), priority=None,
                                  rt_problems=("SCHED_FIFO priority 80 refused",))
    lines = format_loop(figures).splitlines()
    assert lines[0] == ("loop benchmark: 5 s per phase, daemon NOT real-time, emulator "
                        "SCHED_FIFO 70")
    assert lines[1] == "  real-time set-up: SCHED_FIFO priority 80 refused"
    assert format_loop(_loop_figures(cyclictest=True)).startswith(
        "loop benchmark: 5 s per phase, daemon SCHED_FIFO 80, emulator SCHED_FIFO 70\n")


def test_the_loop_alone_rewrites_its_sections_and_nothing_else(tmp_path: Path) -> None:
    """``rakectl bench --loop`` replaces sections (a) and (c) in place (once the file has
    their markers; appended before), the rest as it was."""
    path = tmp_path / BENCHMARKS_FILE
    path.write_text("# Benchmarks\n\nhead\n\n" + "\n".join(hot_path_section(
        "rakectl bench --profiles", "then", "old1234", "hot path text")))
    write_loop_section(path, _loop_figures(True), "first printout", "rakectl bench --loop",
                       "then", "old1234")
    before = path.read_text()
    assert before.count(LOOP_START) == 1 and "first printout" in before
    write_loop_section(path, _loop_figures(False), "second printout",
                       "rakectl bench --loop --seconds 5", "now", "new5678")
    after = path.read_text()
    assert after.count(LOOP_START) == after.count(LOOP_END) == 1
    head, tail = before.split(LOOP_START)[0], before.split(LOOP_END)[1]
    assert after.startswith(head + LOOP_START) and after.endswith(LOOP_END + tail)
    section = after.split(LOOP_START)[1].split(LOOP_END)[0]
    assert "`rakectl bench --loop --seconds 5` on now, tree new5678" in section
    assert "second printout" in section and "first printout" not in after
    assert "## (a) The loop's wake-up latency" in section and "## (c) Cross-process" in section
    assert "cyclictest was not measured: cyclictest not found" in section
    assert "hot path text" in after


def test_the_tick_alone_rewrites_its_section_and_nothing_else(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``rakectl bench --tick`` prints the stages and replaces section (b) in place (once
    the file has its markers; appended before), the rest as it was."""
    path = tmp_path / BENCHMARKS_FILE
    path.write_text("# Benchmarks\n\nhead\n\n" + "\n".join(hot_path_section(
        "rakectl bench --profiles", "then", "old1234", "hot path text")))
    argv = ["bench", "--tick", "--ticks", "1000", "--report", str(tmp_path)]
    assert rakectl_main(argv) == 0
    out = capsys.readouterr().out
    assert "whole Daemon.tick" in out and out.endswith(f"written: section (b) of {path}\n")
    before = path.read_text()
    assert before.count(TICK_START) == before.count(TICK_END) == 1
    first = before.split(TICK_START)[1].split(TICK_END)[0]
    assert f"`rakectl {' '.join(argv[:-2])} --report {tmp_path}` on " in first
    assert "## (b) Per-tick compute, by stage" in first and "**whole tick**" in first
    assert rakectl_main(argv) == 0
    after = path.read_text()
    assert after.count(TICK_START) == after.count(TICK_END) == 1
    head, tail = before.split(TICK_START)[0], before.split(TICK_END)[1]
    assert after.startswith(head + TICK_START) and after.endswith(TICK_END + tail)
    assert "hot path text" in after


SWEEP = (0.1, 0.05, 0.03)


@pytest.fixture(scope="module")
def excavation() -> Any:
    return run_excavation(TINY, workers=2, sweep_speeds=SWEEP)


@pytest.mark.slow
def test_excavation_report_has_every_soil_and_controller_with_finite_figures(
        excavation: Any) -> None:
    assert [(r.job.soil, r.job.controller) for r in excavation.results] == [
        (soil, controller) for soil in SOILS for controller in Controller]
    assert excavation.sweep.tried and math.isfinite(excavation.sweep.speed_m_per_s)
    for r in excavation.results:
        assert r.reached, (r.job, r.fault)
        assert r.depth_reached_m == pytest.approx(TINY.target_depth_m)
        for value in (r.time_s, r.f_true_z_max_n, r.f_estimate_max_n,
                      r.stroke_speed_mean_m_per_s, *r.phase_s.values()):
            assert math.isfinite(value) and value >= 0.0
        assert r.series is not None and len(r.series.t_s) == len(r.series.f_true_z_n) > 10
        # the tiny lane is one 10 mm cut; an adaptive lane gives a place where the tine rode
        # more than 3 mm high one more stroke
        assert r.cycles == 1 or (r.job.controller == Controller.ADAPTIVE and r.cycles == 2)
        assert 0.0 < r.floor_true_m <= 0.0105  # the soil's own floor, at most about that deep
    for soil in SOILS:
        assert math.isfinite(excavation.speedup(soil)) and excavation.stroke_bound(soil) >= 1.0
    text = format_excavation(excavation)
    assert "fixed-safe stroke speed" in text and "Goal" in text
    assert "adaptive time by phase: sand (1 cycle): approach" in text
    assert len(text.splitlines()) >= 9 + 4


@pytest.mark.slow
def test_position_control_has_no_force_estimate_from_the_delay(excavation: Any) -> None:
    """α = 0: F̂ ≡ 0, so its supervised estimate is the current-based one alone."""
    for soil in SOILS:
        position = excavation.result(soil, Controller.POSITION)
        assert "estimator.delay_s=0" in position.job.overrides


@pytest.mark.slow
def test_plots_and_the_report_file(excavation: Any, tmp_path: Path) -> None:
    from rakectl.bench.plot import plot_excavation

    plot_excavation(excavation, "clay", tmp_path / "clay.png")
    assert (tmp_path / "clay.png").stat().st_size > 10_000
    tick = bench_tick(300)
    assert set(tick.stages_us) == {name for name, _ in STAGES}
    assert all(math.isfinite(v) for pair in tick.stages_us.values() for v in pair)
    assert "whole Daemon.tick" in format_tick(tick)
    options = BenchOptions("rakectl bench --all --quick", 5.0, 300, True, 2, tmp_path,
                           tmp_path)
    text = markdown(options, "today", _loop_figures(True), "loop text", tick, excavation,
                    "abc1234")
    assert text.startswith("# Benchmarks\n\nGenerated by `rakectl bench --all --quick`")
    for heading in ("## (a)", "## (b)", "## (c)", "## (d)"):
        assert heading in text
    for fact in machine_facts():
        assert f"- **{fact}**:" in text
    assert "![clay](excavation-clay.png)" in text
    missing = markdown(options, "today", None, "loop benchmark not run: no namespace", tick,
                       excavation, "abc1234")
    assert "loop benchmark not run: no namespace" in missing


def test_the_excavation_alone_rewrites_its_section_and_nothing_else(
        excavation: Any, tmp_path: Path) -> None:
    """``rakectl bench --excavation`` replaces section (d) of a file ``--all`` wrote (and
    ``--profiles`` added to), in place, and writes its plots next to it."""
    options = BenchOptions("rakectl bench --all", 5.0, 300, False, 2, tmp_path, tmp_path)
    tick = bench_tick(300)
    path = tmp_path / BENCHMARKS_FILE
    path.write_text(markdown(options, "then", _loop_figures(True), "loop text", tick,
                             excavation, "old1234"))
    write_hot_path_section(path, hot_path_section("rakectl bench --profiles", "then",
                                                  "old1234", "hot path text"))
    before = path.read_text()
    head, tail = before.split(EXCAVATION_START)[0], before.split(EXCAVATION_END)[1]
    assert "`rakectl bench --all` on then, tree old1234" in before.split(EXCAVATION_END)[0]
    assert write_excavation(excavation, tmp_path, "rakectl bench --excavation", "now",
                            "new5678") == path
    after = path.read_text()
    assert after.count(EXCAVATION_START) == after.count(EXCAVATION_END) == 1
    assert after.startswith(head + EXCAVATION_START) and after.endswith(EXCAVATION_END + tail)
    section = after.split(EXCAVATION_START)[1].split(EXCAVATION_END)[0]
    assert "`rakectl bench --excavation` on now, tree new5678" in section
    assert "old1234" not in section and "## (d) Excavation" in section
    assert "not the benchmark's figures" in section  # TINY is not the reference lane
    for soil in SOILS:
        assert (tmp_path / f"excavation-{soil}.png").stat().st_size > 10_000


def _figures(r: RunResult) -> str:
    """Every field of a run but its wall time and its series, exactly (repr: nan == nan)."""
    return repr({f.name: getattr(r, f.name) for f in dataclasses.fields(r)
                 if f.name not in ("wall_s", "series")})


@pytest.mark.slow
@pytest.mark.usefixtures("dask_offload_thread")
def test_the_excavation_on_a_local_cluster_gives_the_local_pools_figures(
        excavation: Any) -> None:
    executor = DaskExecutor("local:2")
    try:
        dask = run_excavation(TINY, sweep_speeds=SWEEP, executor=executor)
    finally:
        executor.close()
    assert dask.sweep.speed_m_per_s == excavation.sweep.speed_m_per_s
    local_runs = [*excavation.sweep.tried, *excavation.results]
    dask_runs = [*dask.sweep.tried, *dask.results]
    assert [r.job for r in dask_runs] == [r.job for r in local_runs]  # in the jobs' order
    for ours, theirs in zip(local_runs, dask_runs, strict=True):
        assert _figures(theirs) == _figures(ours)
        if ours.series is not None:
            assert theirs.series is not None
            for field in dataclasses.fields(ours.series):
                assert np.array_equal(getattr(theirs.series, field.name),
                                      getattr(ours.series, field.name)), field.name


def test_the_campaign_benchmark_quick_runs_a_few_cases_and_counts_them(
        tmp_path: Path, physics_build: Path) -> None:
    """`bench --campaign --quick` ran the full --cases (60) with each physics, and its
    progress gave no count. --quick runs QUICK_CAMPAIGN_CASES, each line says which of
    how many, and the section goes where --report says (out/bench by default). The
    compiled physics is the test run's own build (the benchmark builds into the cache it
    is given: the run's empty one would then not be empty for the tests after it)."""
    import os
    import subprocess
    import sys

    from rakectl.cli.bench import QUICK_CAMPAIGN_CASES
    from tests.cli_run import ROOT

    done = subprocess.run(
        [sys.executable, "-m", "rakectl", "bench", "--campaign", "--quick", "--report",
         str(tmp_path)], capture_output=True, text=True, timeout=600.0, cwd=ROOT,
        env={**os.environ, "RAKECTL_PHYSICS_CACHE": str(physics_build)})
    assert done.returncode == 0, done.stderr
    progress = done.stdout + done.stderr
    last = f"case {QUICK_CAMPAIGN_CASES} of {QUICK_CAMPAIGN_CASES}, "
    assert progress.count(last) == 2  # the Python physics, then the compiled
    assert f"case {QUICK_CAMPAIGN_CASES + 1} of" not in progress
    assert (tmp_path / BENCHMARKS_FILE).is_file()
