"""Latency benchmark of the 1 kHz loop against cyclictest, measured in the same run.

``python -m rakectl.bench.wakeup --seconds 10`` runs, in interleaved rounds:
cyclictest (Debian ``rt-tests``), our `TickTimer` loop with the real-time
set-up of `rakectl.daemon.rt`, the same loop without it, and the loop with the set-up
but no spin (sleep only); then the hot-path micro-benchmarks
(`FlightRecorder.record_row` and the alternatives tried, `TimingStats.record`,
a chunked dump). It prints the figures.

Wake-up latency is ``actual wake − deadline``. Our loop sleeps to
``spin_threshold`` before the deadline and spins the rest, so its latency
hides the sleep's own error; that error ("sleep overshoot", how late
``time.sleep`` returned) is printed too and is the figure that compares with
cyclictest's ``clock_nanosleep`` wake-up latency. Figures are printed, never
asserted: these machines are shared and noisy.
"""

from __future__ import annotations

import argparse
import math
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from rakectl.daemon.recorder import FlightRecorder
from rakectl.daemon.rt import GcMonitor, RtMode, RtRequest, apply_rt, no_gc, revert_rt
from rakectl.daemon.timing import (
    DEFAULT_SPIN_THRESHOLD_S,
    PERCENTILES,
    TickTimer,
    TimingStats,
    nearest_rank,
    percentiles_ns,
)

CYCLICTEST_HISTOGRAM_US = 20_000
NS_PER_US = 1000


# --- our loop ------------------------------------------------------------------------------


def _dummy_tick(k: int) -> float:
    """A tiny stand-in for a control step: a few float operations."""
    x_m = 1e-6 * k
    return 0.5 * x_m * x_m + 2.0 * x_m


class WakeupPhase:
    """One configuration of our loop; each `run` adds ticks, `result` summarizes them all.

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
    """Run our loop for ``duration_s`` (options: those of `WakeupPhase`) and summarize it."""
    phase = WakeupPhase(rt_mode, load, capacity_s=duration_s, **options)
    phase.run(duration_s)
    return phase.result()


def make_garbage() -> None:
    """A load that leaves a reference cycle per tick, for the cyclic collector to find."""
    node: list[Any] = [None] * 8
    node[0] = node


# --- cyclictest ----------------------------------------------------------------------------


def run_cyclictest(
    duration_s: float,
    *,
    priority: int = 80,
    interval_us: int = 1000,
    why_not: Callable[[str], None] | None = None,
) -> dict[str, Any] | None:
    """Run ``cyclictest -m -p <priority> -i <interval>`` for ``duration_s`` (whole seconds).

    Percentiles come from its histogram (1 µs buckets). Returns None when it is
    absent or fails, after passing the reason to ``why_not`` (default: stderr).
    """
    explain = why_not if why_not is not None else _print_to_stderr
    executable = shutil.which("cyclictest")
    if executable is None:
        explain("cyclictest not found: apt-get install -y rt-tests")
        return None
    seconds = max(1, math.ceil(duration_s))
    with tempfile.TemporaryDirectory(prefix="rakectl-cyclictest-") as directory:
        histfile = Path(directory) / "histogram.txt"
        command = [
            executable, "-m", "-p", str(priority), "-i", str(interval_us), "-q",
            "-D", str(seconds), "-h", str(CYCLICTEST_HISTOGRAM_US), f"--histfile={histfile}",
        ]  # fmt: skip
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 30)
        except (OSError, subprocess.TimeoutExpired) as exc:
            explain(f"cyclictest did not run: {exc}")
            return None
        if done.returncode != 0 or not histfile.exists():
            explain(f"cyclictest failed (exit {done.returncode}): {done.stderr.strip()[-300:]}")
            return None
        result = parse_cyclictest_histogram(histfile.read_text().splitlines())
    return result | {"label": f"cyclictest -m -p {priority} -i {interval_us}"}


def _print_to_stderr(reason: str) -> None:
    print(f"cyclictest: {reason}", file=sys.stderr)


def parse_cyclictest_histogram(lines: Iterable[str]) -> dict[str, Any]:
    """Percentiles (nearest rank, in ns) from cyclictest's ``--histfile`` of one thread."""
    counts = np.zeros(CYCLICTEST_HISTOGRAM_US, dtype=np.int64)
    footer: dict[str, int] = {}
    for line in lines:
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            if value.strip().isdigit():
                footer.setdefault(key.strip(), int(value))
        elif line.strip():
            bucket_us, count = line.split()[:2]
            if int(bucket_us) < counts.size:
                counts[int(bucket_us)] = int(count)
    overflows = footer.get("Histogram Overflows", 0)
    return _cyclictest_summary(counts, overflows, footer.get("Max Latencies", 0) * NS_PER_US)


def _cyclictest_summary(counts: np.ndarray, overflows: int, max_ns: int) -> dict[str, Any]:
    return {
        "samples": int(counts.sum()) + overflows,
        "latency_ns": _histogram_percentiles_ns(counts, overflows, max_ns),
        "overflows": overflows,
        "max_ns": max_ns,
        "counts": counts,
    }


