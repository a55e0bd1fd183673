"""Real-time set-up: ENFORCE raises named errors, IGNORE warns, OFF does nothing; the GC switches.

The full set-up (SCHED_FIFO, mlockall, …) runs in a child process; in this
process only steps that are reverted at once run, and every test checks that
pytest is back at SCHED_OTHER afterwards.
"""

from __future__ import annotations

import errno
import gc
import json
import os
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from dataclasses import replace

import pytest

from rakectl.daemon.rt import (
    GcMonitor,
    Libc,
    RtMode,
    RtRequest,
    RtSetupError,
    apply_rt,
    collect_in_slack,
    freeze_gc,
    no_gc,
    revert_rt,
)
from rakectl.errors import RakeError

NOTHING = RtRequest(
    priority=None, lock_memory=False, timer_slack_ns=None, cpu_dma_latency_us=None, freeze_gc=False
)
needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO and mlockall need root here")


@pytest.fixture(autouse=True)
def _back_to_normal_scheduling() -> Iterator[None]:
    affinity = os.sched_getaffinity(0)
    yield
    policy = os.sched_getscheduler(0)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.sched_setaffinity(0, affinity)
    assert policy == os.SCHED_OTHER, "a test left pytest at a real-time policy"


class FakeLibc(Libc):
    """Records calls; ``refuse`` names the calls that fail with EPERM."""

    def __init__(self, refuse: tuple[str, ...] = ()) -> None:
        self.calls: list[str] = []
        self.slack_ns = 50_000
        self._refuse = refuse

    def _call(self, name: str) -> None:
        self.calls.append(name)
        if name in self._refuse:
            raise OSError(errno.EPERM, f"{name}: Operation not permitted")

    def mlockall(self, flags: int) -> None:
        self._call("mlockall")

    def munlockall(self) -> None:
        self._call("munlockall")

    def set_timer_slack_ns(self, slack_ns: int) -> None:
        self._call("set_timer_slack")
        self.slack_ns = slack_ns

    def timer_slack_ns(self) -> int:
        return self.slack_ns


def test_off_applies_nothing() -> None:
    report = apply_rt(RtMode.OFF, RtRequest(priority=200, cpus=frozenset({4096})))
    assert report.priority is None and report.cpus is None and not report.memory_locked
    assert report.warnings == ()
    revert_rt(report)


def test_enforce_names_an_impossible_priority() -> None:
    with pytest.raises(RtSetupError, match=r"SCHED_FIFO priority 200 refused: valid .* 1\.\.99"):
        apply_rt(RtMode.ENFORCE, RtRequest(priority=200, lock_memory=False, freeze_gc=False))


def test_enforce_names_an_invalid_cpu() -> None:
    request = replace(NOTHING, cpus=frozenset({4096}))
    with pytest.raises(RtSetupError, match=r"CPU affinity \[4096\] refused .* may run on CPUs"):
        apply_rt(RtMode.ENFORCE, request)
    with pytest.raises(RtSetupError, match="negative CPU"):
        apply_rt(RtMode.ENFORCE, replace(NOTHING, cpus=frozenset({-1})))


def test_setup_error_is_in_the_tree() -> None:
    assert issubclass(RtSetupError, RakeError) and issubclass(RtSetupError, OSError)


def test_enforce_names_refused_mlockall_and_how_to_allow_it() -> None:
    libc = FakeLibc(refuse=("mlockall",))
    request = replace(NOTHING, lock_memory=True)
    with pytest.raises(RtSetupError, match=r"mlockall\(MCL_CURRENT\|MCL_FUTURE\) .*CAP_IPC_LOCK"):
        apply_rt(RtMode.ENFORCE, request, libc)


def test_enforce_reverts_the_steps_already_applied() -> None:
    libc = FakeLibc()
    request = replace(NOTHING, lock_memory=True, timer_slack_ns=1, cpus=frozenset({4096}))
    with pytest.raises(RtSetupError):
        apply_rt(RtMode.ENFORCE, request, libc)
    assert libc.calls == ["mlockall", "munlockall"]  # failed before the slack step


def test_ignore_returns_warnings_and_carries_on() -> None:
    libc = FakeLibc(refuse=("mlockall",))
    request = RtRequest(
        priority=200, cpus=frozenset({4096}), timer_slack_ns=1, cpu_dma_latency_us=None,
        freeze_gc=False,
    )  # fmt: skip
    report = apply_rt(RtMode.IGNORE, request, libc)
    try:
        assert [w.split(" refused")[0] for w in report.warnings] == [
            "SCHED_FIFO priority 200",
            "mlockall(MCL_CURRENT|MCL_FUTURE)",
            "CPU affinity [4096]",
        ]
        assert report.priority is None and not report.memory_locked and report.cpus is None
        assert report.timer_slack_ns == 1 and libc.slack_ns == 1
    finally:
        revert_rt(report, libc)
    assert libc.slack_ns == 50_000


