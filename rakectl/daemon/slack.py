"""What the daemon does besides the tick: the slack's work, events, dumps, the end of a run.

The base of the daemon (then :class:`rakectl.daemon.transitions.StateChanges`, then
:class:`rakectl.daemon.loop.Daemon`). Everything here runs in the
tick's slack with a hard time budget (the command socket's poll, flight-recorder
dumps, bus traces, log lines, systemd's watchdog, the garbage collector while
disarmed), or once when the loop ends: it can delay nothing but itself.
"""

from __future__ import annotations

import collections
import gc
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from rakectl.config.settings import Settings
from rakectl.daemon.events import EventLog
from rakectl.daemon.inputs import InputLog
from rakectl.daemon.recorder import DumpError, DumpWriter, FlightRecorder
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.states import ARMED_STATES, DaemonState
from rakectl.daemon.timing import LoopTiming, TickTimer
from rakectl.drive.canbus import TraceRecorder
from rakectl.drive.client import DriveClient

SLACK_GUARD_S = 250e-6  # slack work stops this long before the next deadline
# While the loop overruns there is no slack. At least this often, past the deadline, the
# command socket is still polled for STARVED_POLL_BUDGET_S, so that a request (an e-stop
# among them) waits a bounded time, not until the load drops, and systemd's watchdog is
# still kicked: the loop is slow, not stuck (a slow armed loop faults on its own).
STARVED_POLL_INTERVAL_S = 0.01
STARVED_POLL_BUDGET_S = 200e-6


