"""The daemon's command API: its schema and its requests on the wire (pure; the
replies are :mod:`rakectl.api.replies`).

One JSON object per line (UTF-8) each way. A request is ``{"cmd": NAME, ARG: VALUE …}``
with an optional ``"id"`` (string or integer) that the reply echoes; a reply is
``{"ok": true, …}`` or ``{"ok": false, "error": "<one sentence>"}``. Commands and
their arguments are declared once, in :data:`COMMANDS`: validation and
:func:`rakectl.cli.docs.api_reference` both read that table. A request that fails
validation never reaches the handler.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import json
import math
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rakectl.config.declare import Bounds
from rakectl.config.settings import LaneSettings

MAX_REQUEST_BYTES = 4096  # one request line, without its newline
DEAD_MAN_PERIOD_S = 0.1  # a jog is repeated this often while it should go on
JOG_SPEED_LIMIT_M_PER_S = 0.25
JOG_RATE_LIMIT_RAD_PER_S = 0.5
SOCKET_NAME = "rakectl.sock"
SOCKET_ENV = "RAKECTL_SOCKET"
SERVICE_RUNTIME_DIR = Path("/run/rakectl")  # systemd's RuntimeDirectory=rakectl
ID_MAX_CHARS = 128
MAX_REPLY_BYTES = 1 << 20  # the client's limit on one reply line


# --------------------------------------------------------------------------- schema (pure)


class ApiCommand(enum.StrEnum):
    STATUS = "status"
    ARM = "arm"
    DISARM = "disarm"
    STOP = "stop"
    ESTOP = "estop"
    RESET = "reset"
    DUMP = "dump"
    JOG = "jog"
    EXCAVATE = "excavate"
    TIMING_RESET = "timing_reset"
    SHUTDOWN = "shutdown"


class JogSpace(enum.StrEnum):
    TASK = "task"  # velocities of the rake's tip: reach (horizontal) and height
    JOINT = "joint"  # velocities of the joints r and θ


class ArgKind(enum.StrEnum):
    NUMBER = "number"  # a finite JSON number, given to the handler as float
    STRING = "string"


ArgValue = float | str


@dataclass(frozen=True)
class Arg:
    """One argument of a command, declared once for validation and the reference."""

    name: str
    kind: ArgKind
    doc: str
    unit: str = ""
    bounds: Bounds = Bounds()
    required: bool = False
    default: float | None = None  # given to the handler when the argument is absent
    choices: type[enum.StrEnum] | None = None  # the handler gets the enum member
    only_with: tuple[str, str] | None = None  # (argument, value): allowed only then
    max_chars: int = 1024


@dataclass(frozen=True)
class CommandSpec:
    command: ApiCommand
    doc: str
    args: tuple[Arg, ...] = ()
    check: Callable[[Mapping[str, ArgValue]], str | None] | None = None  # across arguments


def _lane_arg(name: str, required: bool) -> Arg:
    """An excavate argument declared by the lane option of the same name in settings."""
    meta = {f.name: f for f in dataclasses.fields(LaneSettings)}[name].metadata
    doc = meta["doc"] if required else f"{meta['doc']} Default: the configured lane.{name}."
    if name in ("depth_step_m", "stroke_speed_m_per_s"):
        doc += f" On an adaptive lane, at most lane.max_{name}."
    return Arg(name, ArgKind.NUMBER, doc, meta["unit"], meta["bounds"], required=required)


def _jog_arg(name: str, unit: str, limit: float, space: JogSpace, doc: str) -> Arg:
    return Arg(name, ArgKind.NUMBER, doc, unit, Bounds(ge=-limit, le=limit), default=0.0,
               only_with=("space", space.value))


def _far_beyond_near(args: Mapping[str, ArgValue]) -> str | None:
    far, near = args["reach_far_m"], args["reach_near_m"]
    if isinstance(far, float) and isinstance(near, float) and not far > near:
        return f"reach_far_m must be > reach_near_m ({near:g}), got {far:g}"
    return None


_SPECS = (
    CommandSpec(ApiCommand.STATUS, "The daemon's state, pose and counters (changes nothing)."),
    CommandSpec(ApiCommand.ARM, "Enable the drives and hold the present pose; the first time "
                "after start-up through the weight check (state `checking`, about 3 s: the tip "
                "lifted 20 mm and lowered back; a mismatch with the configured weight faults) "
                "and, with `selftest.press`, the tine-mount check (the tines pressed on the "
                "anvil and brought back, up to a minute; a mount stiffer or softer than "
                "configured faults)."),
    CommandSpec(ApiCommand.DISARM, "Stop any motion and disable the drives."),
    CommandSpec(ApiCommand.STOP, "Stop the jog or excavation and hold the pose; stays armed."),
    CommandSpec(ApiCommand.ESTOP, "Emergency stop: quick-stop both drives now and latch it "
                "until a `reset` asked after it (one asked before, still waiting for a fault's "
                "cause to clear, is called off; the fault's cause stays named)."),
    CommandSpec(ApiCommand.RESET, "Clear a latched emergency stop or fault; stays disarmed. "
                "It ends once no drive problem is left and no sooner than 30 loop periods (at "
                "the robot's 1 kHz a SYNC producer of 100 Hz or more still on the bus shows "
                "within them; a slower one faults the daemon again once more than 10 "
                "answers are extra); after 1 s, `reset failed` naming what is left."),
    CommandSpec(ApiCommand.DUMP, "Write the flight recorder's recent history to a file.", (
        Arg("path", ArgKind.STRING, "File to write, on the daemon's machine. Default: a new "
            "file in the daemon's state directory."),)),
    CommandSpec(ApiCommand.JOG, "Move at the given velocities while the requests keep coming: "
                f"repeat it every {DEAD_MAN_PERIOD_S:g} s (dead-man); the daemon stops "
                "when they stop. Absent velocities are 0. The jog belongs to the connection "
                "that started it: another connection's jog is refused while that one is open, "
                "and once the jog has ended (a stop, the force limit, the dead-man) its "
                "connection's next jog is refused, naming why, while that connection stays "
                "open; a new connection starts a new jog.", (
        Arg("space", ArgKind.STRING, "task: tip velocities; joint: joint velocities.",
            required=True, choices=JogSpace),
        _jog_arg("reach_m_per_s", "m/s", JOG_SPEED_LIMIT_M_PER_S, JogSpace.TASK,
                 "Horizontal tip velocity, positive away from the robot."),
        _jog_arg("height_m_per_s", "m/s", JOG_SPEED_LIMIT_M_PER_S, JogSpace.TASK,
                 "Vertical tip velocity, positive up."),
        _jog_arg("r_m_per_s", "m/s", JOG_SPEED_LIMIT_M_PER_S, JogSpace.JOINT,
                 "Velocity of the sliding joint r, positive extending."),
        _jog_arg("theta_rad_per_s", "rad/s", JOG_RATE_LIMIT_RAD_PER_S, JogSpace.JOINT,
                 "Velocity of the rotary joint θ, positive lowering the rake."),
    )),
    CommandSpec(ApiCommand.EXCAVATE, "Rake a lane: contact strokes from reach_far_m to "
                "reach_near_m, deeper each cycle down to target_depth_m. Refused during a "
                "jog or another lane: `stop` first.", (
        _lane_arg("reach_far_m", True), _lane_arg("reach_near_m", True),
        _lane_arg("target_depth_m", True), _lane_arg("depth_step_m", False),
        _lane_arg("stroke_speed_m_per_s", False),
    ), _far_beyond_near),
    CommandSpec(ApiCommand.TIMING_RESET, "Start the loop's timing statistics afresh (benchmarks)."),
    CommandSpec(ApiCommand.SHUTDOWN, "Stop, disarm and end the daemon (tests and bench set-ups; "
                "under systemd use `systemctl stop rakectl`). Needs the same credentials as "
                "every command."),
)
COMMANDS: Mapping[ApiCommand, CommandSpec] = types.MappingProxyType(
    {spec.command: spec for spec in _SPECS})
_KNOWN = ", ".join(COMMANDS)


@dataclass(frozen=True)
class Peer:
    """Credentials of the process at the other end of a connection (SO_PEERCRED)."""

    pid: int
    uid: int
    gid: int
    groups: frozenset[int] = frozenset()


@dataclass(frozen=True)
class Request:
    """A validated request: every argument checked, defaults filled in."""

    cmd: ApiCommand
    args: Mapping[str, ArgValue] = field(default_factory=lambda: types.MappingProxyType({}))
    id: str | int | None = None
    client: int = 0  # serial number of the connection; 0: not from a socket
    peer: Peer | None = None

    def number(self, name: str) -> float | None:
        value = self.args.get(name)
        return value if isinstance(value, float) else None

    def text(self, name: str) -> str | None:
        value = self.args.get(name)
        return value if isinstance(value, str) else None


class ErrorKind(enum.StrEnum):
    TOO_LARGE = "too_large"  # a request line over MAX_REQUEST_BYTES
    MALFORMED = "malformed"  # not UTF-8, or not JSON
    INVALID = "invalid"  # JSON, but not a request of the schema
    REJECTED = "rejected"  # the handler refused it (raised a RakeError)
    INTERNAL = "internal"  # the handler crashed or returned an unusable reply
    PERMISSION = "permission"  # a peer without the credentials was turned away
    BUSY = "busy"  # a peer beyond the client limit was turned away
    SLOW = "slow"  # a client that did not read its replies was dropped
    IDLE = "idle"  # a silent client was closed after the idle timeout
    SOCKET = "socket"  # an OS error on accept, recv or send


@dataclass(frozen=True)
class Refusal:
    """Why a request line was refused; ``error`` is the reply's sentence."""

    kind: ErrorKind
    error: str
    id: str | int | None = None


