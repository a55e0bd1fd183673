"""Loop-latency histograms against numpy's percentiles."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from rakectl.daemon.histogram import Histogram


@given(st.lists(st.integers(0, 30_000_000), min_size=1, max_size=2000))
def test_percentiles_are_within_one_bucket_of_numpy(values: list[int]) -> None:
    h = Histogram()
    for v in values:
        h.add(v)
    got = h.percentiles_ns()
    assert got["max"] == max(values) and got["samples"] == len(values)
    for name, q in (("p50", 50), ("p99", 99), ("p99.9", 99.9)):
        exact = float(np.percentile(values, q, method="inverted_cdf"))
        if exact < 4_000_000:
            assert exact - 1000 <= got[name] <= exact + 1000


def test_reset_forgets_everything() -> None:
    h = Histogram()
    h.add(5000)
    h.reset()
    assert h.percentiles_ns() == {"samples": 0, "max": 0, "p50": 0, "p99": 0, "p99.9": 0}
