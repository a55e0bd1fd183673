"""What decides the daemon's output besides the frames it receives, recorded next to its
bus trace so that a replay (rakectl.daemon.replay) can reproduce every frame it sent.

A tick's output is a function of the frames drained at its start and of the
daemon's state; the state changes with those frames and with four things the
bus trace does not hold:

- the operator's commands, applied in the slack between two ticks;
- overruns: a late wake-up advances the tick counter by the deadlines skipped, and
  a streak of them faults;
- the heartbeat timeout, judged on the wall clock (the time a drive's heartbeat
  was last seen against the time of the check);
- sends that failed (bus-off, a full queue): such a frame is in no trace, and a
  streak of them faults.

With ``bus.trace_path`` set, :class:`InputLog` writes them to the sidecar
``<trace_path>.inputs.jsonl`` (:func:`sidecar_path`), one JSON object a line:

``start``
    written when bring-up ends: the trace's frame count then (``frame``: where the
    loop's frames begin), each drive's statusword read at bring-up's end, the
    settings the daemon runs with, and the rakectl version.
``command``
    a request that changed something, as validated (defaults filled in), with
    ``after_tick``: the tick counter when it took effect, after that tick's frames
    and before the next tick's.
``overrun``
    ``after_tick`` and ``skipped``: the next tick came that many deadlines late.
``heartbeat_lost``
    ``tick``: the heartbeat check of that tick found a drive's heartbeat too old.
``send_failed``
    ``tick``, ``attempt`` (the client's transmissions counted from 0), ``frame`` (the
    trace's frame count then), ``id``, ``data`` (hex) and ``error``; at most
    MAX_SEND_FAILURES of them, the rest counted as ``lost``.
``lost``
    ``entries`` that found the queue full (the slack had no time for the sidecar), or
    failed sends past MAX_SEND_FAILURES, and every entry after the first of them;
    the record is complete only up to entry ``complete_entries`` (counted from 1, the
    start entry included). It may follow the ``end`` entry.
``end``
    the loop's end: ``after_tick``, ``reason`` and the trace's counts (``frames``
    recorded, ``dropped`` on a full ring, ``first_dropped_at``).

The tick only appends a tuple to a queue, and only in the rare cases above
(an overrun, a lost heartbeat, a failed send; commands arrive in the slack);
formatting and writing happen in the slack, as the bus trace's do.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import importlib.metadata
import json
from pathlib import Path
from typing import Any, TextIO

import can

from rakectl.api.schema import Request
from rakectl.config.service import BusSettings
from rakectl.drive.canbus import BusError, TraceRecorder

SIDECAR_SUFFIX = ".inputs.jsonl"
FORMAT = 1
QUEUE_LENGTH = 65536  # entries waiting for the slack: over a minute of overruns at 1 kHz
# Failed sends recorded in one run of the daemon: about 1 s of a link down at 1 kHz (3
# sends a tick), 0.5 MB. A link down for longer (disarmed, nothing faults) would write
# ~2 GB an hour; past this the record ends there as for a full queue (``lost``).
MAX_SEND_FAILURES = 3000
SLACK_ENTRIES = 8  # written per slack


def _version() -> str:
    try:
        return importlib.metadata.version("rakectl")
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def sidecar_path(trace_path: str | Path) -> Path:
    """Where the inputs of the trace ``trace_path`` are written."""
    return Path(f"{trace_path}{SIDECAR_SUFFIX}")


def plain(value: Any) -> Any:
    """A settings value as JSON: sections as objects, enums as their values (pure)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, tuple | list):
        return [plain(item) for item in value]
    return value