def test_zero_timer_slack_is_refused() -> None:
    request = replace(NOTHING, timer_slack_ns=0)
    with pytest.raises(RtSetupError, match="PR_SET_TIMERSLACK"):
        apply_rt(RtMode.ENFORCE, request, FakeLibc())


@needs_root
def test_apply_and_revert_in_this_process() -> None:
    cpu = min(os.sched_getaffinity(0))
    request = replace(NOTHING, priority=1, cpus=frozenset({cpu}), cpu_dma_latency_us=0)
    report = apply_rt(RtMode.ENFORCE, request)
    try:
        assert os.sched_getscheduler(0) == os.SCHED_FIFO
        assert os.sched_getaffinity(0) == {cpu}
        assert report.cpu_dma_latency_us == 0 and report.pm_qos_fd is not None
    finally:
        revert_rt(report)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
    with pytest.raises(OSError):
        os.fstat(report.pm_qos_fd)  # closed: the PM QoS request ended


_CHILD = textwrap.dedent(
    """
    import json, os
    from rakectl.daemon.rt import Libc, RtMode, RtRequest, apply_rt, revert_rt

    def state():
        with open("/proc/self/status") as status:
            locked = [line for line in status if line.startswith("VmLck:")][0].split()[1]
        return {
            "policy": os.sched_getscheduler(0), "priority": os.sched_getparam(0).sched_priority,
            "locked_kb": int(locked), "slack_ns": Libc().timer_slack_ns(),
            "cpus": sorted(os.sched_getaffinity(0)),
        }

    before = state()
    report = apply_rt(RtMode.ENFORCE, RtRequest(cpus=frozenset({0})))
    during = state() | {"frozen": report.gc_frozen_objects, "warnings": list(report.warnings)}
    revert_rt(report)
    print(json.dumps({"before": before, "during": during, "after": state()}))
    """
)


@needs_root
def test_full_setup_in_a_child_process() -> None:
    done = subprocess.run(
        [sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    states = json.loads(done.stdout)
    during = states["during"]
    assert (during["policy"], during["priority"]) == (os.SCHED_FIFO, 80)
    assert during["locked_kb"] > 0 and during["cpus"] == [0]
    assert during["slack_ns"] in (0, 1)  # Linux >= 6.7 gives real-time tasks no slack at all
    assert during["frozen"] > 0 and during["warnings"] == []
    after, before = states["after"], states["before"]
    assert after == before and after["policy"] == os.SCHED_OTHER and after["locked_kb"] == 0


# --- GC --------------------------------------------------------------------------------------


def test_freeze_gc_moves_objects_to_the_permanent_generation() -> None:
    try:
        assert freeze_gc() == gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0


def test_no_gc_disables_and_restores() -> None:
    assert gc.isenabled()
    with pytest.raises(KeyError), no_gc():
        assert not gc.isenabled()
        raise KeyError("inside")
    assert gc.isenabled()
    gc.disable()
    try:
        with no_gc():
            pass
        assert not gc.isenabled()  # it was off before: stays off
    finally:
        gc.enable()


def test_collect_in_slack_frees_cycles_made_under_no_gc() -> None:
    with no_gc(), GcMonitor() as monitor:
        for _ in range(100):
            cycle: list[object] = []
            cycle.append(cycle)
        del cycle
        assert monitor.collections == [0, 0, 0]
        assert collect_in_slack(0) >= 100
        assert monitor.collections == [1, 0, 0]
        gc.collect(2)
        assert monitor.collections[2] == 1 and monitor.longest_pause_ns > 0
    assert monitor._callback not in gc.callbacks


@needs_root
@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs util-linux setpriv")
def test_unprivileged_enforce_says_how_to_allow_it() -> None:
    code = (
        "from rakectl.daemon.rt import RtMode, RtSetupError, apply_rt\n"
        "try:\n    apply_rt(RtMode.ENFORCE)\nexcept RtSetupError as exc:\n    print(exc)\n"
    )
    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all"]
    done = subprocess.run(
        [*nobody, sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("SCHED_FIFO priority 80 refused")
    assert "CAP_SYS_NICE" in done.stdout and "LimitRTPRIO=80" in done.stdout