_MISSING = object()


class _Invalid(Exception):
    def __init__(self, kind: ErrorKind, error: str) -> None:
        super().__init__(error)
        self.kind, self.error = kind, error


def too_large_message(size_bytes: int, complete: bool = True) -> str:
    size = f"{size_bytes} bytes" if complete else f"at least {size_bytes} bytes"
    return f"request too large ({size}, limit {MAX_REQUEST_BYTES})"


def decode_request(line: bytes, client: int = 0, peer: Peer | None = None) -> Request | Refusal:
    """A request line (without its newline) as a validated Request, or why not (pure)."""
    if len(line) > MAX_REQUEST_BYTES:
        return Refusal(ErrorKind.TOO_LARGE, too_large_message(len(line)))
    request_id: str | int | None = None
    try:
        obj = _parse(line)
        request_id = _request_id(obj.pop("id", None))
        spec = _spec(obj.pop("cmd", _MISSING))
        args = _validate(spec, obj)
    except _Invalid as exc:
        return Refusal(exc.kind, exc.error, request_id)
    return Request(spec.command, types.MappingProxyType(args), request_id, client, peer)


def show(value: Any) -> str:
    """A value as an error names it: its JSON, cut at 40 characters; a container nested
    too deeply for the encoder (a request line can nest about 2000 deep) by its kind."""
    try:
        text = json.dumps(value)
    except (RecursionError, ValueError, TypeError):
        kind = "an array" if isinstance(value, list) else \
            "an object" if isinstance(value, dict) else "a value"
        text = f"{kind} nested too deeply to show"
    return text if len(text) <= 40 else text[:39] + "…"


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj: dict[str, Any] = {}
    for key, item in pairs:
        if key in obj:
            raise _Invalid(ErrorKind.MALFORMED, f"malformed JSON: key {show(key)} is given twice")
        obj[key] = item
    return obj


