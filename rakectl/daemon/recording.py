"""A recorded run, read: the frames of its bus trace and its inputs (pure reading, no bus).

A run recorded with ``bus.trace_path`` leaves the candump ``.log`` of every frame
the daemon sent and received (rakectl.drive.canbus) and its sidecar
``<trace>.inputs.jsonl`` (rakectl.daemon.inputs). :func:`frames_of` reads the
first a line at a time through python-can's ``CanutilsLogReader``,
:func:`read_inputs` the second, and :func:`check_settings` compares the
settings the run recorded with a replay's (rakectl.daemon.replay). Anything
missing, garbled or from another run raises :class:`TraceError` naming the file
and line.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import can

from rakectl.api.schema import Request, decode_request
from rakectl.config.settings import Settings
from rakectl.daemon.handlers import CHANGING
from rakectl.daemon.inputs import FORMAT, flat_settings
from rakectl.errors import ConfigError, TraceError

# Options that change nothing the loop sends: where things are, how the process is set up
# and the figures only the wall-clock checks before arming read (replayed as carried out).
UNCOMPARED = frozenset({
    "bus.interface", "bus.channel", "bus.bitrate", "bus.trace_path", "bus.trace_keep",
    "daemon.rt_priority",
    "daemon.cpu", "daemon.socket_path", "daemon.socket_group", "daemon.dump_dir",
    "daemon.recorder_s", "daemon.stats_interval_s", "daemon.startup_cyclictest_s",
    "daemon.arm_timing_s", "daemon.arm_max_latency_p99_us", "daemon.arm_max_late_share",
    "daemon.arm_max_latency_ratio"})


@dataclass(frozen=True)
class Frame:
    """One frame of the trace and the file line it is on (1-based)."""

    line: int
    msg: can.Message

    @property
    def rx(self) -> bool:
        return bool(self.msg.is_rx)


class _Lines:
    """A trace's lines as the text file python-can's reader iterates: each decoded and
    numbered here, so a bad byte is named with its own line; a last line with no end
    (a daemon killed while its writer held the rest) ends the trace."""

    def __init__(self, path: Path, file: BinaryIO) -> None:
        self._path, self._file = path, file
        self.number = 0  # the line last handed on (1-based)
        self.text = ""  # that line, stripped

    def __iter__(self) -> Iterator[str]:
        for number, raw in enumerate(self._file, 1):
            self.number = number
            if not raw.endswith(b"\n"):
                return  # cut short: the run's writer never finished this line
            try:
                line = raw.decode("ascii")
            except UnicodeDecodeError:
                raise TraceError(f"{self._path}, line {number}: not text") from None
            self.text = line.strip()
            yield line

    def close(self) -> None:
        self._file.close()


def frames_of(path: Path) -> Iterator[Frame]:
    """The frames of a candump ``-L`` log written by ``bus.trace_path``, in file order,
    read as they are needed (a trace of hours does not fit in memory); TraceError names
    the line of anything that is not such a frame."""
    try:
        file = open(path, "rb")  # noqa: SIM115 (closed by the reader's stop, below)
    except FileNotFoundError:
        raise TraceError(f"{path}: no such trace") from None
    except OSError as error:
        raise TraceError(f"{path}: cannot read the trace: {error}") from None
    lines = _Lines(path, file)
    reader = can.CanutilsLogReader(lines)  # type: ignore[arg-type]  # (iterated, closed)
    messages = iter(reader)
    try:
        while True:
            try:
                msg = next(messages)
            except StopIteration:
                return
            except TraceError:
                raise  # (a ValueError too) a line that is not text
            except (ValueError, IndexError, KeyError) as error:
                raise TraceError(f"{path}, line {lines.number}: not a candump -L frame "
                                 f"({type(error).__name__}: {error}): "
                                 f"{lines.text[:60]!r}") from None
            if lines.text[-2:] not in (" R", " T") and not msg.is_error_frame:
                raise TraceError(f"{path}, line {lines.number}: no direction (R or T) at the "
                                 f"end: {lines.text[:60]!r}; a trace of bus.trace_path marks "
                                 "each frame")
            yield Frame(lines.number, msg)
    except OSError as error:
        raise TraceError(f"{path}: cannot read the trace: {error}") from None
    finally:
        reader.stop()


@dataclass(frozen=True)
class Command:
    after_tick: int
    request: Request
    line: int


@dataclass(frozen=True)
class Overrun:
    after_tick: int
    skipped: int


@dataclass(frozen=True)
class SendFailure:
    tick: int
    attempt: int
    frame: int  # frames in the trace before it
    can_id: int
    data: bytes
    error: str


@dataclass(frozen=True)
class End:
    after_tick: int
    reason: str
    frames: int
    dropped: int
    first_dropped_at: int


@dataclass
class Inputs:
    """The sidecar, read: what the run's output depended on besides its frames."""

    path: Path
    start_frame: int
    statuswords: tuple[int, int]
    settings: dict[str, Any]
    version: str
    between_ticks: list[Command | Overrun]  # in the order they happened
    heartbeat_lost: frozenset[int]  # ticks
    failures: dict[int, SendFailure]  # by attempt
    end: End | None
    complete_until_tick: int | None  # entries were lost after this tick
    last_tick: int = 0  # the tick of the last entry


