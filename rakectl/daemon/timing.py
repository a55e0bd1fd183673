"""Fixed-step timing of the 1 kHz loop: absolute deadlines and per-tick statistics.

`TickTimer` wakes the loop on a grid of absolute deadlines ``origin + k·period``
of a monotonic clock: it sleeps until shortly before the deadline (``time.sleep``
oversleeps by ~100 µs on a stock kernel) and spins the rest of the way. The
sleep length is recomputed from the absolute deadline at every tick, so wake-up
errors never accumulate into drift (and Python 3.11's ``time.sleep`` itself
sleeps with ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)``).

Overrun policy: when `TickTimer.wait` is entered after the next deadline has
already passed (the previous tick's work overran), the overrun is counted and
the deadline jumps to the next multiple of the period that is still in the
future. The skipped deadlines are returned, so the caller integrates over
``(1 + skipped)`` periods once instead of running a burst of catch-up ticks.

`TimingStats` keeps the last ``window_s`` of period, wake-up latency and
execution time in preallocated int64 rings; `TimingStats.record` only writes
ints into them, and `TimingStats.summary` computes percentiles off the hot path.

The clock and the sleep are injected, so tests run on a fake clock. A loop::

    timer, stats = TickTimer(1e-3), TimingStats(1e-3)
    timer.start()
    while running:
        skipped = timer.wait()
        step(dt_s=(1 + skipped) * 1e-3)  # once, over the skipped deadlines too
        stats.record(timer.wake_ns, timer.latency_ns, time.monotonic_ns() - timer.wake_ns, skipped)
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from typing import Any, TypedDict

import numpy as np

from rakectl.config.service import DaemonSettings
from rakectl.daemon.histogram import Histogram
from rakectl.errors import ConfigError

NS_PER_S = 1_000_000_000

# time.sleep oversleeps by ~100 µs (p99 well under 200 µs) without SCHED_FIFO on
# the development VM; with SCHED_FIFO and 1 ns timer slack the sleep wakes within
# ~50 µs. Spinning the last 200 µs costs at most 20 % of one core at 1 kHz.
DEFAULT_SPIN_THRESHOLD_S = 200e-6

# Reported percentiles, in per mille so that ranks are exact integers.
PERCENTILES = (("p50", 500), ("p99", 990), ("p99.9", 999))


class TickTimer:
    """Wake-ups on absolute deadlines ``origin + k·period`` of a monotonic clock.

    After `wait` returns, `tick_index`, `deadline_ns`, `wake_ns` and `latency_ns`
    (``wake_ns - deadline_ns``) describe the tick about to run; `overruns`
    counts the waits entered after the next deadline had passed and
    `skipped_total` the deadlines skipped by them.
    """

    def __init__(
        self,
        period_s: float,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        sleep: Callable[[float], None] = time.sleep,
        spin_threshold_s: float = DEFAULT_SPIN_THRESHOLD_S,
    ) -> None:
        if not period_s > 0.0:
            raise ConfigError(f"TickTimer: period_s must be > 0, got {period_s!r}")
        if not spin_threshold_s >= 0.0:
            raise ConfigError(f"TickTimer: spin_threshold_s must be >= 0, got {spin_threshold_s!r}")
        self.period_ns = round(period_s * NS_PER_S)
        self._spin_ns = round(spin_threshold_s * NS_PER_S)
        self._clock_ns = clock_ns
        self._sleep = sleep
        self.origin_ns = 0
        self.tick_index = -1
        self.deadline_ns = 0
        self.wake_ns = 0
        self.latency_ns = 0
        self.sleep_overshoot_ns = 0
        self.overruns = 0
        self.skipped_total = 0
        self._next_index = 0
        self._next_deadline_ns = 0
        self._started = False

    def start(self) -> None:
        """Set the grid: tick 0 is due one period from now."""
        self.origin_ns = self._clock_ns() + self.period_ns
        self._next_index = 0
        self._next_deadline_ns = self.origin_ns
        self.tick_index = -1
        self._started = True

    def deadline_of(self, tick_index: int) -> int:
        """Absolute deadline of a tick, in clock nanoseconds."""
        return self.origin_ns + tick_index * self.period_ns

    def wait(self) -> int:
        """Block until the next deadline; return how many deadlines were skipped (normally 0)."""
        if not self._started:
            self.start()
        now_ns = self._clock_ns()
        deadline_ns = self._next_deadline_ns
        skipped = 0
        if now_ns > deadline_ns:
            skipped = (now_ns - deadline_ns) // self.period_ns + 1
            deadline_ns += skipped * self.period_ns
            self.overruns += 1
            self.skipped_total += skipped
        self._sleep_until(deadline_ns, now_ns)
        self.tick_index = self._next_index + skipped
        self.deadline_ns = deadline_ns
        self._next_index = self.tick_index + 1
        self._next_deadline_ns = deadline_ns + self.period_ns
        return skipped

    def _sleep_until(self, deadline_ns: int, now_ns: int) -> None:
        """Sleep until ``spin threshold`` before the deadline, then spin to it."""
        clock_ns = self._clock_ns
        sleep_target_ns = deadline_ns - self._spin_ns
        if sleep_target_ns > now_ns:
            self._sleep((sleep_target_ns - now_ns) / NS_PER_S)
            now_ns = clock_ns()
            self.sleep_overshoot_ns = now_ns - sleep_target_ns
        else:
            self.sleep_overshoot_ns = 0
        while now_ns < deadline_ns:
            now_ns = clock_ns()
        self.wake_ns = now_ns
        self.latency_ns = now_ns - deadline_ns


def nearest_rank(per_mille: int, count: int) -> int:
    """1-based rank of a percentile among ``count`` sorted samples: ceil(q·count), at least 1."""
    return max(1, -(-per_mille * count // 1000))


def percentiles_ns(values_ns: np.ndarray) -> dict[str, int]:
    """p50/p99/p99.9/max of integer samples, nearest rank (numpy's ``inverted_cdf``).

    An empty sample gives zeros.
    """
    if values_ns.size == 0:
        return {name: 0 for name, _ in PERCENTILES} | {"max": 0}
    ordered = np.sort(values_ns)
    result = {name: int(ordered[nearest_rank(q, ordered.size) - 1]) for name, q in PERCENTILES}
    result["max"] = int(ordered[-1])
    return result


class TimingSummary(TypedDict):
    """`TimingStats.summary`: lifetime counters and percentiles over the window."""

    ticks: int
    window_ticks: int
    misses: int
    skipped: int
    longest_gap_ns: int
    period_ns: dict[str, int]
    latency_ns: dict[str, int]
    exec_ns: dict[str, int]


class TimingStats:
    """Rings of the last ``window_s`` of per-tick period, wake-up latency and execution time.

    `record` is O(1) and writes plain ints into preallocated int64 arrays. The
    first tick has no period; it is stored as -1 and left out of the summary.
    """

    def __init__(self, period_s: float, window_s: float = 60.0) -> None:
        if not period_s > 0.0 or not window_s >= period_s:
            raise ConfigError(
                f"TimingStats: need period_s > 0 and window_s >= period_s, "
                f"got {period_s!r}, {window_s!r}"
            )
        self.capacity_ticks = round(window_s / period_s)
        self._period_ns = np.full(self.capacity_ticks, -1, dtype=np.int64)
        self._latency_ns = np.zeros(self.capacity_ticks, dtype=np.int64)
        self._exec_ns = np.zeros(self.capacity_ticks, dtype=np.int64)
        self._next = 0
        self._prev_wake_ns = -1
        self._has_prev = False
        self.ticks = 0
        self.misses = 0
        self.skipped = 0
        self.longest_gap_ns = 0

    def record(self, wake_ns: int, latency_ns: int, exec_ns: int, skipped: int = 0) -> None:
        """Store one tick: its wake-up time, wake-up latency, execution time, skipped deadlines."""
        i = self._next
        period_ns = wake_ns - self._prev_wake_ns if self._has_prev else -1
        self._period_ns[i] = period_ns
        self._latency_ns[i] = latency_ns
        self._exec_ns[i] = exec_ns
        if period_ns > self.longest_gap_ns:
            self.longest_gap_ns = period_ns
        if skipped:
            self.misses += 1
            self.skipped += skipped
        self._prev_wake_ns = wake_ns
        self._has_prev = True
        self.ticks += 1
        i += 1
        self._next = 0 if i == self.capacity_ticks else i

    def resume(self) -> None:
        """After a deliberate pause of the loop: the next tick records no period (and no gap)."""
        self._has_prev = False

    def window(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the stored (period_ns, latency_ns, exec_ns), oldest first; no period is -1."""
        filled = min(self.ticks, self.capacity_ticks)
        start = self._next if self.ticks > self.capacity_ticks else 0
        order = (np.arange(filled) + start) % self.capacity_ticks
        return self._period_ns[order], self._latency_ns[order], self._exec_ns[order]

    def summary(self) -> TimingSummary:
        """Percentiles over the window and lifetime counters (call off the hot path)."""
        period_ns, latency_ns, exec_ns = self.window()
        return {
            "ticks": self.ticks,
            "window_ticks": int(latency_ns.size),
            "misses": self.misses,
            "skipped": self.skipped,
            "longest_gap_ns": self.longest_gap_ns,
            "period_ns": percentiles_ns(period_ns[period_ns >= 0]),
            "latency_ns": percentiles_ns(latency_ns),
            "exec_ns": percentiles_ns(exec_ns),
        }


class LoopTiming:
    """The daemon's timing figures in 1 µs histograms: O(1) per tick, cheap percentiles.

    Wake-up latency (actual wake − deadline), the OS's oversleep before the
    spin, the tick's own work and the period, since the start or the last
    :meth:`reset` (benchmark phases).
    """

    def __init__(self, timer: TickTimer) -> None:
        self.timer = timer
        self.latency = Histogram()
        self.execution = Histogram()
        self.period = Histogram()
        self.oversleep = Histogram()
        self.longest_gap_ns = 0
        self._last_wake_ns = 0
        self._overruns_at_reset = 0

    def record(self, exec_ns: int) -> None:
        """The tick that just ran: its timer's figures and its execution time."""
        timer = self.timer
        self.latency.add(timer.latency_ns)
        self.oversleep.add(timer.sleep_overshoot_ns)
        self.execution.add(exec_ns)
        if self._last_wake_ns:
            gap_ns = timer.wake_ns - self._last_wake_ns
            self.period.add(gap_ns)
            if gap_ns > self.longest_gap_ns:
                self.longest_gap_ns = gap_ns
        self._last_wake_ns = timer.wake_ns

    def reset(self) -> None:
        """Start afresh (benchmark phases)."""
        for histogram in (self.latency, self.execution, self.period, self.oversleep):
            histogram.reset()
        self.longest_gap_ns = 0
        self._overruns_at_reset = self.timer.overruns

    def summary(self) -> dict[str, Any]:
        """Percentiles (ns) and counters; cheap enough for the loop's slack."""
        return {
            "latency_ns": self.latency.percentiles_ns(),
            "exec_ns": self.execution.percentiles_ns(),
            "period_ns": self.period.percentiles_ns(),
            "oversleep_ns": self.oversleep.percentiles_ns(),
            "longest_gap_ns": self.longest_gap_ns,
            "overruns": self.timer.overruns - self._overruns_at_reset,
            "skipped": self.timer.skipped_total,
            "gc_collections": [g["collections"] for g in gc.get_stats()],
        }


def timing_verdict(summary: dict[str, Any], ticks: int, rate_hz: float,
                   daemon: DaemonSettings, reference_p99_us: float | None = None,
                   advise: bool = True) -> str:
    """Why the loop's timing since start-up should not be armed on, or "" (pure).

    ``summary`` is :meth:`LoopTiming.summary`; ``ticks`` the ticks run so far;
    ``reference_p99_us`` cyclictest's p99 measured at start-up, if any; ``advise``: a
    measurement too short says to arm again shortly (where it refuses an arming). The wake-up
    latency is the OS's (how late the sleep woke, before the spin: what cyclictest
    measures); late ticks are the overruns.
    """
    measured_s = ticks / rate_hz
    if measured_s < daemon.arm_timing_s:
        return (f"the loop has measured its timing for {measured_s:.1f} s of the "
                f"{daemon.arm_timing_s:g} s daemon.arm_timing_s asks"
                + ("; arm again shortly" if advise else ""))
    p99_us = summary["oversleep_ns"]["p99"] * 1e-3
    if p99_us > daemon.arm_max_latency_p99_us:
        return (f"the loop's p99 wake-up latency is {p99_us:.0f} µs, above "
                f"daemon.arm_max_latency_p99_us ({daemon.arm_max_latency_p99_us:g} µs) by "
                f"{p99_us - daemon.arm_max_latency_p99_us:.0f} µs")
    late_share = summary["overruns"] / max(1, ticks)
    if late_share > daemon.arm_max_late_share:
        return (f"{summary['overruns']} of {ticks} ticks were late ({late_share:.2%}), above "
                f"daemon.arm_max_late_share ({daemon.arm_max_late_share:.2%})")
    limit = daemon.arm_max_latency_ratio
    if limit > 0.0 and reference_p99_us is not None and reference_p99_us > 0.0:
        ratio = p99_us / reference_p99_us
        if ratio > limit:
            return (f"the loop's p99 wake-up latency, {p99_us:.0f} µs, is {ratio:.1f}× "
                    f"cyclictest's at start-up ({reference_p99_us:.0f} µs), above "
                    f"daemon.arm_max_latency_ratio ({limit:g}×)")
    return ""
