"""The daemon's command API on a Unix socket: schema, non-blocking server, client.

One JSON object per line (UTF-8) each way. A request is ``{"cmd": NAME, ARG: VALUE …}``
with an optional ``"id"`` (string or integer) that the reply echoes; a reply is
``{"ok": true, …}`` or ``{"ok": false, "error": "<one sentence>"}``. Commands and
their arguments are declared once, in :data:`COMMANDS`: validation and
:func:`api_reference` both read that table. A request that fails validation never
reaches the handler.

The 1 kHz loop owns the server's thread: it calls :meth:`CommandServer.poll` in the
slack of a tick with a time budget, and poll never blocks.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import difflib
import enum
import grp
import json
import math
import os
import pwd
import select
import socket
import stat
import struct
import time
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rakectl.config.declare import Bounds
from rakectl.config.settings import LaneSettings
from rakectl.errors import ApiError, CommandRejected, DaemonUnreachable, RakeError

MAX_REQUEST_BYTES = 4096  # one request line, without its newline
MAX_CLIENTS = 16
MAX_BACKLOG_BYTES = 256 * 1024  # replies queued for a client that does not read them
IDLE_TIMEOUT_S = 60.0  # a client silent this long is closed
DEAD_MAN_PERIOD_S = 0.1  # a jog is repeated this often while it should go on
JOG_SPEED_LIMIT_M_PER_S = 0.25
JOG_RATE_LIMIT_RAD_PER_S = 0.5
SOCKET_NAME = "rakectl.sock"
SOCKET_ENV = "RAKECTL_SOCKET"
SERVICE_RUNTIME_DIR = Path("/run/rakectl")  # systemd's RuntimeDirectory=rakectl
_RECV_BYTES = 8192
_ID_MAX_CHARS = 128
_MAX_REPLY_BYTES = 1 << 20  # the client's limit on one reply line
_SO_PEERGROUPS = getattr(socket, "SO_PEERGROUPS", 59)  # Linux >= 4.13; 59 in asm-generic
_POLLIN = select.POLLIN
_POLLOUT = select.POLLOUT


# --------------------------------------------------------------------------- schema (pure)


class Command(enum.StrEnum):
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
    command: Command
    doc: str
    args: tuple[Arg, ...] = ()
    check: Callable[[Mapping[str, ArgValue]], str | None] | None = None  # across arguments


def _lane_arg(name: str, required: bool) -> Arg:
    """An excavate argument declared by the lane option of the same name in settings."""
    meta = {f.name: f for f in dataclasses.fields(LaneSettings)}[name].metadata
    doc = meta["doc"] if required else f"{meta['doc']} Default: the configured lane.{name}."
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
    CommandSpec(Command.STATUS, "The daemon's state, pose and counters (changes nothing)."),
    CommandSpec(Command.ARM, "Enable the drives and hold the present pose."),
    CommandSpec(Command.DISARM, "Stop any motion and disable the drives."),
    CommandSpec(Command.STOP, "Stop the jog or excavation and hold the pose; stays armed."),
    CommandSpec(Command.ESTOP, "Emergency stop: quick-stop both drives now and latch it "
                "until `reset`."),
    CommandSpec(Command.RESET, "Clear a latched emergency stop or fault; stays disarmed."),
    CommandSpec(Command.DUMP, "Write the flight recorder's recent history to a file.", (
        Arg("path", ArgKind.STRING, "File to write, on the daemon's machine. Default: a new "
            "file in the daemon's state directory."),)),
    CommandSpec(Command.JOG, "Move at the given velocities while the requests keep coming: "
                f"repeat it every {DEAD_MAN_PERIOD_S:g} s (dead-man); the daemon stops "
                "when they stop. Absent velocities are 0.", (
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
    CommandSpec(Command.EXCAVATE, "Rake a lane: contact strokes from reach_far_m to "
                "reach_near_m, deeper each cycle down to target_depth_m.", (
        _lane_arg("reach_far_m", True), _lane_arg("reach_near_m", True),
        _lane_arg("target_depth_m", True), _lane_arg("depth_step_m", False),
        _lane_arg("stroke_speed_m_per_s", False),
    ), _far_beyond_near),
    CommandSpec(Command.TIMING_RESET, "Start the loop's timing statistics afresh (benchmarks)."),
    CommandSpec(Command.SHUTDOWN, "Stop, disarm and end the daemon (tests and bench set-ups; "
                "under systemd use `systemctl stop rakectl`). Needs the same credentials as "
                "every command."),
)
COMMANDS: Mapping[Command, CommandSpec] = types.MappingProxyType(
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

    cmd: Command
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


def _show(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:39] + "…"


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj: dict[str, Any] = {}
    for key, item in pairs:
        if key in obj:
            raise _Invalid(ErrorKind.MALFORMED, f"malformed JSON: key {_show(key)} is given twice")
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
        isinstance(value, str) and len(value) <= _ID_MAX_CHARS)
    if not ok:
        raise _Invalid(ErrorKind.INVALID, f'"id" must be an integer or a string of at most '
                       f"{_ID_MAX_CHARS} characters, got {_show(value)}")
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
                       f"unknown command {_show(cmd)}{hint}; known commands: {_KNOWN}")
    return COMMANDS[Command(cmd)]


def _validate(spec: CommandSpec, given: Mapping[str, Any]) -> dict[str, ArgValue]:
    known = {arg.name: arg for arg in spec.args}
    for name in given:
        if name not in known:
            takes = ", ".join(known) or "no arguments"
            raise _Invalid(ErrorKind.INVALID, f"{spec.command}: unknown argument {_show(name)}"
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
            return 0.0, f"{arg.name} must be a number, got {_show(value)}"
        try:
            number = float(value)
        except OverflowError:  # an integer beyond the float range
            number = math.inf
        problem = arg.bounds.violation(number)
        return number, f"{arg.name} {problem}" if problem else None
    if not isinstance(value, str):
        return "", f"{arg.name} must be a string, got {_show(value)}"
    if arg.choices is not None:
        if value not in arg.choices.__members__.values():
            return "", f"{arg.name} must be one of {', '.join(arg.choices)}, got {_show(value)}"
        return arg.choices(value), None
    if not value or "\0" in value or len(value) > arg.max_chars:
        return "", (f"{arg.name} must be a non-empty string of at most {arg.max_chars} "
                    f"characters without NUL, got {_show(value)}")
    return value, None


def api_reference() -> str:
    """Markdown reference of the protocol and every command, from :data:`COMMANDS`."""
    lines = [
        "One JSON object per line, UTF-8, on the Unix socket (default "
        f"`{SERVICE_RUNTIME_DIR / SOCKET_NAME}` for the service). Request: "
        '`{"cmd": "<command>", <arguments>…}`, optionally with `"id"` (an integer or a string), '
        'echoed in the reply. Reply: `{"ok": true, …}` or `{"ok": false, "error": "…"}`. '
        f"A request is at most {MAX_REQUEST_BYTES} bytes; a larger one is answered with an "
        "error and the connection is closed. An invalid request changes nothing. Peers must be "
        "root, the daemon's user or members of the socket's group.", "",
        "| command | arguments | meaning |", "|---|---|---|",
    ]
    for spec in COMMANDS.values():
        args = ", ".join(f"`{a.name}`" if a.required else f"[`{a.name}`]" for a in spec.args)
        lines.append(f"| `{spec.command}` | {args or '—'} | {spec.doc} |")
    for spec in COMMANDS.values():
        if spec.args:
            lines += ["", f"#### `{spec.command}`", "", spec.doc, "", *_arg_table(spec.args)]
    return "\n".join(lines)


def _arg_table(args: tuple[Arg, ...]) -> list[str]:
    rows = ["| argument | type | required | unit | bounds | meaning |", "|---|---|---|---|---|---|"]
    for a in args:
        kind = " \\| ".join(f"`{c}`" for c in a.choices) if a.choices else a.kind.value
        need = "yes" if a.required else (f"no (default {a.default:g})"
                                        if a.default is not None else "no")
        when = f" Only with {a.only_with[0]}={a.only_with[1]}." if a.only_with else ""
        rows.append(f"| `{a.name}` | {kind} | {need} | {a.unit} | {a.bounds.describe()} "
                    f"| {a.doc}{when} |")
    return rows


# --------------------------------------------------------------------------- credentials, paths


def peer_allowed(peer: Peer, daemon_uid: int, socket_gid: int) -> bool:
    """Root, the daemon's own user, or a member of the socket's group (pure)."""
    return peer.uid in (0, daemon_uid) or peer.gid == socket_gid or socket_gid in peer.groups


def _peer(sock: socket.socket) -> Peer:
    pid, uid, gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                        struct.calcsize("3i")))
    try:  # the peer process's own groups at connect time, as the kernel saw them
        raw = sock.getsockopt(socket.SOL_SOCKET, _SO_PEERGROUPS, 1024)  # Python: <= 1024
        groups = frozenset(struct.unpack(f"{len(raw) // 4}I", raw))
    except OSError:  # older kernel: the group database
        try:
            groups = frozenset(os.getgrouplist(pwd.getpwuid(uid).pw_name, gid))
        except KeyError:
            groups = frozenset()
    return Peer(pid, uid, gid, groups)


def default_socket_path(environ: Mapping[str, str] | None = None) -> Path:
    """Where the daemon listens when nobody says otherwise.

    The service's ``$RUNTIME_DIRECTORY`` (set by systemd), else /run/rakectl when the
    service has created it, else ``$XDG_RUNTIME_DIR/rakectl``, else ``/tmp/rakectl-<uid>``.
    """
    env = os.environ if environ is None else environ
    runtime = env.get("RUNTIME_DIRECTORY", "").split(":")[0]
    if runtime:
        return Path(runtime) / SOCKET_NAME
    if SERVICE_RUNTIME_DIR.is_dir():
        return SERVICE_RUNTIME_DIR / SOCKET_NAME
    xdg = env.get("XDG_RUNTIME_DIR", "")
    if xdg.startswith("/"):
        return Path(xdg) / "rakectl" / SOCKET_NAME
    return Path(f"/tmp/rakectl-{os.geteuid()}") / SOCKET_NAME


def socket_path(explicit: str | Path | None = None,
                environ: Mapping[str, str] | None = None) -> Path:
    """The explicit path, else ``$RAKECTL_SOCKET``, else :func:`default_socket_path`."""
    env = os.environ if environ is None else environ
    if explicit:
        return Path(explicit)
    if env.get(SOCKET_ENV):
        return Path(env[SOCKET_ENV])
    return default_socket_path(env)


# --------------------------------------------------------------------------- replies


def _encode(message: Mapping[str, Any]) -> bytes:
    try:
        text = json.dumps(message, allow_nan=False, separators=(",", ":"))
    except ValueError:  # NaN or infinity: strict JSON has none, they go out as null
        text = json.dumps(_finite(message), separators=(",", ":"))
    return text.encode() + b"\n"


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def _sentence(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def error_reply(error: str, request_id: str | int | None = None) -> bytes:
    reply: dict[str, Any] = {"ok": False}
    if request_id is not None:
        reply["id"] = request_id
    reply["error"] = error
    return _encode(reply)


def ok_reply(payload: Mapping[str, Any], request_id: str | int | None = None) -> bytes:
    if not isinstance(payload, Mapping):
        raise TypeError(f"the handler returned {type(payload).__name__}, not a mapping")
    for key in ("ok", "id", "error"):
        if key in payload:
            raise ValueError(f"the handler's reply uses the reserved key {key!r}")
    head: dict[str, Any] = {"ok": True} if request_id is None else {"ok": True, "id": request_id}
    return _encode(head | dict(payload))


Handler = Callable[[Request], Mapping[str, Any]]


# --------------------------------------------------------------------------- server


@dataclass
class ServerStats:
    """Counters of the server; the daemon reads and logs them off the hot path."""

    requests: int = 0  # request lines answered, valid or not
    handled: int = 0  # requests that reached the handler
    accepted: int = 0  # connections admitted
    clients: int = 0  # connections open now
    errors: dict[ErrorKind, int] = field(default_factory=lambda: dict.fromkeys(ErrorKind, 0))


@dataclass(eq=False)
class _Conn:
    sock: socket.socket
    fd: int
    serial: int
    peer: Peer
    last_active_s: float
    inbuf: bytearray = field(default_factory=bytearray)  # an incomplete line
    lines: collections.deque[bytes | Refusal] = field(default_factory=collections.deque)
    outbuf: bytearray = field(default_factory=bytearray)
    closing: bool = False  # read no more; close once the replies are out
    blocked: bool = False  # the socket took only part of outbuf: wait for POLLOUT
    closed: bool = False


class CommandServer:
    """The daemon's end of the socket: non-blocking, polled by the control loop.

    ``handler`` gets each valid :class:`Request` and returns the reply's fields (a
    JSON-able mapping without "ok", "id" or "error"); to refuse it raises a
    :class:`~rakectl.errors.RakeError` whose message becomes the error reply. Any
    other exception is answered as an internal error and counted; the server goes on.
    Not thread-safe: the thread that polls it is the only one that touches it.
    """

    def __init__(self, path: Path, group: str | None, handler: Handler, *,
                 clock: Callable[[], float] = time.monotonic, max_clients: int = MAX_CLIENTS,
                 max_backlog_bytes: int = MAX_BACKLOG_BYTES,
                 idle_timeout_s: float = IDLE_TIMEOUT_S) -> None:
        self.path = Path(path)
        self.stats = ServerStats()
        self._handler, self._clock = handler, clock
        self._max_clients, self._max_backlog_bytes = max_clients, max_backlog_bytes
        self._idle_timeout_s = idle_timeout_s
        self._listener = _listen(self.path, group, max_clients)
        st = os.stat(self.path)
        self._identity, self._socket_gid = (st.st_dev, st.st_ino), st.st_gid
        self._group_name, self._uid = _group_name(st.st_gid), os.geteuid()
        self._poller = select.poll()
        self._poller.register(self._listener.fileno(), _POLLIN)
        self._listen_fd = self._listener.fileno()
        self._conns: dict[int, _Conn] = {}  # by file descriptor
        self._ready: collections.deque[_Conn] = collections.deque()  # with lines to answer
        self._dirty: list[_Conn] = []  # with replies to send
        self._serial = 0
        self._next_sweep_s = clock() + 1.0
        self._open = True

    def __enter__(self) -> CommandServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def poll(self, budget_s: float) -> int:
        """Accept, read, answer and write what fits in ``budget_s``; never blocks.

        Returns the number of request lines answered (valid or not).
        """
        deadline_s = self._clock() + budget_s
        for fd, events in self._poller.poll(0):
            if self._clock() >= deadline_s:
                break  # the events come back at the next poll
            if fd == self._listen_fd:
                self._accept()
            elif (conn := self._conns.get(fd)) is not None:
                self._on_events(conn, events)
        answered = self._answer_ready(deadline_s)
        for conn in self._dirty:
            self._flush(conn)
        self._dirty.clear()
        if self._clock() >= self._next_sweep_s:
            self._sweep()
        return answered

    def is_connected(self, client: int) -> bool:
        """Whether the connection ``Request.client`` came on is still open (dead-man)."""
        return any(conn.serial == client for conn in self._conns.values())

    def close(self) -> None:
        """Send what is queued if the sockets take it, close everything, remove the file."""
        if not self._open:
            return
        self._open = False
        for conn in list(self._conns.values()):
            with contextlib.suppress(OSError):
                conn.sock.send(conn.outbuf, socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL)
            self._close(conn)
        self._listener.close()
        with contextlib.suppress(OSError):
            st = os.lstat(self.path)
            if (st.st_dev, st.st_ino) == self._identity:
                os.unlink(self.path)

    # -- connections

    def _accept(self) -> None:
        for _ in range(4):  # a few per poll; the others wait in the listen backlog
            try:
                sock, _ = self._listener.accept()
            except BlockingIOError:
                return
            except OSError:
                self._count(ErrorKind.SOCKET)
                return
            self._admit(sock)

    def _admit(self, sock: socket.socket) -> None:
        try:
            sock.setblocking(False)
            peer = _peer(sock)
        except OSError:
            self._count(ErrorKind.SOCKET)
            sock.close()
            return
        if not peer_allowed(peer, self._uid, self._socket_gid):
            self._turn_away(sock, ErrorKind.PERMISSION, f"permission denied: uid {peer.uid} is "
                            f"not root, not the daemon's user and not in group {self._group_name}")
        elif len(self._conns) >= self._max_clients:
            self._turn_away(sock, ErrorKind.BUSY,
                            f"too many clients (limit {self._max_clients}); try again later")
        else:
            self._serial += 1
            conn = _Conn(sock, sock.fileno(), self._serial, peer, self._clock())
            self._conns[conn.fd] = conn
            self._poller.register(conn.fd, _POLLIN)
            self.stats.accepted += 1
            self.stats.clients = len(self._conns)

    def _turn_away(self, sock: socket.socket, kind: ErrorKind, error: str) -> None:
        self._count(kind)
        with contextlib.suppress(OSError):
            sock.send(error_reply(error), socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL)
        sock.close()

    def _close(self, conn: _Conn) -> None:
        if conn.closed:
            return
        conn.closed = True
        self._poller.unregister(conn.fd)
        del self._conns[conn.fd]
        conn.sock.close()
        self.stats.clients = len(self._conns)

    def _sweep(self) -> None:
        now_s = self._clock()
        self._next_sweep_s = now_s + 1.0
        for conn in list(self._conns.values()):
            if now_s - conn.last_active_s > self._idle_timeout_s:
                self._count(ErrorKind.IDLE)
                self._close(conn)

    def _watch(self, conn: _Conn) -> None:
        events = (0 if conn.closing else _POLLIN) | (_POLLOUT if conn.blocked else 0)
        self._poller.modify(conn.fd, events)

    # -- input

    def _on_events(self, conn: _Conn, events: int) -> None:
        if events & _POLLOUT:
            self._flush(conn)
        if conn.closed or conn.closing or conn.lines:
            return  # nothing more to read, or the lines read are not answered yet
        if events & (_POLLIN | select.POLLHUP | select.POLLERR):
            self._read(conn)
        elif events & select.POLLNVAL:
            self._close(conn)

    def _read(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(_RECV_BYTES)
        except BlockingIOError:
            return
        except OSError:
            self._count(ErrorKind.SOCKET)
            self._close(conn)
            return
        if not data:  # end of input: answer the complete lines, then close
            conn.closing, conn.inbuf = True, bytearray()
            self._watch(conn)
            if not conn.outbuf:
                self._close(conn)
            return
        conn.last_active_s = self._clock()
        conn.inbuf += data
        self._split(conn, b"\n" in data)

    def _split(self, conn: _Conn, newline: bool) -> None:
        if newline:
            *complete, conn.inbuf = conn.inbuf.split(b"\n")
            conn.lines.extend(bytes(line) for line in complete if line.strip())
        if len(conn.inbuf) > MAX_REQUEST_BYTES:
            too_large = too_large_message(len(conn.inbuf), complete=False)
            conn.lines.append(Refusal(ErrorKind.TOO_LARGE, too_large))
            conn.inbuf, conn.closing = bytearray(), True
            self._watch(conn)
        if conn.lines:
            self._ready.append(conn)

    # -- answers

    def _answer_ready(self, deadline_s: float) -> int:
        answered = 0
        while self._ready and self._clock() < deadline_s:
            conn = self._ready.popleft()
            if conn.closed or not conn.lines:
                continue
            self._answer(conn, conn.lines.popleft())
            answered += 1
            if conn.lines and not conn.closed:
                self._ready.append(conn)  # one line per client per turn: a flood waits
        return answered

    def _answer(self, conn: _Conn, line: bytes | Refusal) -> None:
        result = line if isinstance(line, Refusal) else decode_request(line, conn.serial, conn.peer)
        self.stats.requests += 1
        if isinstance(result, Refusal):
            self._count(result.kind)
            if result.kind is ErrorKind.TOO_LARGE:  # answer, then close the connection
                conn.lines.clear()
                conn.closing = True
                self._watch(conn)
            self._queue(conn, error_reply(result.error, result.id))
        else:
            self.stats.handled += 1
            self._queue(conn, self._call(result))

    def _call(self, request: Request) -> bytes:
        try:
            return ok_reply(self._handler(request), request.id)
        except RakeError as exc:
            self._count(ErrorKind.REJECTED)
            return error_reply(_sentence(exc), request.id)
        except Exception as exc:  # a bug in the handler must not end the server
            self._count(ErrorKind.INTERNAL)
            error = f"internal error: {type(exc).__name__}: {_sentence(exc)}"
            return error_reply(error, request.id)

    def _count(self, kind: ErrorKind) -> None:
        self.stats.errors[kind] += 1

    # -- output

    def _queue(self, conn: _Conn, reply: bytes) -> None:
        if not conn.outbuf:
            self._dirty.append(conn)
        conn.outbuf += reply
        if len(conn.outbuf) > self._max_backlog_bytes:
            self._count(ErrorKind.SLOW)
            self._close(conn)

    def _flush(self, conn: _Conn) -> None:
        if conn.closed:
            return
        try:
            sent = conn.sock.send(conn.outbuf, socket.MSG_NOSIGNAL) if conn.outbuf else 0
        except BlockingIOError:
            sent = 0
        except OSError:  # the client went away
            self._count(ErrorKind.SOCKET)
            self._close(conn)
            return
        del conn.outbuf[:sent]
        if bool(conn.outbuf) != conn.blocked:
            conn.blocked = bool(conn.outbuf)
            self._watch(conn)
        if conn.closing and not conn.outbuf and not conn.lines:
            self._close(conn)


def _group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _listen(path: Path, group: str | None, backlog: int) -> socket.socket:
    """A listening socket at ``path``: mode 0660, owned by ``group`` if given."""
    gid = _group_id(group)
    _prepare_directory(path.parent)
    _remove_stale(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(str(path))
        os.chmod(path, 0o660)
        if gid is not None and os.stat(path).st_gid != gid:
            os.chown(path, -1, gid)
        sock.listen(backlog)
        sock.setblocking(False)
    except OSError as exc:
        sock.close()
        with contextlib.suppress(OSError):
            os.unlink(path)
        hint = (f" (the daemon's user must be in group {group})"
                if isinstance(exc, PermissionError) and group else "")
        raise ApiError(f"cannot set up the command socket {path}: "
                       f"{exc.strerror or exc}{hint}") from exc
    return sock


def _group_id(group: str | None) -> int | None:
    if group is None:
        return None
    try:
        return grp.getgrnam(group).gr_gid
    except KeyError:
        raise ApiError(f"the command socket's group {group!r} does not exist (create it with "
                       "systemd-sysusers or groupadd)") from None


def _prepare_directory(directory: Path) -> None:
    try:
        directory.mkdir(mode=0o750, parents=True, exist_ok=True)
        st = os.lstat(directory)
    except OSError as exc:
        raise ApiError(f"cannot create the directory of the command socket {directory}: "
                       f"{exc.strerror or exc}") from exc
    if not stat.S_ISDIR(st.st_mode) or st.st_uid not in (0, os.geteuid()):
        raise ApiError(f"refusing to put the command socket in {directory}: not a directory "
                       f"owned by root or by uid {os.geteuid()}")


def _remove_stale(path: Path) -> None:
    """Remove a socket file that nobody listens on; refuse anything else."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise ApiError(f"{path} exists and is not a socket; refusing to replace it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(0.5)
    try:
        probe.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return
    except (TimeoutError, BlockingIOError):
        pass  # its backlog is full: somebody listens
    except OSError as exc:
        raise ApiError(f"cannot tell whether {path} is in use: {exc.strerror or exc}") from exc
    finally:
        probe.close()
    raise ApiError(f"another daemon is already listening at {path}")


