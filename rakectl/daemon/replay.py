"""Replaying a recorded bus trace through the controller, offline: no bus, no clock.

A run recorded with ``bus.trace_path`` leaves two files: the candump ``.log`` of
every frame the daemon sent and received (rakectl.drive.canbus) and its sidecar
``<trace>.inputs.jsonl`` (rakectl.daemon.inputs): the operator's commands,
overruns, heartbeats found lost and failed sends, each at its tick. :func:`replay`
reads both (python-can's ``CanutilsLogReader``), builds a real
:class:`~rakectl.daemon.loop.Daemon` and :class:`~rakectl.drive.client.DriveClient`
on a :class:`ReplayBus` that serves the recorded frames and compares what is
sent, and runs the loop tick by tick (the files are read by rakectl.daemon.recording):

- bring-up is not replayed: the client takes up the state the bring-up left
  (each drive's statusword, recorded in the sidecar) and the comparison starts
  with the first frame of the loop (the sidecar's ``start.frame``);
- each tick, the client's drain gets the frames the run received in that tick
  (those recorded before the tick's first frame sent), the tick runs with the
  deadlines the run skipped before it, and each frame it sends must equal the next
  frame the run sent: COB-ID, DLC and data (timestamps are not compared);
- between ticks, the commands the run carried out are applied through the same
  handler (rakectl.daemon.handlers), except for the check of the loop's measured
  timing before arming; the heartbeat check is given the outcomes the run's wall
  clock gave; a send the run saw fail fails again;
- at the run's end, the frames of its ``finish`` (0 V, drives disabled) are
  compared too.

The result names the first frame that differs (the tick, the trace's line, the
frame expected and the frame sent) or how many frames were reproduced. A trace or
sidecar that is missing, garbled or from another run raises :class:`TraceError`
naming the file and line; a configuration other than the run's raises
:class:`ConfigError` naming the first option that differs.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from rakectl.api.schema import Request
from rakectl.config.settings import Settings
from rakectl.daemon.events import EventLog
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.inputs import sidecar_path
from rakectl.daemon.loop import Daemon
from rakectl.daemon.recording import (
    Frame,
    Inputs,
    Overrun,
    SendFailure,
    check_settings,
    frames_of,
    read_inputs,
)
from rakectl.daemon.sdnotify import Notifier
from rakectl.drive.client import DriveClient
from rakectl.errors import CommandRejected, FrameError, RakeError, TraceError
from rakectl.protocol.codec import NMT_COB_ID, SYNC_COB_ID, split_cob_id

# =========================================================================== the bus


def describe(msg: can.Message) -> str:
    """A frame in candump's notation with what it is: ``201#E8030F00 (RPDO1 of node 1)``."""
    if msg.is_error_frame:
        return "an error frame"
    can_id = msg.arbitration_id
    frame = f"{can_id:03X}#" + ("R" if msg.is_remote_frame else msg.data.hex().upper())
    if can_id == SYNC_COB_ID:
        name = "SYNC"
    elif can_id == NMT_COB_ID:
        name = "NMT"
    else:
        try:
            function, node = split_cob_id(can_id)
            name = f"{function.name} of node {node}"
        except FrameError:
            name = "an unknown ID"
    return f"{frame} ({name})"


def same_frame(a: can.Message, b: can.Message) -> bool:
    """Equal on the bus: ID, its format, kind, DLC and data (not timestamps)."""
    return (a.arbitration_id == b.arbitration_id and a.is_extended_id == b.is_extended_id
            and a.is_remote_frame == b.is_remote_frame and a.is_error_frame == b.is_error_frame
            and a.dlc == b.dlc and bytes(a.data or b"") == bytes(b.data or b""))


class _Stop(Exception):
    """Ends the replay from inside the loop; never a RakeError, never a CanError."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class _Diverged(_Stop):
    """A frame sent differs from the run's."""


class _Incomplete(_Stop):
    """The record is not complete beyond this point."""


class _TraceEnds(_Stop):
    """No frame left to compare with."""


class _Replayed(_Stop):
    """The sidecar lost entries: replayed as far as it is complete."""