_DECODER = json.JSONDecoder(object_pairs_hook=_unique_keys)


def _parse(line: bytes) -> dict[str, Any]:
    try:
        obj = _DECODER.decode(line.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise _Invalid(ErrorKind.MALFORMED, f"request is not UTF-8 (byte 0x{line[exc.start]:02x}"
                       f" at offset {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise _Invalid(ErrorKind.MALFORMED,
                       f"malformed JSON: {exc.msg} at column {exc.colno}") from None
    except RecursionError:
        raise _Invalid(ErrorKind.MALFORMED, "malformed JSON: nested too deeply") from None
    except ValueError as exc:
        raise _Invalid(ErrorKind.MALFORMED, f"malformed JSON: {exc}") from None
    if not isinstance(obj, dict):
        names = {list: "an array", str: "a string", bool: "a boolean", type(None): "null"}
        raise _Invalid(ErrorKind.INVALID,
                       f"a request must be a JSON object, got {names.get(type(obj), 'a number')}")
    return obj


def _request_id(value: Any) -> str | int | None:
    ok = value is None or (isinstance(value, int) and not isinstance(value, bool)) or (
        isinstance(value, str) and len(value) <= ID_MAX_CHARS)
    if not ok:
        raise _Invalid(ErrorKind.INVALID, f'"id" must be an integer or a string of at most '
                       f"{ID_MAX_CHARS} characters, got {show(value)}")
    return value  # type: ignore[no-any-return]


def _suggest(word: str, known: list[str]) -> str:
    """A known name close to ``word``; also one it begins (a name without its unit)."""
    close = [name for name in known if word and name.startswith(word + "_")]
    close = close or difflib.get_close_matches(word, known, n=1)
    return f" (did you mean {close[0]}?)" if close else ""


def _spec(cmd: Any) -> CommandSpec:
    if cmd is _MISSING:
        raise _Invalid(ErrorKind.INVALID, f'a request needs "cmd", one of: {_KNOWN}')
    if not isinstance(cmd, str) or cmd not in COMMANDS:
        hint = _suggest(cmd, list(COMMANDS)) if isinstance(cmd, str) else ""
        raise _Invalid(ErrorKind.INVALID,
                       f"unknown command {show(cmd)}{hint}; known commands: {_KNOWN}")
    return COMMANDS[ApiCommand(cmd)]


def _validate(spec: CommandSpec, given: Mapping[str, Any]) -> dict[str, ArgValue]:
    known = {arg.name: arg for arg in spec.args}
    for name in given:
        if name not in known:
            takes = ", ".join(known) or "no arguments"
            raise _Invalid(ErrorKind.INVALID, f"{spec.command}: unknown argument {show(name)}"
                           f"{_suggest(name, list(known))}; {spec.command} takes {takes}")
    args: dict[str, ArgValue] = {}
    for arg in spec.args:
        _raise_if(spec, _take(arg, given, args))
    _raise_if(spec, spec.check(args) if spec.check is not None else None)
    return args


def _raise_if(spec: CommandSpec, problem: str | None) -> None:
    if problem is not None:
        raise _Invalid(ErrorKind.INVALID, f"{spec.command}: {problem}")


def _take(arg: Arg, given: Mapping[str, Any], args: dict[str, ArgValue]) -> str | None:
    """Check one argument into ``args``; why it is wrong, or None."""
    active = arg.only_with is None or args.get(arg.only_with[0]) == arg.only_with[1]
    if arg.name not in given:
        if active and arg.required:
            return f"{arg.name} is required"
        if active and arg.default is not None:
            args[arg.name] = arg.default
        return None
    if not active and arg.only_with is not None:
        return f"{arg.name} is only allowed with {arg.only_with[0]}={arg.only_with[1]}"
    value, problem = _coerce(arg, given[arg.name])
    if problem is None:
        args[arg.name] = value
    return problem


def _coerce(arg: Arg, value: Any) -> tuple[ArgValue, str | None]:
    if arg.kind is ArgKind.NUMBER:
        if isinstance(value, bool) or not isinstance(value, int | float):
            return 0.0, f"{arg.name} must be a number, got {show(value)}"
        try:
            number = float(value)
        except OverflowError:  # an integer beyond the float range
            number = math.inf
        problem = arg.bounds.violation(number)
        return number, f"{arg.name} {problem}" if problem else None
    if not isinstance(value, str):
        return "", f"{arg.name} must be a string, got {show(value)}"
    if arg.choices is not None:
        if value not in arg.choices.__members__.values():
            return "", f"{arg.name} must be one of {', '.join(arg.choices)}, got {show(value)}"
        return arg.choices(value), None
    if not value or "\0" in value or len(value) > arg.max_chars:
        return "", (f"{arg.name} must be a non-empty string of at most {arg.max_chars} "
                    f"characters without NUL, got {show(value)}")
    return value, None


Handler = Callable[[Request], Mapping[str, Any]]


