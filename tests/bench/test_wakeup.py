"""The wake-up benchmark's arithmetic and its run (figures are printed there, never asserted)."""

from __future__ import annotations

import numpy as np

from rakectl.bench.wakeup import bench_wakeup, format_comparison, make_garbage
from rakectl.daemon.cyclictest import merge_cyclictest, parse_cyclictest_histogram
from rakectl.daemon.rt import RtMode
from rakectl.daemon.timing import percentiles_ns


def _histfile(samples_us: np.ndarray) -> list[str]:
    counts = np.bincount(samples_us, minlength=200)
    lines = [f"{bucket:06d} {count:06d}" for bucket, count in enumerate(counts)]
    return [*lines, f"# Max Latencies: {samples_us.max():05d}", "# Histogram Overflows: 00000"]


def test_cyclictest_histogram_percentiles_agree_with_the_samples() -> None:
    rng = np.random.default_rng(5)
    first_us, second_us = rng.integers(10, 120, size=5000), rng.integers(5, 190, size=3000)
    parsed = parse_cyclictest_histogram(_histfile(first_us))
    assert parsed["samples"] == 5000
    assert parsed["latency_ns"] == percentiles_ns(first_us * 1000)
    merged = merge_cyclictest([parsed, parse_cyclictest_histogram(_histfile(second_us))])
    assert merged["latency_ns"] == percentiles_ns(np.concatenate([first_us, second_us]) * 1000)


def test_cyclictest_overflow_reads_as_the_max() -> None:
    lines = ["000010 000990", "# Histogram Overflows: 00010", "# Max Latencies: 25000"]
    parsed = parse_cyclictest_histogram(lines)
    assert parsed["latency_ns"]["p50"] == 10_000
    assert parsed["latency_ns"]["p99.9"] == parsed["latency_ns"]["max"] == 25_000_000


def test_bench_wakeup_runs_and_formats() -> None:
    ours = bench_wakeup(0.02, RtMode.OFF, load=make_garbage)
    assert ours["ticks"] == 20 and ours["rt_warnings"] == []
    text = format_comparison([ours], None, "not installed")
    assert "cyclictest: not measured (not installed)" in text and ours["label"] in text