# --------------------------------------------------------------------------- client

_STOP: Mapping[str, str] = types.MappingProxyType({"cmd": Command.STOP.value})


class Client:
    """One connection for several requests, one at a time (the jog dead-man)."""

    def __init__(self, path: Path, timeout_s: float = 2.0) -> None:
        self.path, self._timeout_s = Path(path), timeout_s
        self._sock = _connect(self.path, timeout_s)
        self._inbuf = bytearray()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._sock.close()

    def request(self, request: Mapping[str, Any]) -> dict[str, Any]:
        """Send one request, return its reply; raise CommandRejected on an error reply."""
        try:
            line = json.dumps(dict(request), allow_nan=False).encode() + b"\n"
        except (TypeError, ValueError) as exc:
            raise ApiError(f"cannot send {request!r}: {exc}") from exc
        try:
            self._sock.settimeout(self._timeout_s)
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                self._sock.sendall(line)  # if it fails, the daemon may have said why: read on
            return _check_reply(self._read_line(time.monotonic() + self._timeout_s), self.path)
        except ApiError:
            raise
        except TimeoutError as exc:
            self.close()
            raise DaemonUnreachable(f"the rakectl daemon at {self.path} did not answer within "
                                    f"{self._timeout_s:g} s") from exc
        except OSError as exc:
            self.close()
            raise DaemonUnreachable(f"lost the connection to the rakectl daemon at {self.path}: "
                                    f"{exc.strerror or exc}") from exc

    def hold(self, request: Mapping[str, Any], duration_s: float, *,
             period_s: float = DEAD_MAN_PERIOD_S, clock: Callable[[], float] = time.monotonic,
             sleep: Callable[[float], object] = time.sleep) -> int:
        """Repeat ``request`` every ``period_s`` for ``duration_s`` (a jog), then send stop.

        On any error or Ctrl-C, stop goes out on a new connection before the error
        propagates. Returns the number of requests sent.
        """
        start_s, sent = clock(), 0
        try:
            while clock() - start_s < duration_s:
                self.request(request)
                sent += 1
                sleep(max(0.0, start_s + sent * period_s - clock()))
        except BaseException:
            with contextlib.suppress(ApiError):
                call(self.path, _STOP, self._timeout_s)
            raise
        self.request(_STOP)
        return sent

    def _read_line(self, deadline_s: float) -> bytes:
        while b"\n" not in self._inbuf:
            remaining_s = deadline_s - time.monotonic()
            if remaining_s <= 0:
                raise TimeoutError
            self._sock.settimeout(remaining_s)
            chunk = self._sock.recv(65536)
            if not chunk:
                raise DaemonUnreachable(f"the rakectl daemon at {self.path} closed the "
                                        "connection without answering")
            self._inbuf += chunk
            if len(self._inbuf) > _MAX_REPLY_BYTES:
                raise ApiError(f"the reply of the daemon at {self.path} is over "
                               f"{_MAX_REPLY_BYTES} bytes")
        line, _, self._inbuf = self._inbuf.partition(b"\n")
        return bytes(line)