def flat_settings(settings: Any) -> dict[str, Any]:
    """Every option of ``settings`` by its dotted name, JSON values (pure)."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for key, item in value.items():
                walk(f"{prefix}{key}.", item)
        else:
            out[prefix[:-1]] = value

    walk("", plain(settings))
    return out


def request_fields(request: Request) -> dict[str, Any]:
    """A validated request as a JSON object that decodes to it again."""
    return {"cmd": request.cmd.value, **{name: value.value if isinstance(value, enum.Enum)
                                         else value for name, value in request.args.items()}}


class InputLog:
    """The sidecar of a bus trace: entries queued where they happen, written in the slack."""

    def __init__(self, file: TextIO, queue_length: int = QUEUE_LENGTH) -> None:
        self._file = file
        self._queue: collections.deque[tuple[Any, ...]] = collections.deque()
        self._queue_length = queue_length
        self.lost = 0  # entries that found the queue full
        self._lost_written = 0
        self._complete_entries = 0  # entries before the first lost one
        self._send_failures = 0
        self.written = 0

    # ------------------------------------------------------------------ recording

    def start(self, frame: int, statuswords: tuple[int, int], settings: Any) -> None:
        """Bring-up ended (written at once: the loop has not started)."""
        self._write({"kind": "start", "format": FORMAT, "rakectl": _version(),
                     "frame": frame, "statuswords": list(statuswords),
                     "settings": flat_settings(settings)})
        self._file.flush()

    def command(self, after_tick: int, request: Request) -> None:
        """A request that changed something, taking effect after tick ``after_tick``."""
        self._append(("command", after_tick, request))

    def overrun(self, after_tick: int, skipped: int) -> None:
        """The tick after ``after_tick`` came ``skipped`` deadlines late (O(1))."""
        self._append(("overrun", after_tick, skipped))

    def heartbeat_lost(self, tick: int) -> None:
        """The heartbeat check of ``tick`` found a heartbeat too old (O(1))."""
        self._append(("heartbeat_lost", tick))

    def send_failed(self, tick: int, attempt: int, frame: int, msg: can.Message,
                    error: can.CanError) -> None:
        """Transmission ``attempt`` (of ``msg``) failed in ``tick`` (O(1): no formatting;
        past MAX_SEND_FAILURES, counted as lost)."""
        self._send_failures += 1
        if self._send_failures > MAX_SEND_FAILURES:
            self._lose()
            return
        self._append(("send_failed", tick, attempt, frame, msg.arbitration_id,
                      bytes(msg.data), error))

    def end(self, after_tick: int, reason: str, trace: TraceRecorder | None) -> None:
        """The loop ended after ``after_tick``; the trace's counts as they are now."""
        counts = (trace.recorded, trace.dropped, trace.first_dropped_at) if trace else (0, 0, -1)
        self._queue.append(("end", after_tick, reason, *counts))  # even past a loss

    def _append(self, entry: tuple[Any, ...]) -> None:
        if len(self._queue) >= self._queue_length or self.lost:
            self._lose()  # (once one is lost, the record is complete only up to it)
            return
        self._queue.append(entry)

    def _lose(self) -> None:
        if not self.lost:
            self._complete_entries = self.written + len(self._queue)
        self.lost += 1

    # ------------------------------------------------------------------ writing (slack)

    @property
    def pending(self) -> int:
        return len(self._queue)

    def drain(self, max_entries: int = SLACK_ENTRIES) -> int:
        """Write up to ``max_entries`` queued entries; returns how many were written."""
        queue = self._queue
        count = min(max_entries, len(queue))
        for _ in range(count):
            self._write(self._fields(queue.popleft()))
        if self.lost > self._lost_written and not queue:
            self._write({"kind": "lost", "entries": self.lost - self._lost_written,
                         "complete_entries": self._complete_entries})
            self._lost_written = self.lost
            count += 1
        if count:
            self._file.flush()  # a daemon that is killed leaves what was written
        return count

    def close(self) -> None:
        """Write everything still queued and close the file."""
        self.drain(len(self._queue))
        self._file.close()

    def _write(self, fields: dict[str, Any]) -> None:
        self._file.write(json.dumps(fields) + "\n")
        self.written += 1

    @staticmethod
    def _fields(entry: tuple[Any, ...]) -> dict[str, Any]:
        kind = entry[0]
        if kind == "command":
            return {"kind": kind, "after_tick": entry[1], "request": request_fields(entry[2])}
        if kind == "overrun":
            return {"kind": kind, "after_tick": entry[1], "skipped": entry[2]}
        if kind == "heartbeat_lost":
            return {"kind": kind, "tick": entry[1]}
        if kind == "send_failed":
            _, tick, attempt, frame, can_id, data, error = entry
            return {"kind": kind, "tick": tick, "attempt": attempt, "frame": frame,
                    "id": can_id, "data": data.hex(), "error": f"{type(error).__name__}: {error}"}
        _, after_tick, reason, frames, dropped, first_dropped_at = entry
        return {"kind": kind, "after_tick": after_tick, "reason": reason, "frames": frames,
                "dropped": dropped, "first_dropped_at": first_dropped_at}


def open_inputs(settings: BusSettings) -> InputLog | None:
    """The sidecar of ``settings.trace_path``; None without a trace."""
    if not settings.trace_path:
        return None
    path = sidecar_path(settings.trace_path)
    try:
        file = open(path, "w", encoding="utf-8")  # noqa: SIM115 (closed by InputLog.close)
    except OSError as error:
        raise BusError(f"bus.trace_path: cannot open the trace's inputs {str(path)!r}: "
                       f"{error}") from error
    return InputLog(file)