class SlackWork:
    """The slack's work and the run's end; the loop's state is the subclass's."""

    settings: Settings
    client: DriveClient
    notifier: Notifier
    dump_dir: Path
    timer: TickTimer
    timing: LoopTiming
    recorder: FlightRecorder
    events: EventLog
    state: DaemonState
    ticks: int
    slack_hook: Callable[[float], object] | None  # the command server's poll
    trace: TraceRecorder | None  # bus trace, drained in the slack
    inputs: InputLog | None  # the trace's sidecar, drained in the slack
    _dumps: collections.deque[DumpWriter]
    dump_failures: collections.deque[str]  # the last dumps that could not be written
    _clock_ns: Callable[[], int]
    _next_stats_tick: int
    _next_watchdog_tick: int
    _next_starved_tick: int  # from this tick, the socket is polled even with no slack

    def finish(self, reason: str = "stop requested") -> None:
        """0 V, drives disabled, the recorder dumped: the end of every run (``reason``
        goes to the trace's inputs)."""
        self.notifier.stopping()
        self.client.stop_all()
        if self.inputs is not None:
            self.inputs.end(self.ticks, reason, self.trace)
        self._dump("shutdown")
        self.event("bus_latency", **self.bus_latency())
        while self._dumps:
            self._work_on_dump(1.0)
        self.events.flush(self.state.name)


    # ------------------------------------------------------------------ slack

    def slack(self) -> None:
        """Work that is not the tick, within the time left before the next deadline."""
        deadline_ns = self.timer.deadline_of(self.timer.tick_index + 1)
        budget_s = (deadline_ns - self._clock_ns()) * 1e-9 - SLACK_GUARD_S
        if budget_s <= 0.0:
            if self.ticks >= self._next_starved_tick:
                self._starved()
            return
        started = time.perf_counter()
        self._next_starved_tick = self.ticks + self._starved_interval_ticks()
        if self.slack_hook is not None:
            self.slack_hook(budget_s * 0.5)
        if self._dumps:
            left = budget_s - (time.perf_counter() - started)
            if left > 0:
                self._work_on_dump(left)
        if self.trace is not None or self.inputs is not None:
            self._write_trace()
        self.events.flush(self.state.name, 1)
        self._periodic()

    def _starved(self) -> None:
        """The slack's work that cannot wait for slack, bounded: the tick is late already."""
        self._next_starved_tick = self.ticks + self._starved_interval_ticks()
        if self.slack_hook is not None:
            self.slack_hook(STARVED_POLL_BUDGET_S)
        self._kick_watchdog()

    def _starved_interval_ticks(self) -> int:
        return max(1, round(STARVED_POLL_INTERVAL_S * self.settings.rate_hz))

    def _kick_watchdog(self) -> None:
        if self.ticks >= self._next_watchdog_tick:
            self.notifier.watchdog(self.ticks)  # only sent if the tick counter advanced
            self._next_watchdog_tick = self.ticks + round(0.1 * self.settings.rate_hz)

    def _write_trace(self) -> None:
        """A little of the bus trace and of its inputs. A file that cannot be written (a
        full disk) ends the recording, logged once, never the loop: the ring then drops
        what it can no longer hand on (counted in its ``dropped``)."""
        try:
            if self.trace is not None:
                self.trace.drain(32)
            if self.inputs is not None and self.inputs.pending:
                self.inputs.drain()
        except OSError as error:
            self.event("trace_failed", error=f"{type(error).__name__}: {error}",
                       path=self.settings.bus.trace_path)
            self.trace = self.inputs = None

    def _work_on_dump(self, budget_s: float) -> None:
        """Write on the oldest dump; a dump that cannot be written is dropped and logged,
        never a reason for the loop to stop."""
        writer = self._dumps[0]
        try:
            done = writer.work(budget_s)
        except DumpError as error:
            self._dumps.popleft()
            self.dump_failures.append(str(error))
            self.event("recorder_dump_failed", path=str(writer.path), error=str(error))
            return
        if done:
            self._dumps.popleft()
            self.event("recorder_dumped", path=str(writer.path))

    def pending_dumps(self) -> list[str]:
        return [str(writer.path) for writer in self._dumps]

    def _periodic(self) -> None:
        self._kick_watchdog()
        if self.ticks >= self._next_stats_tick:
            self._next_stats_tick = self.ticks + round(self.settings.daemon.stats_interval_s
                                                       * self.settings.rate_hz)
            if self.ticks > 1:
                self.event("timing", **self.timing.summary())
        if self.state not in ARMED_STATES and self.ticks % 1000 == 0:
            gc.collect(1)  # never while armed: the collector is off then (see cli)

    def bus_latency(self) -> dict[str, Any]:
        """SYNC → TPDO1 arrival percentiles (µs) and the bus counters (off the hot path)."""
        samples = self.client.sync_to_tpdo_s()
        out: dict[str, Any] = {"samples": len(samples), **self.client.stats.as_dict()}
        if samples:
            values = np.array(samples) * 1e6
            for name, q in (("p50", 50), ("p99", 99), ("p99.9", 99.9)):
                out[f"sync_to_tpdo_{name}_us"] = round(float(np.percentile(values, q)), 1)
            out["sync_to_tpdo_max_us"] = round(float(values.max()), 1)
        return out

    # ------------------------------------------------------------------ events and dumps

    def event(self, name: str, **fields: Any) -> None:
        """Queue a log line; it is written in the slack, never in the tick."""
        self.events.add(name, fields)

    def _dump(self, reason: str) -> Path:
        """A dump named after now, the tick and ``reason``; a second one of the same tick
        and reason (two requests between ticks) gets a number, not the same file."""
        stamp = time.strftime("%Y%m%d-%H%M%S")
        base = f"rakectl-{stamp}-{self.ticks}-{reason}"
        taken = {writer.path for writer in self._dumps}
        path, n = self.dump_dir / f"{base}.csv", 1
        while path in taken or path.exists():
            n += 1
            path = self.dump_dir / f"{base}-{n}.csv"
        return self.dump_to(path)

    def dump_to(self, path: Path, open_now: bool = False) -> Path:
        """Snapshot the recorder now, to be written to ``path`` in the slack; with
        ``open_now`` the file is created first (DumpError if it cannot be)."""
        writer = self.recorder.start_dump(path)
        if open_now:
            writer.open_now()
        self._dumps.append(writer)
        return path
