"""Real-time set-up of the control thread: scheduler, memory lock, affinity, timer slack, GC.

`apply_rt` runs the steps of an `RtRequest` on the *calling thread* (Linux
scheduling policy, affinity and timer slack are per thread; threads started
afterwards inherit them, so start other threads first or reset theirs):

1. SCHED_FIFO at a priority (``os.sched_setscheduler``);
2. ``mlockall(MCL_CURRENT | MCL_FUTURE)`` so no page fault stalls a tick;
3. CPU affinity (``os.sched_setaffinity``);
4. ``prctl(PR_SET_TIMERSLACK, 1 ns)`` so sleeps are not rounded up by 50 µs (Linux
   >= 6.7 already gives SCHED_FIFO tasks zero slack and ignores the call for them);
5. hold ``/dev/cpu_dma_latency`` at 0 µs (PM QoS: no deep C-state, as cyclictest does);
6. ``gc.collect(); gc.freeze()`` so the start-up objects leave the collector's scans.

`RtMode.ENFORCE` turns the first failure into `RtSetupError` naming what failed
and how to allow it (after undoing the steps already applied);
`RtMode.IGNORE` records it in `RtReport.warnings` and carries on; `RtMode.OFF`
does nothing. `revert_rt` undoes what a report says was applied.

`no_gc` keeps the cyclic collector off while the loop runs (a generation-2
collection pauses 14–19 ms); `collect_in_slack` runs a collection at a moment
the caller knows is safe; `GcMonitor` counts collections and their pauses.
"""

from __future__ import annotations

import ctypes
import enum
import errno
import gc
import os
import struct
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

from rakectl.errors import RakeError

MCL_CURRENT = 1
MCL_FUTURE = 2
PR_SET_TIMERSLACK = 29
PR_GET_TIMERSLACK = 30
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


class RtSetupError(RakeError, OSError):
    """A real-time set-up step was refused; the message says how to allow it."""


class RtMode(enum.Enum):
    """What to do when a real-time step fails."""

    ENFORCE = "enforce"  # raise RtSetupError
    IGNORE = "ignore"  # warn in the report, run anyway
    OFF = "off"  # do not try


@dataclass(frozen=True)
class RtRequest:
    """What to apply; ``None`` leaves that setting alone."""

    priority: int | None = 80
    cpus: frozenset[int] | None = None
    lock_memory: bool = True
    timer_slack_ns: int | None = 1
    cpu_dma_latency_us: int | None = 0
    freeze_gc: bool = True


@dataclass(frozen=True)
class _Previous:
    policy: int
    priority: int
    cpus: frozenset[int]
    timer_slack_ns: int


@dataclass(frozen=True)
class RtReport:
    """What `apply_rt` applied (``None``/``False``: not applied) and the warnings of IGNORE."""

    mode: RtMode
    priority: int | None = None
    memory_locked: bool = False
    cpus: frozenset[int] | None = None
    timer_slack_ns: int | None = None
    cpu_dma_latency_us: int | None = None
    gc_frozen_objects: int | None = None
    warnings: tuple[str, ...] = ()
    previous: _Previous | None = field(default=None, repr=False)
    pm_qos_fd: int | None = field(default=None, repr=False)  # closing it ends the request


class Libc:
    """The libc calls that ``os`` lacks (ctypes); errors raise OSError with errno."""

    def __init__(self) -> None:
        self._libc = ctypes.CDLL(None, use_errno=True)

    def _check(self, result: int, what: str) -> int:
        if result == -1:
            code = ctypes.get_errno()
            raise OSError(code, f"{what}: {os.strerror(code)}")
        return result

    def mlockall(self, flags: int) -> None:
        self._check(self._libc.mlockall(flags), "mlockall")

    def munlockall(self) -> None:
        self._check(self._libc.munlockall(), "munlockall")

    def set_timer_slack_ns(self, slack_ns: int) -> None:
        self._check(self._libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0), "prctl")

    def timer_slack_ns(self) -> int:
        return self._check(self._libc.prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0), "prctl")


