"""Shared fixtures: every test must leave no thread and no child process behind; the
emulator's physics runs as Python unless a test asks for its compiled build."""

from __future__ import annotations

import multiprocessing
import os
import shutil
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

# Which physics a process runs is decided when it imports drivers (drivers.compiled):
# an empty cache of builds for this whole run, so every process of it runs the Python
# physics whatever the machine has built, until a test points one at `physics_build`.
_EMPTY_CACHE = tempfile.mkdtemp(prefix="rakectl-no-physics-build-")
os.environ["RAKECTL_PHYSICS_CACHE"] = _EMPTY_CACHE


def pytest_unconfigure(config: pytest.Config) -> None:
    shutil.rmtree(_EMPTY_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def physics_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache holding the compiled physics of these sources (built once per run, about
    30 s of CPU); a test sets RAKECTL_PHYSICS_CACHE to it for the processes it starts."""
    from drivers import compiled

    cache = tmp_path_factory.mktemp("physics-build")
    os.environ[compiled.CACHE_ENV] = str(cache)
    try:
        compiled.build(progress=lambda line: None)
    finally:
        os.environ[compiled.CACHE_ENV] = _EMPTY_CACHE
    return cache


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
