"""Latency benchmark of the 1 kHz loop against cyclictest, measured in the same run.

``python -m rakectl.bench.wakeup --seconds 10`` runs, in interleaved rounds:
cyclictest (Debian ``rt-tests``), the daemon's `TickTimer` loop with the real-time
set-up of `rakectl.daemon.rt`, the same loop without it, and the loop with the set-up
but no spin (sleep only); then the hot-path micro-benchmarks
(`FlightRecorder.record_row` and the alternatives tried, `TimingStats.record`,
a chunked dump). It prints the figures.

Wake-up latency is ``actual wake − deadline``. The daemon's loop sleeps to
``spin_threshold`` before the deadline and spins the rest, so its latency
hides the sleep's own error; that error ("sleep overshoot", how late
``time.sleep`` returned) is printed too and is the figure that compares with
cyclictest's ``clock_nanosleep`` wake-up latency. Figures are printed, never
asserted: these machines are shared and noisy.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from typing import Any

import numpy as np

from rakectl.bench.recording import bench_dump, bench_hot_paths
from rakectl.daemon.cyclictest import NS_PER_US, merge_cyclictest, run_cyclictest
from rakectl.daemon.rt import GcMonitor, RtMode, RtRequest, apply_rt, no_gc, revert_rt
from rakectl.daemon.timing import (
    DEFAULT_SPIN_THRESHOLD_S,
    TickTimer,
    TimingStats,
    percentiles_ns,
)

# --- the daemon's loop -------------------------------------------------------------------


def _dummy_tick(k: int) -> float:
    """A tiny stand-in for a control step: a few float operations."""
    x_m = 1e-6 * k
    return 0.5 * x_m * x_m + 2.0 * x_m


class WakeupPhase:
    """One configuration of the daemon's loop; each `run` adds ticks, `result` summarizes them all.

    ``load`` runs in each tick's slack. The real-time set-up (``rt_mode``,
    ``request``) is applied to this thread for each run and reverted after it.
    """

    def __init__(
        self,
        rt_mode: RtMode,
        load: Callable[[], None] | None = None,
        *,
        capacity_s: float = 60.0,
        period_s: float = 1e-3,
        request: RtRequest | None = None,
        spin_threshold_s: float = DEFAULT_SPIN_THRESHOLD_S,
        disable_gc: bool = True,
    ) -> None:
        self.rt_mode, self.request, self.load = rt_mode, request, load
        self.period_s, self.spin_threshold_s = period_s, spin_threshold_s
        self.disable_gc = disable_gc
        self.stats = TimingStats(period_s, window_s=capacity_s)
        self._overshoot_ns = np.zeros(self.stats.capacity_ticks, dtype=np.int64)
        self.gc_collections = [0, 0, 0]
        self.gc_longest_pause_ns = 0
        self.label = ""
        self.warnings: list[str] = []

    def run(self, duration_s: float) -> None:
        """Apply the set-up, tick for ``duration_s``, revert."""
        report = apply_rt(self.rt_mode, self.request)
        try:
            with no_gc() if self.disable_gc else nullcontext(), GcMonitor() as monitor:
                self._loop(max(1, round(duration_s / self.period_s)))
        finally:
            revert_rt(report)
        self.gc_collections = [
            a + b for a, b in zip(self.gc_collections, monitor.collections, strict=True)
        ]
        self.gc_longest_pause_ns = max(self.gc_longest_pause_ns, monitor.longest_pause_ns)
        self.warnings.extend(w for w in report.warnings if w not in self.warnings)
        scheduler = "SCHED_OTHER" if report.priority is None else f"SCHED_FIFO {report.priority}"
        spin_us = self.spin_threshold_s * 1e6
        self.label = f"ours, {scheduler}, " + (
            f"spin {spin_us:.0f} µs" if spin_us else "sleep only"
        )

    def _loop(self, ticks: int) -> None:
        timer = TickTimer(self.period_s, spin_threshold_s=self.spin_threshold_s)
        stats, overshoot_ns, load = self.stats, self._overshoot_ns, self.load
        clock_ns = time.monotonic_ns
        stats.resume()
        timer.start()
        for k in range(ticks):
            skipped = timer.wait()
            _dummy_tick(k)
            stats.record(timer.wake_ns, timer.latency_ns, clock_ns() - timer.wake_ns, skipped)
            overshoot_ns[(stats.ticks - 1) % overshoot_ns.size] = timer.sleep_overshoot_ns
            if load is not None:
                load()

    def result(self) -> dict[str, Any]:
        filled = min(self.stats.ticks, self._overshoot_ns.size)
        return {
            **self.stats.summary(),
            "sleep_overshoot_ns": percentiles_ns(self._overshoot_ns[:filled]),
            "label": self.label,
            "rt_mode": self.rt_mode.value,
            "rt_warnings": self.warnings,
            "gc_disabled": self.disable_gc,
            "gc_collections": self.gc_collections,
            "gc_gen2_collections": self.gc_collections[2],
            "gc_longest_pause_ns": self.gc_longest_pause_ns,
        }


def bench_wakeup(
    duration_s: float, rt_mode: RtMode, load: Callable[[], None] | None = None, **options: Any
) -> dict[str, Any]:
    """Run the daemon's loop for ``duration_s`` (options: those of `WakeupPhase`); summarize."""
    phase = WakeupPhase(rt_mode, load, capacity_s=duration_s, **options)
    phase.run(duration_s)
    return phase.result()


