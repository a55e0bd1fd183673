"""Micro-benchmarks that print figures (never asserted in tests: machines are noisy)."""

from __future__ import annotations

import gc
import statistics
import time

from rakectl.config import load_settings
from rakectl.simulate import build_controller


def _percentile(sorted_values: list[float], q: float) -> float:
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def bench_controller_step(ticks: int) -> str:
    """Cost of one ImpedanceController.step, timed per call over ``ticks`` calls."""
    controller = build_controller(load_settings())
    controller.reset(0.0)
    clock = time.perf_counter_ns
    samples = [0.0] * ticks
    overhead = [0.0] * ticks
    step = controller.step
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for k in range(ticks):
            t0 = clock()
            t1 = clock()
            overhead[k] = t1 - t0
        for k in range(ticks):
            x_m = 7e-6 * k
            t0 = clock()
            step(x_m, x_m)
            t1 = clock()
            samples[k] = t1 - t0
    finally:
        if gc_was_enabled:
            gc.enable()
    clock_ns = statistics.median(overhead)
    cost_us = sorted((s - clock_ns) / 1e3 for s in samples)
    return (
        f"controller step (estimator + impedance filter), {ticks} ticks, "
        f"clock overhead {clock_ns:.0f} ns subtracted:\n"
        f"  median {statistics.median(cost_us):.2f} µs, p99 {_percentile(cost_us, 0.99):.2f} µs, "
        f"p99.9 {_percentile(cost_us, 0.999):.2f} µs, max {cost_us[-1]:.2f} µs "
        f"(goal: median <= 10 µs)"
    )
