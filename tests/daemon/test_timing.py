"""TickTimer on a fake clock (absolute deadlines, overruns skipped ahead); TimingStats figures."""

from __future__ import annotations

import dataclasses
import itertools
import random
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rakectl.config.service import DaemonSettings
from rakectl.daemon.timing import TickTimer, TimingStats, percentiles_ns, timing_verdict
from rakectl.errors import ConfigError
from tests.memory import assert_no_growth

PERIOD_NS = 1_000_000
SPIN_NS = 200_000


class FakeTime:
    """A clock that advances ``read_ns`` per read and a sleep that over/undersleeps by a jitter."""

    def __init__(self, jitter_ns: Callable[[], int] = lambda: 0, read_ns: int = 1_000) -> None:
        self.now_ns = 10**12
        self._jitter_ns = jitter_ns
        self._read_ns = read_ns
        self.sleep_targets_ns: list[int] = []

    def clock_ns(self) -> int:
        self.now_ns += self._read_ns
        return self.now_ns

    def sleep(self, seconds: float) -> None:
        assert seconds > 0.0
        self.sleep_targets_ns.append(self.now_ns + round(seconds * 1e9))
        self.now_ns += max(0, round(seconds * 1e9) + self._jitter_ns())

    def timer(self) -> TickTimer:
        return TickTimer(1e-3, self.clock_ns, self.sleep, spin_threshold_s=SPIN_NS / 1e9)


def test_deadlines_are_absolute_over_100k_jittery_ticks() -> None:
    rng = random.Random(7)
    fake = FakeTime(jitter_ns=lambda: rng.randint(-150_000, 350_000))
    timer = fake.timer()
    timer.start()
    for k in range(100_000):
        assert timer.wait() == 0
        assert timer.tick_index == k
        assert timer.deadline_ns == timer.origin_ns + k * PERIOD_NS
        assert timer.wake_ns >= timer.deadline_ns
        assert timer.latency_ns == timer.wake_ns - timer.deadline_ns
    assert timer.deadline_ns - timer.origin_ns == 99_999 * PERIOD_NS  # no drift at all
    assert timer.overruns == 0


def test_sleep_aims_at_the_absolute_deadline_minus_the_spin_threshold() -> None:
    rng = random.Random(3)
    fake = FakeTime(jitter_ns=lambda: rng.randint(0, 100_000))
    timer = fake.timer()
    timer.start()
    for _ in range(1000):
        timer.wait()
        assert abs(fake.sleep_targets_ns[-1] - (timer.deadline_ns - SPIN_NS)) <= 1


def test_oversleep_past_the_deadline_is_a_late_wake_not_a_skip() -> None:
    fake = FakeTime(jitter_ns=lambda: 500_000)  # sleep wakes 300 µs after the deadline
    timer = fake.timer()
    timer.start()
    timer.wait()
    assert timer.latency_ns >= 300_000
    assert timer.wait() == 0 and timer.tick_index == 1


@pytest.mark.parametrize(
    ("work_ns", "skipped"),
    [(999_000, 0), (1_000_001, 1), (2_500_000, 2), (10_000_000, 10)],
)
def test_overrun_skips_to_the_next_future_deadline(work_ns: int, skipped: int) -> None:
    fake = FakeTime(read_ns=1)
    timer = fake.timer()
    timer.start()
    timer.wait()
    fake.now_ns = timer.deadline_ns + work_ns  # this tick's work ends here
    entered_ns = fake.now_ns + 1  # what wait() reads first
    assert timer.wait() == skipped
    assert timer.tick_index == 1 + skipped
    assert timer.deadline_ns == timer.deadline_of(1 + skipped)
    assert timer.deadline_ns - PERIOD_NS < entered_ns <= timer.deadline_ns  # next future one
    assert timer.overruns == (1 if skipped else 0)
    assert timer.skipped_total == skipped


def test_no_catch_up_burst_after_an_overrun() -> None:
    fake = FakeTime()
    timer = fake.timer()
    timer.start()
    timer.wait()
    fake.now_ns += 5 * PERIOD_NS + 123
    assert timer.wait() == 5
    wakes_ns = [timer.wake_ns]
    for _ in range(5):
        assert timer.wait() == 0
        wakes_ns.append(timer.wake_ns)
    assert all(b - a >= PERIOD_NS - 2_000 for a, b in itertools.pairwise(wakes_ns))
    assert timer.tick_index == 11


def test_entering_wait_exactly_at_the_deadline_is_on_time() -> None:
    fake = FakeTime(read_ns=0)
    timer = fake.timer()
    timer.start()
    fake.now_ns = timer.deadline_of(0)
    assert timer.wait() == 0 and timer.latency_ns == 0


@pytest.mark.parametrize(("period_s", "spin_s"), [(0.0, 0.0), (-1e-3, 0.0), (1e-3, -1e-6)])
def test_timer_rejects_bad_settings(period_s: float, spin_s: float) -> None:
    with pytest.raises(ConfigError):
        TickTimer(period_s, spin_threshold_s=spin_s)


# --- TimingStats ---------------------------------------------------------------------------