def merge_cyclictest(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One summary of several cyclictest runs (their histograms added)."""
    counts = np.sum([run["counts"] for run in runs], axis=0)
    overflows = sum(run["overflows"] for run in runs)
    merged = _cyclictest_summary(counts, overflows, max(run["max_ns"] for run in runs))
    return merged | {"label": runs[0].get("label", "cyclictest")}


def _histogram_percentiles_ns(counts: np.ndarray, overflows: int, max_ns: int) -> dict[str, int]:
    """Like `percentiles_ns` on the samples; a rank inside the overflow reads as the max."""
    total = int(counts.sum()) + overflows
    cumulative = np.cumsum(counts)
    result: dict[str, int] = {}
    for name, per_mille in PERCENTILES:
        bucket = int(np.searchsorted(cumulative, nearest_rank(per_mille, total)))
        result[name] = bucket * NS_PER_US if bucket < counts.size else max_ns
    result["max"] = max_ns
    return result


# --- hot paths -----------------------------------------------------------------------------


def _per_call_us(run: Callable[[int], None], calls: int) -> float:
    """Best of 5 runs of ``run(calls)``, per call, in µs."""
    best_s = math.inf
    for _ in range(5):
        start_s = time.perf_counter()
        run(calls)
        best_s = min(best_s, time.perf_counter() - start_s)
    return best_s / calls * 1e6


def _allocation(run: Callable[[int], None], calls: int) -> tuple[float, int]:
    """(bytes kept per call, peak bytes above the start) of ``run``, traced by tracemalloc.

    Bytes kept per call compare ``calls`` with ``10 × calls``: the few objects a
    write replaces (a counter's int) cancel out, a per-call leak does not.
    """
    run(calls)
    tracemalloc.start()
    try:
        start_bytes = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        run(calls)
        short_bytes = tracemalloc.get_traced_memory()[0]
        run(10 * calls)
        long_bytes, peak_bytes = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return (long_bytes - short_bytes) / (10 * calls), peak_bytes - start_bytes


def _record_row_variants(columns: int, capacity: int) -> dict[str, Callable[[int], None]]:
    """Ways to write one row of a float64 ring, each run ``calls`` times in a loop."""
    recorder = FlightRecorder(tuple(f"c{j}" for j in range(columns)), capacity)
    data = np.zeros((capacity, columns))
    row_views = list(data)
    raw = data.data.cast("B")
    pack_into = struct.Struct(f"={columns}d").pack_into
    values = tuple(0.1 * j for j in range(columns))
    index = [k % capacity for k in range(capacity * 4)]

    def loop_only(calls: int) -> None:
        for k in range(calls):
            index[k % len(index)]

    def record_row(calls: int) -> None:
        write = recorder.record_row
        for _ in range(calls):
            write(values)

    def ndarray_setitem(calls: int) -> None:
        for k in range(calls):
            data[index[k % len(index)]] = values

    def row_view_slice(calls: int) -> None:
        for k in range(calls):
            row_views[index[k % len(index)]][:] = values

    def struct_pack_into(calls: int) -> None:
        for k in range(calls):
            pack_into(raw, index[k % len(index)] * columns * 8, *values)

    return {
        "FlightRecorder.record_row (struct.pack_into, ring index kept)": record_row,
        "ndarray[i] = tuple": ndarray_setitem,
        "row_view[:] = tuple": row_view_slice,
        "struct.pack_into(memoryview, offset, *tuple)": struct_pack_into,
        "loop alone (the index lookup the variants below share)": loop_only,
    }


def bench_hot_paths(calls: int = 100_000, columns: int = 12) -> str:
    """µs per call and allocations of the recorder's and the stats' hot-path writes."""
    lines = [f"hot paths, {calls} calls, best of 5, {columns} columns (µs per call incl. loop):"]
    with no_gc():
        for name, run in _record_row_variants(columns, 2000).items():
            lines.append(_hot_path_line(name, run, calls))
        stats = TimingStats(1e-3, window_s=60.0)

        def record(calls: int) -> None:
            write = stats.record
            for k in range(calls):
                write(1_000_000 * k, 40_000, 12_000, 0)

        lines.append(_hot_path_line("TimingStats.record", record, calls))
    return "\n".join(lines)


def bench_dump(rows: int = 2000, columns: int = 12, budget_s: float = 200e-6) -> str:
    """How a `DumpWriter` of ``rows`` shares out over `work` calls of ``budget_s`` each."""
    recorder = FlightRecorder(tuple(f"c{j}" for j in range(columns)), rows)
    rng = np.random.default_rng(0)
    for row in rng.normal(size=(rows, columns)).tolist():
        recorder.record_row(row)
    with tempfile.TemporaryDirectory(prefix="rakectl-dump-") as directory:
        start_s = time.perf_counter()
        writer = recorder.start_dump(Path(directory) / "dump.csv")
        snapshot_s = time.perf_counter() - start_s
        call_ns: list[int] = []
        done = False
        while not done:
            start_ns = time.perf_counter_ns()
            done = writer.work(budget_s)
            call_ns.append(time.perf_counter_ns() - start_ns)
    per_call = percentiles_ns(np.array(call_ns, dtype=np.int64))
    return (
        f"dump of {rows} rows × {columns} columns: snapshot {snapshot_s * 1e6:.0f} µs, then "
        f"{len(call_ns)} work({budget_s * 1e6:.0f} µs) calls taking p50 "
        f"{per_call['p50'] / 1e3:.0f} µs, p99 {per_call['p99'] / 1e3:.0f} µs, max "
        f"{per_call['max'] / 1e3:.0f} µs"
    )


def _hot_path_line(name: str, run: Callable[[int], None], calls: int) -> str:
    kept_per_call, peak = _allocation(run, calls)
    return (
        f"  {_per_call_us(run, calls):6.3f} µs  {name}  "
        f"[memory kept {abs(kept_per_call):.4f} B/call, peak +{peak} B]"
    )


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
    """Our runs and cyclictest side by side, with the ratio of p99s (goal: ≤ 2×)."""
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
        "--gc", choices=("off", "on"), default="off", help="cyclic GC in our runs (off: no_gc)"
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
