"""Micro-benchmarks that print figures (never asserted in tests: machines are noisy)."""

from __future__ import annotations

import gc
import statistics
import time

from rakectl.config.loader import load_settings
from rakectl.core.control import build_impedance


def _percentile(sorted_values: list[float], q: float) -> float:
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def bench_controller_step(ticks: int) -> str:
    """Cost of one ImpedanceController.step, timed per call over ``ticks`` calls."""
    controller = build_impedance(load_settings())
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


def bench_emulator_step(steps: int) -> str:
    """CPU time of one 1 ms physics step (arm, motors, ground) in soil, and the real-time ratio."""
    from drivers.arm import ArmPlant
    from drivers.ground import Ground
    from rakectl.core.control import workspace_of
    from rakectl.sim.scenario import Scenario

    scenario = load_settings(None, (), root=Scenario)
    emu = scenario.emulator
    ws = workspace_of(scenario)
    arm = ArmPlant(emu.arm, emu.motor_r, emu.motor_theta, ws, emu.substep_s, emu.seed)
    ground = Ground(emu.ground, emu.seed)
    arm.set_pose_at_rest(1.0, 0.7)  # tip about 4 cm into the soil at ~0.76 m reach
    clock = time.perf_counter_ns
    samples = [0.0] * steps
    for k in range(steps):
        voltage_r = -2.0 if (k // 2000) % 2 == 0 else 2.0  # drag back and forth
        t0 = clock()
        arm.step(voltage_r, 0.5, ground, 1e-3)
        samples[k] = (clock() - t0) / 1e3
    samples.sort()
    median = statistics.median(samples)
    return (
        f"emulator physics, 1 ms step = {round(1e-3 / emu.substep_s)} substeps of "
        f"{emu.substep_s * 1e6:.0f} µs, arm + motors + soil, {steps} steps:\n"
        f"  median {median:.0f} µs, p99 {_percentile(samples, 0.99):.0f} µs per step: "
        f"{1e3 / median:.1f}× faster than real time"
    )
