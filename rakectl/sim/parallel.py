"""Running independent simulated jobs on worker processes (fork), or in this one."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from typing import TypeVar

J = TypeVar("J")
R = TypeVar("R")


def fork_map(run: Callable[[J], R], jobs: Sequence[J], workers: int,
             ordered: bool = True) -> Iterator[R]:
    """``run`` over ``jobs`` on up to ``workers`` forked processes (in this process when
    ``workers`` <= 1 or there is a single job); in the order of ``jobs`` if ``ordered``,
    else as they finish. The pool is torn down however the caller stops iterating."""
    if workers <= 1 or len(jobs) <= 1:
        yield from map(run, jobs)
        return
    pool = multiprocessing.get_context("fork").Pool(min(workers, len(jobs)))
    try:
        yield from (pool.imap if ordered else pool.imap_unordered)(run, jobs)
        pool.close()
    finally:
        pool.terminate()
        pool.join()