class ReplayBus(can.BusABC):
    """A python-can bus serving a trace's received frames and comparing what is sent.

    ``recv`` returns the next frame the run received, up to the next frame the run
    sent (or the next send that failed): the frames of the tick's drain. ``send``
    compares the frame with the next frame the run sent and raises (an internal
    exception the loop does not catch) on the first difference; a send the run saw
    fail raises ``CanOperationError`` with the run's error. The trace is read as the
    replay goes: ``start`` frames (bring-up's) are skipped, and the frames from
    ``complete`` on are not the run's, all of them (a ring that dropped frames).
    """

    def __init__(self, frames: Iterator[Frame], start: int, failures: dict[int, SendFailure],
                 complete: int | None) -> None:
        super().__init__(channel="replay")
        self.channel_info = "replay of a bus trace"
        self._frames = frames
        self._next: Frame | None = None
        self.position = 0  # frames of the trace consumed
        self._peek()
        while self.position < start and self._next is not None:
            self._take()
        if self.position < start:
            self.shutdown()  # python-can warns of a bus dropped unshut
            raise TraceError(f"{self.position} frames in the trace, but its inputs say the "
                             f"loop began after frame {start}: not this run's trace")
        self._failures = failures
        self._fail_frames = sorted((f.attempt, f.frame) for f in failures.values())
        self._next_failure = 0
        self._attempts = 0
        self._complete = complete
        self.reproduced = 0  # frames sent that equal the run's

    def _peek(self) -> None:
        self._next = next(self._frames, None)

    def _take(self) -> Frame:
        frame = self._next
        assert frame is not None
        self.position += 1
        self._peek()
        return frame

    @property
    def next_frame(self) -> Frame | None:
        """The next frame of the trace not consumed yet, None at its end."""
        return self._next

    def _check_complete(self) -> None:
        if self._complete is not None and self.position >= self._complete:
            raise _Incomplete("the trace lost frames here")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        frame = self._next
        if frame is None or not frame.rx:
            return None, False
        self._check_complete()
        if (self._next_failure < len(self._fail_frames)
                and self._fail_frames[self._next_failure][1] <= self.position):
            return None, False  # the run's next send failed before this frame arrived
        return self._take().msg, True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        attempt = self._attempts
        self._attempts += 1
        failure = self._failures.get(attempt)
        if failure is not None:
            self._next_failure += 1
            if failure.frame != self.position:
                raise _Diverged(f"the run's send {attempt} ({failure.can_id:03X}#) failed "
                                f"before trace frame {failure.frame}, the replay's is at "
                                f"frame {self.position}")
            if msg.arbitration_id != failure.can_id or bytes(msg.data) != failure.data:
                raise _Diverged(f"the run's send {attempt}, which failed, was "
                                f"{failure.can_id:03X}#{failure.data.hex().upper()}; the "
                                f"replay sends {describe(msg)}")
            raise can.CanOperationError(f"replayed: {failure.error}")
        expected = self._next
        if expected is None:
            raise _TraceEnds(f"the trace ends; the replay sends {describe(msg)}")
        self._check_complete()
        if expected.rx:
            raise _Diverged(f"trace line {expected.line}: the run sent nothing more before "
                            f"receiving {describe(expected.msg)}; the replay sends "
                            f"{describe(msg)}")
        if not same_frame(expected.msg, msg):
            raise _Diverged(f"trace line {expected.line}: expected {describe(expected.msg)}, "
                            f"got {describe(msg)}")
        self._take()
        self.reproduced += 1


# =========================================================================== the replay


@dataclass
class ReplayResult:
    """How a replay went: reproduced, or the first difference, or where the record stops."""

    reproduced: int  # frames sent that equal the run's
    ticks: int  # the tick counter reached
    bring_up_frames: int  # trace frames before the loop, not compared
    states: list[str]  # the states the replay went through
    ended: str  # how the run ended, as its inputs say
    faults: list[str] = dataclasses.field(default_factory=list)  # why it entered FAULT
    mismatch: str = ""  # the first difference, one line
    incomplete: str = ""  # the record is not complete beyond this point, one line

    @property
    def ok(self) -> bool:
        return not self.mismatch and not self.incomplete

    def message(self) -> str:
        if self.mismatch:
            return f"replay: mismatch at {self.mismatch} ({self.reproduced} frames reproduced " \
                   "before it)"
        if self.incomplete:
            return f"replay: {self.incomplete}; {self.reproduced} frames reproduced up to there"
        return (f"replay: {self.reproduced} frames reproduced, frame for frame, over "
                f"{self.ticks} ticks ({' → '.join(self.states)}; {self.ended}; "
                f"{self.bring_up_frames} bring-up frames before the loop not compared)")


class _Events:
    """Collects the daemon's events (a structlog-like logger) instead of writing them."""

    def __init__(self) -> None:
        self.states: list[str] = []
        self.faults: list[str] = []

    def _event(self, name: str, **fields: Any) -> None:
        if name == "state":
            self.states.append(str(fields.get("new")))
            if fields.get("new") == "FAULT":
                self.faults.append(str(fields.get("reason")))

    info = warning = error = _event