MAX_COUNT = 2 ** 53  # ticks, frames, attempts: far beyond any run


def _int(entry: dict[str, Any], key: str, where: str, minimum: int = 0) -> int:
    value = entry.get(key)
    if (isinstance(value, bool) or not isinstance(value, int) or value < minimum
            or value > MAX_COUNT):
        shown = json.dumps(value) if not isinstance(value, int) or abs(value) < 10 ** 20 \
            else "a huge integer"
        raise TraceError(f"{where}: {key!r} must be an integer from {minimum} to 2**53, "
                         f"got {shown}")
    return value


def _text(entry: dict[str, Any], key: str, where: str) -> str:
    value = entry.get(key)
    if not isinstance(value, str):
        raise TraceError(f"{where}: {key!r} must be a string, got {json.dumps(value)}")
    return value


def _entries(path: Path) -> Iterator[tuple[str, dict[str, Any]]]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TraceError(f"{path}: no such file: the trace's inputs (written next to "
                         "the trace while bus.trace_path is set) are needed to replay it") from None
    except (OSError, UnicodeDecodeError) as error:
        raise TraceError(f"{path}: cannot read the trace's inputs: {error}") from None
    for number, line in enumerate(text.splitlines(), 1):
        where = f"{path}, line {number}"
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as error:
            raise TraceError(f"{where}: not JSON ({error.msg} at column {error.colno})") from None
        except (ValueError, RecursionError) as error:  # integers too long, nesting too deep
            raise TraceError(f"{where}: not an entry of the trace's inputs "
                             f"({type(error).__name__})") from None
        if not isinstance(entry, dict) or not isinstance(entry.get("kind"), str):
            raise TraceError(f"{where}: not an entry of the trace's inputs (no \"kind\")")
        yield where, entry