def make_garbage() -> None:
    """A load that leaves a reference cycle per tick, for the cyclic collector to find."""
    node: list[Any] = [None] * 8
    node[0] = node


# --- report --------------------------------------------------------------------------------


def _us(value_ns: int) -> str:
    return f"{value_ns / NS_PER_US:8.1f}"


def _row(label: str, latency_ns: Mapping[str, int], extra: str = "") -> str:
    cells = "".join(_us(latency_ns[name]) for name in ("p50", "p99", "p99.9", "max"))
    return f"{label:<44}{cells}  {extra}"


def format_comparison(
    ours: Mapping[str, Any] | Sequence[Mapping[str, Any]],
    cyclictest: Mapping[str, Any] | None,
    cyclictest_reason: str = "",
) -> str:
    """The loop's runs and cyclictest side by side, with the ratio of p99s (goal: ≤ 2×)."""
    runs = [ours] if isinstance(ours, Mapping) else list(ours)
    lines = [f"{'wake-up latency, µs':<44}{'p50':>8}{'p99':>8}{'p99.9':>8}{'max':>8}"]
    if cyclictest is not None:
        samples = f"{cyclictest['samples']} samples"
        lines.append(_row(cyclictest["label"], cyclictest["latency_ns"], samples))
    else:
        lines.append(f"cyclictest: not measured ({cyclictest_reason or 'unavailable'})")
    for run in runs:
        lines.extend(_run_lines(run))
    lines.extend(_ratio_lines(runs, cyclictest))
    return "\n".join(lines)


def _run_lines(run: Mapping[str, Any]) -> list[str]:
    counts = f"{run['ticks']} ticks, {run['misses']} overruns, {run['skipped']} skipped"
    gap = f"longest gap {run['longest_gap_ns'] / 1e3:.0f} µs"
    gc_state = "disabled" if run["gc_disabled"] else "enabled"
    lines = [
        _row(run["label"], run["latency_ns"], counts),
        _row("  its time.sleep overshoot (before the spin)", run["sleep_overshoot_ns"]),
        _row("  its tick period", run["period_ns"], gap),
        _row("  its execution time (dummy tick)", run["exec_ns"]),
        f"  GC {gc_state}: collections per generation {run['gc_collections']}, generation-2 "
        f"{run['gc_gen2_collections']}, longest pause {run['gc_longest_pause_ns'] / 1e3:.0f} µs",
    ]
    lines.extend(f"  rt warning: {warning}" for warning in run["rt_warnings"])
    return lines


def _ratio_lines(
    runs: Sequence[Mapping[str, Any]], cyclictest: Mapping[str, Any] | None
) -> list[str]:
    if cyclictest is None or cyclictest["latency_ns"]["p99"] == 0:
        return []
    reference_ns = cyclictest["latency_ns"]["p99"]
    lines = []
    for run in runs:
        ratio = run["latency_ns"]["p99"] / reference_ns
        sleep_ratio = run["sleep_overshoot_ns"]["p99"] / reference_ns
        verdict = "meets" if ratio <= 2.0 else "misses"
        lines.append(
            f"p99 ratio {run['label']} / cyclictest: {ratio:.2f}× ({verdict} the ≤ 2× goal); "
            f"sleep overshoot alone {sleep_ratio:.2f}×"
        )
    return lines


def bench_interleaved(
    seconds: float, rounds: int, phases: Sequence[WakeupPhase], why_not: Callable[[str], None]
) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """``rounds`` rounds of cyclictest then each phase, ``seconds / rounds`` each; merged."""
    chunk_s = max(1, round(seconds / rounds))
    cyclictest_runs: list[dict[str, Any]] = []
    for round_index in range(rounds):
        result = None
        if round_index == 0 or cyclictest_runs:
            result = run_cyclictest(chunk_s, why_not=why_not)
        if result is not None:
            cyclictest_runs.append(result)
        for phase in phases:
            phase.run(chunk_s)
    merged = merge_cyclictest(cyclictest_runs) if cyclictest_runs else None
    return [phase.result() for phase in phases], merged


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rakectl.bench.wakeup", description=__doc__)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each phase")
    parser.add_argument("--rounds", type=int, default=5, help="interleave the phases this often")
    parser.add_argument(
        "--load",
        choices=("none", "garbage"),
        default="none",
        help="garbage: leave a reference cycle per tick, in the slack",
    )
    parser.add_argument(
        "--gc", choices=("off", "on"), default="off", help="cyclic GC in the runs (off: no_gc)"
    )
    parser.add_argument("--spin-us", type=float, default=DEFAULT_SPIN_THRESHOLD_S * 1e6)
    args = parser.parse_args(argv)
    options: dict[str, Any] = {
        "load": make_garbage if args.load == "garbage" else None,
        "capacity_s": args.seconds + args.rounds,
        "spin_threshold_s": args.spin_us * 1e-6,
        "disable_gc": args.gc == "off",
    }
    phases = [
        WakeupPhase(RtMode.IGNORE, **options),
        WakeupPhase(RtMode.OFF, **options),
        WakeupPhase(RtMode.IGNORE, **(options | {"spin_threshold_s": 0.0})),
    ]
    reasons: list[str] = []
    ours, cyclictest = bench_interleaved(args.seconds, max(1, args.rounds), phases, reasons.append)
    print(format_comparison(ours, cyclictest, "; ".join(reasons)))
    print(bench_hot_paths())
    print(bench_dump())
    return 0


if __name__ == "__main__":
    sys.exit(main())
