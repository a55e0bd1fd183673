"""Shared fixtures: every test must leave no thread and no child process behind; the
emulator's physics runs as Python unless a test asks for its compiled build."""

from __future__ import annotations

import multiprocessing
import os
import shutil
import tempfile
import threading
import time
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


CHILD_EXIT_GRACE_S = 3.0  # a child killed at a test's end may take this long to go


def _children() -> dict[int, str]:
    """This process's children still running (not zombies), however started
    (multiprocessing, subprocess): pid → command line, read from /proc."""
    me, found = os.getpid(), {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text()
            state, ppid = stat.rsplit(")", 1)[1].split()[:2]
            if int(ppid) != me or state in ("Z", "X"):
                continue
            command = Path(entry.path, "cmdline").read_bytes()
        except (OSError, ValueError):
            continue  # gone meanwhile
        found[int(entry.name)] = command.replace(b"\0", b" ").decode(errors="replace").strip()
    return found


@pytest.fixture(scope="session", autouse=True)
def _resource_tracker() -> None:
    """multiprocessing's resource tracker: one process for the whole test run, started by
    the first spawned process (Dask's workers); started here, before a test's leak check
    would take it for that test's child."""
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()


@pytest.fixture(autouse=True)
def _no_leaks() -> Iterator[None]:
    threads_before = set(threading.enumerate())
    children_before = set(_children())  # (a wider fixture's: set up before this one)
    yield
    leaked_threads = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    leaked_children = multiprocessing.active_children()
    assert not leaked_threads, f"test leaked threads: {leaked_threads}"
    assert not leaked_children, f"test leaked child processes: {leaked_children}"
    deadline = time.monotonic() + CHILD_EXIT_GRACE_S
    while True:
        running = {pid: cmd for pid, cmd in _children().items() if pid not in children_before}
        if not running or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert not running, f"test left child processes running: {running}"


@pytest.fixture(scope="session")
def dask_offload_thread() -> None:
    """distributed keeps one offload thread for the life of the process, started on
    first use: started here, before a test's own leak check sees it appear."""
    from distributed.utils import _offload_executor

    _offload_executor.submit(lambda: None).result()