def replay(trace: Path, settings: Settings, inputs_path: Path | None = None) -> ReplayResult:
    """Feed ``trace``'s received frames through a real daemon and compare what it sends.

    ``settings`` must be the run's (ConfigError names the first option that differs);
    TraceError for a trace or inputs file that is missing, garbled or another run's.
    """
    if not trace.is_file():
        raise TraceError(f"{trace}: no such trace")
    inputs = read_inputs(sidecar_path(trace) if inputs_path is None else inputs_path)
    check_settings(inputs.settings, settings, inputs.path)
    complete: int | None = None
    end = inputs.end
    if end is not None and end.first_dropped_at >= 0:
        complete = end.first_dropped_at
    try:
        bus = ReplayBus(frames_of(trace), inputs.start_frame, inputs.failures, complete)
    except TraceError as error:
        if str(error).startswith(f"{trace}"):
            raise
        raise TraceError(f"{trace}: {error} ({inputs.path})") from None
    try:
        with tempfile.TemporaryDirectory(prefix="rakectl-replay-") as dump_dir:
            client = DriveClient(bus, settings.drives, settings.motors, settings.rate_hz,
                                 clock=lambda: 0.0)
            try:
                client.started(inputs.statuswords)
            except FrameError as error:
                raise TraceError(f"{inputs.path}, line 1: a recorded statusword: {error}") from None
            daemon = Daemon(settings, client, Notifier(None), Path(dump_dir))
            events = _Events()
            daemon.events = EventLog(events)
            daemon.heartbeat_clock = _outcomes(daemon, inputs.heartbeat_lost)
            result = ReplayResult(0, 0, inputs.start_frame, [daemon.state.name],
                                  end.reason if end is not None else
                                  "no end entry: the run was killed or its files not closed")
            try:
                _run(daemon, make_handler(daemon, timing_checked=False), inputs, bus)
                frame = bus.next_frame
                if frame is not None:
                    raise _Diverged(f"trace line {frame.line}: the run's end, and the trace goes "
                                    f"on with {describe(frame.msg)}")
            except _Incomplete:
                assert end is not None
                result.incomplete = (f"the trace lost {end.dropped} frames from frame "
                                     f"{end.first_dropped_at} on, its ring full (tick "
                                     f"{daemon.ticks})")
            except _TraceEnds:
                if end is not None:  # (no end entry: the run was killed, its trace ends here)
                    result.incomplete = (f"the trace ends at frame {bus.position} of the "
                                         f"{end.frames} the run recorded (tick {daemon.ticks}): "
                                         "cut short")
            except _Diverged as diverged:
                result.mismatch = f"tick {daemon.ticks}, {diverged.message}"
                if end is None and daemon.ticks > inputs.last_tick:  # (a killed run's file
                    # holds every entry, flushed as written, and its trace ends there too)
                    result.mismatch += (f" (its inputs {inputs.path} have no end entry: "
                                        "the run was killed, or the file was cut short; "
                                        f"their last entry is at tick {inputs.last_tick})")
            except _Replayed as stopped:
                result.incomplete = stopped.message
            daemon.events.flush(daemon.state.name)
            result.reproduced, result.ticks = bus.reproduced, daemon.ticks
            result.states = [result.states[0], *events.states]
            result.faults = events.faults
    finally:
        bus.shutdown()  # (also when a garbled line ends it)
    return result


def _outcomes(daemon: Daemon, lost_ticks: frozenset[int]) -> Callable[[], float]:
    """The heartbeat check's "now": the client stamps every heartbeat 0.0, so a check is
    lost exactly at the ticks where the run found it lost (now = ∞)."""

    def now() -> float:
        return math.inf if daemon.ticks in lost_ticks else 0.0

    return now


def _run(daemon: Daemon, handle: Callable[[Request], object], inputs: Inputs,
         bus: ReplayBus) -> None:
    """The loop of ``Daemon.run`` with the run's inputs in place of the clock and socket."""
    between = inputs.between_ticks
    end = inputs.end
    index = 0
    while True:
        skipped = 0
        while index < len(between) and between[index].after_tick == daemon.ticks:
            entry = between[index]
            index += 1
            if isinstance(entry, Overrun):
                skipped = entry.skipped
                continue
            try:
                handle(entry.request)
            except (CommandRejected, RakeError) as error:
                raise _Diverged(f"{inputs.path}, line {entry.line}: the run carried out "
                                f"{entry.request.cmd.value}, the replay refuses it: "
                                f"{error}") from None
        if index < len(between) and between[index].after_tick < daemon.ticks:
            raise _Diverged(f"{inputs.path}: an entry after tick {between[index].after_tick}, "
                            f"which the replay's tick counter passed")
        if end is not None and daemon.ticks == end.after_tick:
            break
        # (the last complete entry may be one of several in its tick: that tick not run)
        if (inputs.complete_until_tick is not None
                and daemon.ticks + 1 >= inputs.complete_until_tick):
            raise _Replayed(f"the trace's inputs lost entries after tick {daemon.ticks}")
        if end is None and bus.next_frame is None:
            return  # the trace ends between ticks: the run was not ended cleanly
        try:
            daemon.tick(skipped)
        except _Stop:
            raise
        except TraceError:
            raise  # a garbled line met on the way
        except Exception as error:  # the run's loop ends on it: its end entry must say so
            if end is None or end.after_tick != daemon.ticks or \
                    not end.reason.startswith(type(error).__name__):
                raise _Diverged(f"the replay's tick raised {type(error).__name__}: "
                                f"{error}") from None
            break
        daemon.events.flush(daemon.state.name)
    if end is not None:
        daemon.finish(end.reason)


__all__ = ["ReplayBus", "ReplayResult", "describe", "replay", "same_frame"]
