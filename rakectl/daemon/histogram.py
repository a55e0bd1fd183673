"""Latency histograms for the loop: O(1) to record, cheap percentiles (numpy).

Fixed 1 µs buckets up to a ceiling (the last bucket collects everything
above); the exact maximum is kept apart. Percentiles over ~20 000 buckets
take tens of µs, so ``status`` can report them from the loop's slack, where
sorting a 60 s window of samples would take milliseconds.
"""

from __future__ import annotations

import numpy as np

PERCENTILES = (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999))


class Histogram:
    """Counts of values in ns, in ``bucket_ns`` buckets up to ``ceiling_ns``."""

    __slots__ = ("_bucket_ns", "_last", "counts", "max_ns", "samples")

    def __init__(self, bucket_ns: int = 1000, ceiling_ns: int = 4_000_000) -> None:
        self._bucket_ns = bucket_ns
        self._last = ceiling_ns // bucket_ns
        self.counts = np.zeros(self._last + 1, dtype=np.int64)
        self.max_ns = 0
        self.samples = 0

    def add(self, value_ns: int) -> None:
        i = value_ns // self._bucket_ns
        self.counts[i if 0 <= i < self._last else (self._last if i > 0 else 0)] += 1
        if value_ns > self.max_ns:
            self.max_ns = value_ns
        self.samples += 1

    def reset(self) -> None:
        self.counts[:] = 0
        self.max_ns = 0
        self.samples = 0

    def percentiles_ns(self) -> dict[str, int]:
        """p50/p99/p99.9 (upper edge of the bucket reached) and the exact max, in ns."""
        out = {"samples": self.samples, "max": self.max_ns}
        if self.samples == 0:
            return out | {name: 0 for name, _ in PERCENTILES}
        cumulative = np.cumsum(self.counts)
        for name, q in PERCENTILES:
            index = int(np.searchsorted(cumulative, q * self.samples))
            out[name] = min((index + 1) * self._bucket_ns, self.max_ns)
        return out
