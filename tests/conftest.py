"""Shared fixtures: every test must leave no thread and no child process behind."""

from __future__ import annotations

import multiprocessing
import threading
from collections.abc import Iterator

import pytest


@pytest.fixture(autouse=True)
def _no_leaks() -> Iterator[None]:
    threads_before = set(threading.enumerate())
    yield
    leaked_threads = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    leaked_children = multiprocessing.active_children()
    assert not leaked_threads, f"test leaked threads: {leaked_threads}"
    assert not leaked_children, f"test leaked child processes: {leaked_children}"


@pytest.fixture(scope="session")
def dask_offload_thread() -> None:
    """distributed keeps one offload thread for the life of the process, started on
    first use: started here, before a test's own leak check sees it appear."""
    from distributed.utils import _offload_executor

    _offload_executor.submit(lambda: None).result()
