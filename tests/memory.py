"""A check shared by hot-path tests: a call keeps no memory."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable


def assert_no_growth(run: Callable[[int], None], limit_bytes: int = 512) -> None:
    """``run(n)`` makes n calls; 20 000 calls may not keep more than ``limit_bytes`` more
    than 1000 do (a per-call leak would be at least 20 000 × 28 B)."""
    run(1000)
    tracemalloc.start()
    try:
        run(1000)
        short_bytes = tracemalloc.get_traced_memory()[0]
        run(20_000)
        long_bytes = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert long_bytes - short_bytes < limit_bytes
