"""Per-tick compute of the daemon, stage by stage: the real tick code, timed from outside.

The daemon (:class:`rakectl.daemon.loop.Daemon`) and the emulated drives
(:class:`drivers.emulator.Emulator`) share a python-can ``virtual`` bus in one
process and run in lock-step: each ``Daemon.tick`` is followed by the
emulator's turn. The daemon is brought up, armed and told to rake a lane
through its own command handler, so the ticks timed are ticks in contact.

Stages are timed in the objects the tick calls (the drive client, the
estimator, the impedance filter, the joint servo, the clamp, the supervisor,
the lane planner, the flight recorder): each becomes an instance of a
subclass of its own class whose one method calls the real one between two
clock reads. Nothing is copied, so a change to the tick is measured as it
is. The timers cost a little: the whole tick is also timed without them, in
a separate phase.
Figures are printed, never asserted.
"""

from __future__ import annotations

import dataclasses
import gc
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.emulator import Emulator
from drivers.settings import EmulatorConfig
from rakectl.api.schema import Request, decode_request
from rakectl.config.service import BusInterface, BusSettings
from rakectl.config.settings import Settings
from rakectl.core.lane import LanePhase
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.loop import Daemon
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.states import DaemonState
from rakectl.drive.canbus import open_bus
from rakectl.drive.client import DriveClient
from rakectl.drive.joints import receive_ids
from rakectl.errors import RakeError

# (stage, what is timed), in the order of the tick
STAGES = (
    ("decode", "DriveClient.receive: drain the bus, decode 2 TPDO1"),
    ("plan", "LanePlanner.step: the lane's reference"),
    ("estimate", "DelayForceEstimator.step: F̂"),
    ("control", "ImpedanceFilter.step + JointServo.step (IK, 2 PID)"),
    ("clamp", "VoltageClamp.apply"),
    ("supervise", "ForceSupervisor.step + LanePlanner.govern"),
    ("encode", "DriveClient.send + sync: pack, send 2 RPDO1 + SYNC"),
    ("record", "flight recorder row"),
)
EXCAVATE = (b'{"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 0.8, '
            b'"target_depth_m": 0.05}')


class _Samples:
    """Nanoseconds per tick for each stage (several calls in one tick add up)."""

    def __init__(self, ticks: int) -> None:
        self.ns = {name: np.zeros(ticks, dtype=np.int64) for name, _ in STAGES}
        self.calls = {name: 0 for name, _ in STAGES}
        self.tick = -1  # < 0: not recording

    def timed(self, stage: str, method: Callable[..., Any]) -> Callable[..., Any]:
        clock, ns, calls = time.perf_counter_ns, self.ns[stage], self.calls

        def call(*args: Any) -> Any:
            t0 = clock()
            result = method(*args)
            elapsed = clock() - t0
            if self.tick >= 0:
                ns[self.tick] += elapsed
                calls[stage] += 1
            return result

        return call


def _time(owner: Any, method: str, stage: str, samples: _Samples) -> None:
    """Time ``owner.method`` in place: ``owner`` becomes an instance of a subclass of its
    class whose ``method`` calls the real one inside the timer. Everything else is the
    object's own, at full speed (this works for classes with __slots__ too)."""
    cls = type(owner)
    timed = samples.timed(stage, getattr(cls, method))
    owner.__class__ = type(f"Timed{cls.__name__}", (cls,), {"__slots__": (), method: timed})


def _instrument(daemon: Daemon, samples: _Samples) -> None:
    """Put the timers into the daemon's tick (the real methods run inside)."""
    c = daemon.controller
    for owner, method, stage in (
            (daemon.client, "receive", "decode"), (daemon.planner, "step", "plan"),
            (c.impedance.estimator, "step", "estimate"), (c.impedance.filter, "step", "control"),
            (c.servo, "step", "control"), (c.clamp, "apply", "clamp"),
            (daemon.supervisor, "step", "supervise"), (daemon.planner, "govern", "supervise"),
            (daemon.client, "send", "encode"), (daemon.client, "sync", "encode"),
            (daemon, "_record", "record")):
        _time(owner, method, stage, samples)


class _SilentLog:
    def info(self, event: str, **fields: Any) -> None:
        pass

    warning = info


@dataclass(frozen=True)
class TickFigures:
    ticks: int
    stages_us: dict[str, tuple[float, float]]  # stage: (p50, p99)
    rest_us: tuple[float, float]  # the tick less its timed stages (timed phase)
    tick_us: tuple[float, float, float]  # whole tick without the timers: p50, p99, max
    timer_overhead_ns: float
    state: str  # the daemon's state at the end (EXCAVATE or DONE → HOLD expected)