# --- the steps: each applies one setting and explains its failure ---------------------------


def _fifo_hint(priority: int, exc: OSError | ValueError) -> str:
    low, high = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
    if not low <= priority <= high:
        return f"SCHED_FIFO priority {priority} refused: valid priorities are {low}..{high}"
    return (
        f"SCHED_FIFO priority {priority} refused ({exc}): run as root or grant CAP_SYS_NICE / "
        f"LimitRTPRIO={priority} (systemd) / an rtprio limit (limits.conf); under a cgroup "
        f"without real-time runtime, give it cpu.rt_runtime_us"
    )


def _mlock_hint(exc: OSError | ValueError) -> str:
    return (
        f"mlockall(MCL_CURRENT|MCL_FUTURE) refused ({exc}): run as root or grant CAP_IPC_LOCK / "
        f"LimitMEMLOCK=infinity (systemd) / a memlock limit (limits.conf)"
    )


def _affinity_hint(cpus: frozenset[int], exc: OSError | ValueError) -> str:
    allowed = sorted(os.sched_getaffinity(0))
    return (
        f"CPU affinity {sorted(cpus)} refused ({exc}): this process may run on CPUs {allowed}; "
        f"choose among them (CPUAffinity= in systemd, a cpuset cgroup, isolcpus= to reserve one)"
    )


def _slack_hint(slack_ns: int, exc: OSError | ValueError) -> str:
    return f"prctl(PR_SET_TIMERSLACK, {slack_ns} ns) refused ({exc}): needs Linux, slack >= 1 ns"


def _pm_qos_hint(latency_us: int, exc: OSError | ValueError) -> str:
    return (
        f"{CPU_DMA_LATENCY} = {latency_us} µs refused ({exc}): run as root or give the service "
        f"write access to {CPU_DMA_LATENCY} (a udev rule)"
    )


# Each step applies one setting and returns the RtReport fields that record it.
_Applied = dict[str, Any]
_Step = tuple[Callable[[], _Applied], Callable[[Any], str]]


def _set_fifo(priority: int) -> _Applied:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    return {"priority": priority}


def _lock_memory(libc: Libc) -> _Applied:
    libc.mlockall(MCL_CURRENT | MCL_FUTURE)
    return {"memory_locked": True}


def _set_affinity(cpus: frozenset[int]) -> _Applied:
    os.sched_setaffinity(0, cpus)
    return {"cpus": cpus}


def _set_slack(libc: Libc, slack_ns: int) -> _Applied:
    if slack_ns < 1:  # 0 would mean "back to the default" (50 µs)
        raise OSError(errno.EINVAL, "0 restores the default slack")
    libc.set_timer_slack_ns(slack_ns)
    return {"timer_slack_ns": slack_ns}


def _hold_cpu_dma_latency(latency_us: int) -> _Applied:
    """Ask for at most ``latency_us`` of C-state exit latency while the fd stays open."""
    fd = os.open(CPU_DMA_LATENCY, os.O_WRONLY | os.O_CLOEXEC)
    try:
        os.write(fd, struct.pack("=i", latency_us))
    except OSError:
        os.close(fd)
        raise
    return {"cpu_dma_latency_us": latency_us, "pm_qos_fd": fd}


def _planned_steps(request: RtRequest, libc: Libc) -> list[_Step]:
    """The requested steps, in order, each with the hint that explains its failure."""
    priority, cpus, slack_ns = request.priority, request.cpus, request.timer_slack_ns
    latency_us = request.cpu_dma_latency_us
    steps: list[_Step] = []
    if priority is not None:
        steps.append((lambda: _set_fifo(priority), lambda e: _fifo_hint(priority, e)))
    if request.lock_memory:
        steps.append((lambda: _lock_memory(libc), _mlock_hint))
    if cpus is not None:
        steps.append((lambda: _set_affinity(cpus), lambda e: _affinity_hint(cpus, e)))
    if slack_ns is not None:
        steps.append((lambda: _set_slack(libc, slack_ns), lambda e: _slack_hint(slack_ns, e)))
    if latency_us is not None:
        steps.append(
            (lambda: _hold_cpu_dma_latency(latency_us), lambda e: _pm_qos_hint(latency_us, e))
        )
    if request.freeze_gc:
        steps.append((lambda: {"gc_frozen_objects": freeze_gc()}, str))
    return steps