def call(path: Path, request: Mapping[str, Any], timeout_s: float = 2.0) -> dict[str, Any]:
    """One request, one reply, on a connection of its own.

    Raises DaemonUnreachable (no daemon, no answer), CommandRejected (an error reply,
    with the daemon's sentence) or ApiError (an unusable reply).
    """
    with Client(path, timeout_s) as client:
        return client.request(request)


def _connect(path: Path, timeout_s: float) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout_s)
    try:
        sock.connect(str(path))
    except OSError as exc:
        sock.close()
        raise DaemonUnreachable(f"cannot reach the rakectl daemon at {path}: "
                                f"{_why(exc, timeout_s)}") from exc
    return sock


def _why(exc: OSError, timeout_s: float) -> str:
    if isinstance(exc, FileNotFoundError):
        return "no such file (is `rakectl run` or the service running?)"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused (is `rakectl run` or the service running?)"
    if isinstance(exc, PermissionError):
        return ("permission denied (is your user in group rakectl? `sudo usermod -aG rakectl "
                "$USER`, then log in again)")
    if isinstance(exc, TimeoutError | BlockingIOError):
        return f"no answer within {timeout_s:g} s (the daemon is busy)"
    return exc.strerror or str(exc)


def _check_reply(line: bytes, path: Path) -> dict[str, Any]:
    try:
        reply = json.loads(line)
    except ValueError as exc:
        raise ApiError(f"unusable reply from the rakectl daemon at {path}: {exc}") from exc
    if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
        raise ApiError(f"unusable reply from the rakectl daemon at {path}: {_show(reply)}")
    if not reply["ok"]:
        raise CommandRejected(str(reply.get("error") or "the daemon refused without a reason"))
    return reply