def _expected(values: np.ndarray) -> dict[str, int]:
    levels = np.quantile(values, [0.5, 0.99, 0.999], method="inverted_cdf")
    return {
        "p50": int(levels[0]),
        "p99": int(levels[1]),
        "p99.9": int(levels[2]),
        "max": int(values.max()),
    }


def test_percentiles_on_known_data() -> None:
    values = np.arange(1, 1001, dtype=np.int64)[::-1].copy()
    assert percentiles_ns(values) == {"p50": 500, "p99": 990, "p99.9": 999, "max": 1000}
    assert percentiles_ns(np.zeros(0, dtype=np.int64)) == {"p50": 0, "p99": 0, "p99.9": 0, "max": 0}


@given(
    st.lists(st.integers(0, 10**7), min_size=2, max_size=400),
    st.lists(st.integers(0, 10**6), min_size=400, max_size=400),
    st.integers(1, 300),
)
def test_stats_match_numpy_over_the_window(
    gaps_ns: list[int], exec_ns: list[int], capacity: int
) -> None:
    stats = TimingStats(1e-3, window_s=capacity * 1e-3)
    wakes_ns = np.cumsum([0, *gaps_ns])
    latencies_ns = np.array(gaps_ns[:1] + gaps_ns) // 7
    for k, wake_ns in enumerate(wakes_ns):
        stats.record(int(wake_ns), int(latencies_ns[k]), exec_ns[k], skipped=k % 3 == 0)
    summary = stats.summary()
    window = slice(-capacity, None)
    periods_ns = np.diff(wakes_ns)[window] if capacity < len(wakes_ns) else np.diff(wakes_ns)
    assert summary["ticks"] == len(wakes_ns)
    assert summary["window_ticks"] == min(capacity, len(wakes_ns))
    assert summary["latency_ns"] == _expected(latencies_ns[window])
    assert summary["exec_ns"] == _expected(np.array(exec_ns[: len(wakes_ns)])[window])
    assert summary["period_ns"] == _expected(periods_ns)
    assert summary["longest_gap_ns"] == max(gaps_ns)
    assert summary["misses"] == summary["skipped"] == len(range(0, len(wakes_ns), 3))


def test_window_is_in_time_order_after_wrapping() -> None:
    stats = TimingStats(1e-3, window_s=5e-3)
    for k in range(12):
        stats.record(k * PERIOD_NS, k, 100 + k)
    _, latency_ns, exec_ns = stats.window()
    assert latency_ns.tolist() == [7, 8, 9, 10, 11]
    assert exec_ns.tolist() == [107, 108, 109, 110, 111]


def test_first_tick_has_no_period() -> None:
    stats = TimingStats(1e-3)
    stats.record(5 * PERIOD_NS, 0, 0)
    assert stats.summary()["period_ns"]["max"] == 0
    stats.record(6 * PERIOD_NS + 40, 0, 0)
    assert stats.summary()["period_ns"]["p50"] == PERIOD_NS + 40


def test_record_keeps_no_memory_per_call() -> None:
    stats = TimingStats(1e-3, window_s=10.0)

    def run(calls: int) -> None:
        for k in range(calls):
            stats.record(PERIOD_NS * k + 1_000_000_007, 40_000 + k, 12_000, 0)

    assert_no_growth(run)


def _summary(p99_us: float, overruns: int) -> dict[str, object]:
    return {"oversleep_ns": {"p99": round(p99_us * 1000)}, "overruns": overruns}


def test_the_timing_verdict_before_arming_names_what_and_by_how_much() -> None:
    daemon = DaemonSettings()  # 2 s measured, p99 ≤ 500 µs, ≤ 0.1 % late ticks
    assert timing_verdict(_summary(80, 1), 5000, 1000.0, daemon) == ""
    assert "measured its timing for 1.5 s of the 2 s" in timing_verdict(
        _summary(80, 0), 1500, 1000.0, daemon)
    late = timing_verdict(_summary(812, 0), 5000, 1000.0, daemon)
    assert late == ("the loop's p99 wake-up latency is 812 µs, above "
                    "daemon.arm_max_latency_p99_us (500 µs) by 312 µs")
    assert "12 of 5000 ticks were late (0.24%), above daemon.arm_max_late_share (0.10%)" in \
        timing_verdict(_summary(80, 12), 5000, 1000.0, daemon)


def test_a_loop_much_later_than_cyclictest_is_not_armed_on() -> None:
    """With a start-up cyclictest, the loop's p99 wake-up is judged against it too."""
    daemon = dataclasses.replace(DaemonSettings(), arm_timing_s=2.0, arm_max_latency_ratio=3.0)
    assert timing_verdict(_summary(80, 1), 5000, 1000.0, daemon, reference_p99_us=30.0) == ""
    worse = timing_verdict(_summary(200, 1), 5000, 1000.0, daemon, reference_p99_us=30.0)
    assert "is 6.7× cyclictest's at start-up (30 µs)" in worse
    assert "daemon.arm_max_latency_ratio (3×)" in worse
    off = dataclasses.replace(daemon, arm_max_latency_ratio=0.0)
    assert timing_verdict(_summary(200, 1), 5000, 1000.0, off, reference_p99_us=30.0) == ""
    assert timing_verdict(_summary(200, 1), 5000, 1000.0, daemon, reference_p99_us=None) == ""