def read_inputs(path: Path) -> Inputs:
    """The sidecar at ``path``; TraceError naming the line of anything wrong."""
    entries = list(_entries(path))
    if not entries or entries[0][1]["kind"] != "start":
        raise TraceError(f"{path}: no start entry: the run ended before its bring-up did, "
                         "or this is not a trace's inputs file")
    where, start = entries[0]
    if start.get("format") != FORMAT:
        raise TraceError(f"{where}: format {json.dumps(start.get('format'))}, this rakectl "
                         f"reads format {FORMAT}")
    words = start.get("statuswords")
    if not (isinstance(words, list) and len(words) == 2
            and all(isinstance(w, int) and 0 <= w <= 0xFFFFFFFF for w in words)):
        raise TraceError(f"{where}: 'statuswords' must be two integers in 0 … 0xFFFFFFFF "
                         "(CiA 402 statuswords, or a Roboteq-class drive's flags)")
    settings = start.get("settings")
    if not isinstance(settings, dict):
        raise TraceError(f"{where}: 'settings' must be an object")
    inputs = Inputs(path, _int(start, "frame", where), (words[0], words[1]), settings,
                    str(start.get("rakectl", "?")), [], frozenset(), {}, None, None)
    lost: set[int] = set()
    last_tick = 0
    ticks_of_lines = [0]  # the tick each entry was recorded at, by entry (start: 0)
    for where, entry in entries[1:]:
        kind = entry["kind"]
        if inputs.end is not None and kind != "lost":  # (a loss is written when it can be)
            raise TraceError(f"{where}: an entry after the end entry")
        if kind == "command":
            after = _int(entry, "after_tick", where)
            fields = entry.get("request")
            request = decode_request(json.dumps(fields).encode()) if isinstance(
                fields, dict) else None
            if not isinstance(request, Request):
                raise TraceError(f"{where}: not a request of the API: "
                                 f"{request.error if request else json.dumps(fields)}")
            if request.cmd not in CHANGING:  # (the daemon records no other: never replayed)
                raise TraceError(f"{where}: {request.cmd.value!r} is not a command a run "
                                 "records")
            inputs.between_ticks.append(Command(after, request, int(where.rsplit(" ", 1)[1])))
        elif kind == "overrun":
            after = _int(entry, "after_tick", where)
            inputs.between_ticks.append(Overrun(after, _int(entry, "skipped", where, 1)))
        elif kind == "heartbeat_lost":
            after = _int(entry, "tick", where, 1)
            lost.add(after)
        elif kind == "send_failed":
            after = _int(entry, "tick", where)
            try:
                data = bytes.fromhex(_text(entry, "data", where))
            except ValueError:
                raise TraceError(f"{where}: 'data' must be hex bytes") from None
            failure = SendFailure(after, _int(entry, "attempt", where),
                                  _int(entry, "frame", where), _int(entry, "id", where),
                                  data, _text(entry, "error", where))
            inputs.failures[failure.attempt] = failure
        elif kind == "lost":
            complete = _int(entry, "complete_entries", where, 1)
            tick = ticks_of_lines[min(complete, len(ticks_of_lines)) - 1]
            if inputs.complete_until_tick is None:
                inputs.complete_until_tick = tick
            continue
        elif kind == "end":
            after = _int(entry, "after_tick", where)
            inputs.end = End(after, _text(entry, "reason", where), _int(entry, "frames", where),
                             _int(entry, "dropped", where),
                             _int(entry, "first_dropped_at", where, -1))
        else:
            raise TraceError(f"{where}: unknown entry kind {json.dumps(kind)}")
        if after < last_tick and kind in ("command", "overrun", "end"):
            raise TraceError(f"{where}: tick {after} comes after tick {last_tick}: "
                             "the entries are out of order")
        if kind in ("command", "overrun", "end"):
            last_tick = after
        ticks_of_lines.append(after)
    inputs.heartbeat_lost = frozenset(lost)
    inputs.last_tick = max(ticks_of_lines)
    return inputs


def check_settings(recorded: dict[str, Any], settings: Settings, path: Path) -> None:
    """ConfigError naming the first option (that changes what the loop sends) whose value
    differs from the run's; options only one side knows are not compared."""
    here = json.loads(json.dumps(flat_settings(settings)))
    for key in sorted(recorded.keys() & here.keys() - UNCOMPARED):
        if recorded[key] != here[key]:
            raise ConfigError(
                f"replay: {key} is {json.dumps(here[key])} here but was "
                f"{json.dumps(recorded[key])} in the run ({path}): replay with the daemon's "
                "own --config and --set")


__all__ = ["MAX_COUNT", "UNCOMPARED", "Command", "End", "Frame", "Inputs", "Overrun",
           "SendFailure", "check_settings", "frames_of", "read_inputs"]
