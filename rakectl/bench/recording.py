"""What the loop's per-tick writes cost: the flight recorder's row, a timing record, a dump.

Each write is timed per call (best of 5) and traced for the memory it keeps,
next to the alternatives that were measured for the recorder's ring; the
dump's work is shared out over slack-sized calls. Figures are printed.
"""

from __future__ import annotations

import math
import struct
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rakectl.daemon.recorder import FlightRecorder
from rakectl.daemon.rt import no_gc
from rakectl.daemon.timing import TimingStats, percentiles_ns


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
