"""cyclictest (Debian ``rt-tests``): the machine's own wake-up latency, the loop's reference.

Run for a few seconds next to the loop under test, in the same run; its
histogram gives percentiles in 1 µs buckets. Absent or failing, the reason is
passed on and the benchmark says it was not measured.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rakectl.daemon.timing import PERCENTILES, nearest_rank

CYCLICTEST_HISTOGRAM_US = 20_000
NS_PER_US = 1000


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