# --- applying and reverting ----------------------------------------------------------------


def _capture(libc: Libc) -> _Previous:
    return _Previous(
        policy=os.sched_getscheduler(0),
        priority=os.sched_getparam(0).sched_priority,
        cpus=frozenset(os.sched_getaffinity(0)),
        timer_slack_ns=libc.timer_slack_ns(),
    )


def apply_rt(mode: RtMode, request: RtRequest | None = None, libc: Libc | None = None) -> RtReport:
    """Apply ``request`` (default: `RtRequest()`) to the calling thread as ``mode`` says."""
    if mode is RtMode.OFF:
        return RtReport(mode=mode)
    libc = libc if libc is not None else Libc()
    applied: _Applied = {"mode": mode, "previous": _capture(libc)}
    warnings: list[str] = []
    for action, hint in _planned_steps(request or RtRequest(), libc):
        try:
            applied.update(action())
        except (OSError, ValueError, OverflowError) as exc:
            warnings.append(hint(exc))
            if mode is RtMode.ENFORCE:
                revert_rt(RtReport(**applied), libc)
                raise RtSetupError(warnings[-1]) from exc
    return RtReport(**applied, warnings=tuple(warnings))


def revert_rt(report: RtReport, libc: Libc | None = None) -> None:
    """Undo what ``report`` says was applied (back to SCHED_OTHER etc.), on the calling thread."""
    previous = report.previous
    if previous is None:
        return
    libc = libc if libc is not None else Libc()
    if report.gc_frozen_objects is not None:
        gc.unfreeze()
    if report.pm_qos_fd is not None:
        os.close(report.pm_qos_fd)
    if report.timer_slack_ns is not None:
        libc.set_timer_slack_ns(previous.timer_slack_ns)
    if report.cpus is not None:
        os.sched_setaffinity(0, previous.cpus)
    if report.memory_locked:
        libc.munlockall()
    if report.priority is not None:
        os.sched_setscheduler(0, previous.policy, os.sched_param(previous.priority))


# --- garbage collector ---------------------------------------------------------------------


def freeze_gc() -> int:
    """Collect once, then move every tracked object to the permanent generation.

    Call after start-up, before the loop: the collector then never scans the
    start-up objects again. Returns how many objects were frozen.
    """
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


@contextmanager
def no_gc() -> Iterator[None]:
    """Keep the cyclic collector disabled inside the block; restore its state after."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def collect_in_slack(generation: int = 1) -> int:
    """Collect ``generation`` now (0–2), at a moment the caller knows is safe; objects freed.

    Under `no_gc` reference cycles pile up; a young collection (0 or 1) at an
    idle moment bounds them at a cost that grows with the garbage, not the heap.
    """
    return gc.collect(generation)


class GcMonitor:
    """Counts collections per generation and the longest pause while installed (a context)."""

    def __init__(self, clock_ns: Callable[[], int] = time.perf_counter_ns) -> None:
        self._clock_ns = clock_ns
        self.collections = [0, 0, 0]
        self.longest_pause_ns = 0
        self._started_ns = 0

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._started_ns = self._clock_ns()
            return
        self.collections[info["generation"]] += 1
        self.longest_pause_ns = max(self.longest_pause_ns, self._clock_ns() - self._started_ns)

    def __enter__(self) -> GcMonitor:
        gc.callbacks.append(self._callback)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        gc.callbacks.remove(self._callback)