class LockstepRig:
    """Daemon and emulator on one fresh virtual channel, in lock-step."""

    def __init__(self, directory: Path, defaults: Settings | None = None,
                 emulator: EmulatorConfig | None = None) -> None:
        """``defaults``: the daemon's settings before the rig's own changes; ``emulator``:
        the emulated robot (tests)."""
        defaults = Settings() if defaults is None else defaults
        # The emulator keeps lock-step time (1 ms per tick), so its drives' watchdogs do not
        # see the machine's stalls; the daemon stamps heartbeats with the wall clock, so
        # the heartbeat timeout is long (a stall of a loaded machine is not a lost drive).
        settings = dataclasses.replace(
            defaults, lane=dataclasses.replace(defaults.lane, adaptive=True),
            drives=dataclasses.replace(defaults.drives, heartbeat_timeout_ms=5000))
        self.now_s = 0.0
        bus = BusSettings(interface=BusInterface.VIRTUAL, channel=f"tick-{uuid.uuid4().hex}")
        self.controller_bus = open_bus(bus, receive_ids(settings.drives))
        self.emulator_bus = open_bus(bus, ())
        self.emulator = Emulator(EmulatorConfig() if emulator is None else emulator,
                                 self.emulator_bus, clock=self.clock,
                                 log=_SilentLog())
        client = DriveClient(self.controller_bus, settings.drives, settings.motors,
                             settings.rate_hz)
        self.daemon = Daemon(settings, client, Notifier(None), directory)

    def bring_up(self) -> None:
        """The canopen bring-up (a temporary Notifier thread) against the emulator's thread."""
        stop = threading.Event()
        server = threading.Thread(target=self.emulator.run, args=(stop.is_set, 0.002),
                                  name="bench-emulator")
        self.emulator.start()
        server.start()
        try:
            self.daemon.bring_up()
        finally:
            stop.set()
            server.join(5.0)

    def clock(self) -> float:
        return self.now_s

    def tick(self) -> None:
        self.daemon.tick()
        self.now_s += self.daemon.dt_s
        self.emulator.service(0.0)

    def until(self, state: DaemonState, limit: int) -> None:
        for _ in range(limit):
            if self.daemon.state is state:
                return
            self.tick()
        raise RakeError(f"tick benchmark: the daemon did not reach {state.name} "
                        f"(it is {self.daemon.state.name}: {self.daemon.fault_reason})")

    def close(self) -> None:
        self.daemon.client.stop_all()
        self.emulator.close()
        self.controller_bus.shutdown()
        self.emulator_bus.shutdown()


def _request(line: bytes) -> Request:
    request = decode_request(line)
    if not isinstance(request, Request):
        raise RakeError(f"tick benchmark: a bad request {line!r}: {request}")
    return request


def _clock_overhead_ns() -> float:
    clock = time.perf_counter_ns
    pairs = []
    for _ in range(10_000):
        t0 = clock()
        pairs.append(clock() - t0)
    return float(np.median(pairs))


def _p(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) / 1e3


def bench_tick(ticks: int) -> TickFigures:
    """Run the daemon's tick ``ticks`` times bare, then ``ticks`` times with the timers."""
    with tempfile.TemporaryDirectory(prefix="rakectl-bench-tick-") as directory:
        rig = LockstepRig(Path(directory))
        try:
            return _measure(rig, ticks)
        finally:
            rig.close()


def _measure(rig: LockstepRig, ticks: int) -> TickFigures:
    daemon, handle = rig.daemon, make_handler(rig.daemon)
    rig.bring_up()
    rig.until(DaemonState.DISARMED, 3000)
    handle(_request(b'{"cmd": "arm"}'))
    rig.until(DaemonState.ARMED, 5000)  # through the weight check (about 2.7 s)
    for _ in range(500):  # the drives enable, the loops take the arm's weight
        rig.tick()
    handle(_request(EXCAVATE))
    for _ in range(20_000):  # approach, lower, plunge: measure from the first stroke on
        if daemon.planner is not None and daemon.planner.phase is LanePhase.STROKE:
            break
        rig.tick()
    clock = time.perf_counter_ns
    bare = np.zeros(ticks, dtype=np.int64)
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for k in range(ticks):
            t0 = clock()
            daemon.tick()
            bare[k] = clock() - t0
            rig.now_s += daemon.dt_s
            rig.emulator.service(0.0)
        samples = _Samples(ticks)
        whole = np.zeros(ticks, dtype=np.int64)
        _instrument(daemon, samples)
        for k in range(ticks):
            samples.tick = k
            t0 = clock()
            daemon.tick()
            whole[k] = clock() - t0
            samples.tick = -1
            rig.now_s += daemon.dt_s
            rig.emulator.service(0.0)
    finally:
        if gc_was_enabled:
            gc.enable()
    if daemon.state not in (DaemonState.EXCAVATE, DaemonState.HOLD):
        raise RakeError(f"tick benchmark: the daemon left the lane: {daemon.state.name} "
                        f"({daemon.fault_reason})")
    return _figures(ticks, samples, whole, bare, daemon.state.name)


def _figures(ticks: int, samples: _Samples, whole: np.ndarray, bare: np.ndarray,
             state: str) -> TickFigures:
    overhead = _clock_overhead_ns()
    stages: dict[str, tuple[float, float]] = {}
    total = np.zeros(ticks, dtype=np.float64)
    for name, _ in STAGES:
        per_tick_calls = samples.calls[name] / ticks
        ns = samples.ns[name] - overhead * per_tick_calls
        total += ns
        stages[name] = (_p(ns, 50), _p(ns, 99))
    rest = whole - total
    return TickFigures(ticks, stages, (_p(rest, 50), _p(rest, 99)),
                       (_p(bare, 50), _p(bare, 99), float(bare.max()) / 1e3), overhead, state)


def format_tick(f: TickFigures) -> str:
    lines = [f"per-tick compute: Daemon.tick in lock-step with the emulator on virtual, raking "
             f"loam, {f.ticks} ticks per phase (gc off; timer overhead {f.timer_overhead_ns:.0f} "
             "ns per call subtracted)",
             f"  {'stage':<10}{'p50 µs':>8}{'p99 µs':>8}  what"]
    for name, what in STAGES:
        p50, p99 = f.stages_us[name]
        lines.append(f"  {name:<10}{p50:8.1f}{p99:8.1f}  {what}")
    lines.append(f"  {'rest':<10}{f.rest_us[0]:8.1f}{f.rest_us[1]:8.1f}  the tick less the "
                 "stages: states, checks, the timers' own calls")
    lines.append(f"  {'tick':<10}{f.tick_us[0]:8.1f}{f.tick_us[1]:8.1f}  whole Daemon.tick "
                 f"without timers (max {f.tick_us[2]:.0f} µs)")
    return "\n".join(lines)
