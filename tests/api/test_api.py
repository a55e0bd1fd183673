"""The command API: schema, a real socket polled from the test's thread, the client.

The server is polled between client operations in the test's own thread; only the
tests of the blocking client run it in a thread, which they join.
"""

from __future__ import annotations

import contextlib
import grp
import json
import math
import os
import pwd
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rakectl.api import client as api_client
from rakectl.api.client import Client, call, default_socket_path, socket_path
from rakectl.api.endpoint import peer_allowed
from rakectl.api.schema import (
    COMMANDS,
    MAX_REQUEST_BYTES,
    ApiCommand,
    ErrorKind,
    JogSpace,
    Peer,
    Refusal,
    Request,
    decode_request,
    show,
)
from rakectl.api.server import EVICT_IDLE_S, CommandServer
from rakectl.cli.docs import api_reference
from rakectl.errors import ApiError, CommandRejected, DaemonUnreachable, RakeError

JOG_TASK = {"cmd": "jog", "space": "task", "reach_m_per_s": 0.1}


class Recorder:
    """A handler that records what reached it and answers with the command's name."""

    def __init__(self, reply: Callable[[Request], Mapping[str, Any]] | None = None) -> None:
        self.requests: list[Request] = []
        self._reply = reply

    def __call__(self, request: Request) -> Mapping[str, Any]:
        self.requests.append(request)
        return self._reply(request) if self._reply else {"did": request.cmd.value}


@pytest.fixture
def sock_path(tmp_path: Path) -> Path:
    return tmp_path / "run" / "rakectl.sock"


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


@pytest.fixture
def server(sock_path: Path, recorder: Recorder) -> Iterator[CommandServer]:
    with CommandServer(sock_path, None, recorder) as srv:
        yield srv


def _connect(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(1.0)
    sock.connect(str(path))
    return sock


def _drain(sock: socket.socket) -> tuple[bytes, bool]:
    """What the socket holds now, and whether the server closed it."""
    data, timeout_s = b"", sock.gettimeout()
    sock.settimeout(0.0)
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except BlockingIOError:
        return data, False
    except ConnectionResetError:
        pass
    finally:
        sock.settimeout(timeout_s)
    return data, True


def _replies(server: CommandServer, sock: socket.socket, count: int,
             polls: int = 50) -> tuple[list[dict[str, Any]], bool]:
    """Poll until ``count`` reply lines arrived (or the connection closed)."""
    data, closed = b"", False
    for _ in range(polls):
        server.poll(0.01)
        more, closed = _drain(sock)
        data += more
        if closed or data.count(b"\n") >= count:
            break
    return [json.loads(line) for line in data.splitlines()], closed


def _exchange(server: CommandServer, payload: bytes, count: int = 1) -> list[dict[str, Any]]:
    with _connect(server.path) as sock:
        sock.sendall(payload)
        replies, _ = _replies(server, sock, count)
    return replies


# --------------------------------------------------------------------------- bad input


BAD = [
    (b"{not json", ErrorKind.MALFORMED,
     "malformed JSON: Expecting property name enclosed in double quotes at column 2"),
    (b'{"cmd": "status"} x', ErrorKind.MALFORMED, "malformed JSON: Extra data at column 19"),
    (b"\xff\xfe{}", ErrorKind.MALFORMED, "request is not UTF-8 (byte 0xff at offset 0)"),
    (b"[" * 3000, ErrorKind.MALFORMED, "malformed JSON: nested too deeply"),
    (b'{"cmd": "status", "cmd": "estop"}', ErrorKind.MALFORMED,
     'malformed JSON: key "cmd" is given twice'),
    (b"[1, 2]", ErrorKind.INVALID, "a request must be a JSON object, got an array"),
    (b'"status"', ErrorKind.INVALID, "a request must be a JSON object, got a string"),
    (b"3", ErrorKind.INVALID, "a request must be a JSON object, got a number"),
    (b"{}", ErrorKind.INVALID, 'a request needs "cmd", one of: status, arm, disarm, stop, '
     "estop, reset, dump, jog, excavate, timing_reset, shutdown"),
    (b'{"cmd": 3}', ErrorKind.INVALID, "unknown command 3; known commands: status, arm"),
    (b'{"cmd": "stauts"}', ErrorKind.INVALID,
     'unknown command "stauts" (did you mean status?); known commands: status, arm'),
    (b'{"cmd": "status", "id": [1]}', ErrorKind.INVALID,
     '"id" must be an integer or a string of at most 128 characters, got [1]'),
    (b'{"cmd": "status", "verbose": true}', ErrorKind.INVALID,
     'status: unknown argument "verbose"; status takes no arguments'),
    (b'{"cmd": "jog", "space": "task", "reach": 0.1}', ErrorKind.INVALID,
     'jog: unknown argument "reach" (did you mean reach_m_per_s?); jog takes space, '
     "reach_m_per_s, height_m_per_s, r_m_per_s, theta_rad_per_s"),
    (b'{"cmd": "jog", "reach_m_per_s": 0.1}', ErrorKind.INVALID, "jog: space is required"),
    (b'{"cmd": "jog", "space": "cartesian"}', ErrorKind.INVALID,
     'jog: space must be one of task, joint, got "cartesian"'),
    (b'{"cmd": "jog", "space": "task", "reach_m_per_s": "fast"}', ErrorKind.INVALID,
     'jog: reach_m_per_s must be a number, got "fast"'),
    (b'{"cmd": "jog", "space": "task", "reach_m_per_s": true}', ErrorKind.INVALID,
     "jog: reach_m_per_s must be a number, got true"),
    (b'{"cmd": "jog", "space": "task", "reach_m_per_s": NaN}', ErrorKind.INVALID,
     "jog: reach_m_per_s must be finite, got nan"),
    (b'{"cmd": "jog", "space": "task", "height_m_per_s": -Infinity}', ErrorKind.INVALID,
     "jog: height_m_per_s must be finite, got -inf"),
    (b'{"cmd": "jog", "space": "task", "height_m_per_s": 1e999}', ErrorKind.INVALID,
     "jog: height_m_per_s must be finite, got inf"),
    (b'{"cmd": "jog", "space": "joint", "r_m_per_s": 1' + b"0" * 400 + b"}", ErrorKind.INVALID,
     "jog: r_m_per_s must be finite, got inf"),
    (b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0.3}', ErrorKind.INVALID,
     "jog: reach_m_per_s must be <= 0.25, got 0.3"),
    (b'{"cmd": "jog", "space": "joint", "theta_rad_per_s": -0.6}', ErrorKind.INVALID,
     "jog: theta_rad_per_s must be >= -0.5, got -0.6"),
    (b'{"cmd": "jog", "space": "task", "r_m_per_s": 0.1}', ErrorKind.INVALID,
     "jog: r_m_per_s is only allowed with space=joint"),
    (b'{"cmd": "excavate", "reach_far_m": 1.3, "reach_near_m": 0.8}', ErrorKind.INVALID,
     "excavate: target_depth_m is required"),
    (b'{"cmd": "excavate", "reach_far_m": 0.8, "reach_near_m": 1, "target_depth_m": 0.05}',
     ErrorKind.INVALID, "excavate: reach_far_m must be > reach_near_m (1), got 0.8"),
    (b'{"cmd": "excavate", "reach_far_m": 1.3, "reach_near_m": 0.8, "target_depth_m": 0.6}',
     ErrorKind.INVALID, "excavate: target_depth_m must be <= 0.5, got 0.6"),
    (b'{"cmd": "dump", "path": 3}', ErrorKind.INVALID, "dump: path must be a string, got 3"),
    (b'{"cmd": "dump", "path": ""}', ErrorKind.INVALID,
     'dump: path must be a non-empty string of at most 1024 characters without NUL, got ""'),
]


@pytest.mark.parametrize(("payload", "kind", "error"), BAD,
                         ids=[error[:40] for _, _, error in BAD])
def test_bad_request_gets_its_error_and_never_reaches_the_handler(
    server: CommandServer, recorder: Recorder, payload: bytes, kind: ErrorKind, error: str
) -> None:
    [reply] = _exchange(server, payload + b"\n")
    assert reply["ok"] is False
    assert reply["error"].startswith(error), reply["error"]
    assert "\n" not in reply["error"]
    assert recorder.requests == []
    assert server.stats.errors[kind] == 1
    assert server.stats.handled == 0


def test_pure_decoder_agrees_with_the_server() -> None:
    for payload, kind, error in BAD:
        result = decode_request(payload)
        assert isinstance(result, Refusal)
        assert result.kind is kind and result.error.startswith(error)


def test_error_reply_echoes_a_valid_id(server: CommandServer) -> None:
    [reply] = _exchange(server, b'{"cmd": "fly", "id": "a-7"}\n')
    assert reply == {"ok": False, "id": "a-7", "error": reply["error"]}
    assert reply["error"].startswith('unknown command "fly"')


def test_request_too_large_is_answered_then_closed(
    server: CommandServer, recorder: Recorder
) -> None:
    big = b'{"cmd": "status"' + b" " * 5000 + b"}"
    with _connect(server.path) as sock:
        sock.sendall(b'{"cmd": "arm"}\n' + big + b'\n{"cmd": "estop"}\n')
        replies, closed = _replies(server, sock, 2)
    assert [r["ok"] for r in replies] == [True, False]
    assert replies[1]["error"] == f"request too large ({len(big)} bytes, limit 4096)"
    assert closed
    assert [r.cmd for r in recorder.requests] == [ApiCommand.ARM]  # estop after it was not read
    assert server.stats.errors[ErrorKind.TOO_LARGE] == 1


def test_endless_line_is_cut_off(server: CommandServer, recorder: Recorder) -> None:
    with _connect(server.path) as sock:
        sock.sendall(b"x" * 6000)
        replies, closed = _replies(server, sock, 1)
    assert replies[0]["error"].startswith("request too large (at least ")
    assert closed and recorder.requests == []


def test_request_of_exactly_the_limit_is_accepted(server: CommandServer) -> None:
    line = b'{"cmd": "status"}'.ljust(MAX_REQUEST_BYTES)
    [reply] = _exchange(server, line + b"\n")
    assert reply == {"ok": True, "did": "status"}


# --------------------------------------------------------------------------- good input


def test_good_requests_reach_the_handler_with_typed_arguments(
    server: CommandServer, recorder: Recorder
) -> None:
    payload = (b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0, "id": 7}\n'
               b'{"cmd": "jog", "space": "joint", "theta_rad_per_s": -0.25}\n'
               b'{"cmd": "excavate", "reach_far_m": 1.3, "reach_near_m": 0.8, '
               b'"target_depth_m": 0.05, "stroke_speed_m_per_s": 0.04}\n'
               b'{"cmd": "dump", "path": "/var/lib/rakectl/x.log"}\n')
    replies = _exchange(server, payload, 4)
    assert replies[0] == {"ok": True, "id": 7, "did": "jog"}
    jog_task, jog_joint, excavate, dump = recorder.requests
    assert jog_task.args == {"space": JogSpace.TASK, "reach_m_per_s": 0.0, "height_m_per_s": 0.0}
    assert jog_task.args["space"] is JogSpace.TASK
    assert type(jog_task.args["reach_m_per_s"]) is float and jog_task.id == 7
    assert jog_joint.args == {"space": JogSpace.JOINT, "r_m_per_s": 0.0, "theta_rad_per_s": -0.25}
    assert excavate.number("depth_step_m") is None  # absent: the configured value applies
    assert excavate.number("stroke_speed_m_per_s") == 0.04
    assert dump.text("path") == "/var/lib/rakectl/x.log"
    assert jog_task.peer is not None and jog_task.peer.pid == os.getpid()
    assert jog_task.peer.uid == os.geteuid()
    with pytest.raises(TypeError):
        jog_task.args["space"] = "joint"  # type: ignore[index]


def test_several_requests_in_one_packet_are_answered_in_order(
    server: CommandServer, recorder: Recorder
) -> None:
    payload = b'{"cmd":"status","id":1}\n{"cmd":"arm","id":2}\n\n  \r\n{"cmd":"stop","id":3}\n'
    replies = _exchange(server, payload, 3)
    assert [r["id"] for r in replies] == [1, 2, 3]
    assert [r.cmd for r in recorder.requests] == [ApiCommand.STATUS, ApiCommand.ARM,
                                                  ApiCommand.STOP]
    assert server.stats.requests == 3


def test_request_dribbled_byte_by_byte(server: CommandServer, recorder: Recorder) -> None:
    with _connect(server.path) as sock:
        for byte in b'{"cmd": "status"}':
            sock.send(bytes([byte]))
            server.poll(0.01)
        assert recorder.requests == []
        sock.send(b"\n")
        replies, _ = _replies(server, sock, 1)
    assert replies == [{"ok": True, "did": "status"}]


def test_client_gone_mid_request(server: CommandServer, recorder: Recorder) -> None:
    sock = _connect(server.path)
    server.poll(0.01)
    assert server.stats.clients == 1
    sock.sendall(b'{"cmd": "est')
    sock.close()
    for _ in range(3):
        server.poll(0.01)
    assert recorder.requests == [] and server.stats.clients == 0


def test_half_closed_client_still_gets_its_replies(server: CommandServer) -> None:
    """Its complete requests answered, and its last line without a newline said to be
    incomplete, not dropped in silence; then the connection closes."""
    with _connect(server.path) as sock:
        sock.sendall(b'{"cmd": "status"}\n{"cmd": "arm"}\n{"cmd": "st')
        sock.shutdown(socket.SHUT_WR)
        replies, closed = _replies(server, sock, 3)
    assert [r.get("did") for r in replies] == ["status", "arm", None] and closed
    assert replies[2] == {"ok": False, "error": "incomplete request at the end of input (a "
                          "request ends with a newline)"}
    assert server.stats.errors[ErrorKind.MALFORMED] == 1 and server.stats.clients == 0


def test_client_that_never_reads_is_dropped(sock_path: Path) -> None:
    recorder = Recorder(lambda request: {"blob": "x" * 65536})
    with CommandServer(sock_path, None, recorder, max_backlog_bytes=128 * 1024) as server:
        sock = _connect(sock_path)
        sock.sendall(b'{"cmd": "status"}\n' * 40)
        for _ in range(60):
            server.poll(0.01)
        assert server.stats.errors[ErrorKind.SLOW] == 1 and server.stats.clients == 0
        sock.close()
        assert _exchange(server, b'{"cmd": "status"}\n')[0]["ok"]  # the others go on


def test_client_limit(sock_path: Path, recorder: Recorder) -> None:
    with CommandServer(sock_path, None, recorder, max_clients=2, clock=lambda: 0.0) as server:
        first, second = _connect(sock_path), _connect(sock_path)
        server.poll(0.01)
        third = _connect(sock_path)
        replies, closed = _replies(server, third, 1)
        assert replies[0]["error"] == "too many clients (limit 2); try again later" and closed
        first.sendall(b'{"cmd": "status"}\n')
        assert _replies(server, first, 1)[0][0]["ok"]
        assert server.stats.errors[ErrorKind.BUSY] == 1
        for sock in (first, second, third):
            sock.close()


def test_a_full_server_makes_room_by_closing_its_idlest_client(
        sock_path: Path, recorder: Recorder) -> None:
    """Every slot taken by connections silent for EVICT_IDLE_S: the one silent longest
    is closed so that a new one (an e-stop) gets in; a client in use keeps its slot."""
    now = [0.0]
    with CommandServer(sock_path, None, recorder, max_clients=2,
                       clock=lambda: now[0]) as server:
        forgotten, busy = _connect(sock_path), _connect(sock_path)
        server.poll(0.01)
        now[0] = EVICT_IDLE_S
        busy.sendall(b'{"cmd": "status"}\n')
        assert _replies(server, busy, 1)[0][0]["ok"]
        now[0] = 2 * EVICT_IDLE_S
        estop = _connect(sock_path)
        estop.sendall(b'{"cmd": "estop"}\n')
        assert _replies(server, estop, 1)[0][0]["did"] == "estop"
        assert _drain(forgotten)[1]  # closed by the server
        busy.sendall(b'{"cmd": "status"}\n')
        assert _replies(server, busy, 1)[0][0]["ok"]
        assert server.stats.errors[ErrorKind.IDLE] == 1
        assert server.stats.errors[ErrorKind.BUSY] == 0
        for sock in (forgotten, busy, estop):
            sock.close()


def test_a_request_the_validation_fails_on_is_an_internal_error_and_the_server_goes_on(
        server: CommandServer, recorder: Recorder, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bug in decoding (a RecursionError from a request nested near the stack's limit
    once ended the daemon's loop) is answered, counted and survived."""
    from rakectl.api import server as server_module

    def broken(line: bytes, client: int = 0, peer: Peer | None = None) -> Request | Refusal:
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(server_module, "decode_request", broken)
    [reply] = _exchange(server, b'{"cmd": "estop"}\n')
    assert reply == {"ok": False, "error": "internal error: RecursionError reading the request"}
    assert server.stats.errors[ErrorKind.INTERNAL] == 1 and recorder.requests == []
    monkeypatch.undo()
    assert _exchange(server, b'{"cmd": "status"}\n')[0]["ok"]


def test_a_value_nested_too_deeply_to_encode_is_named_by_its_kind() -> None:
    """Near the stack's limit, as deep in the daemon's loop, the encoder cannot show a
    value nested 900 deep that the decoder could read: the error names its kind."""
    nested: list[Any] = []
    for _ in range(900):
        nested = [nested]
    depth, frame = 0, sys._getframe()
    while frame is not None:
        depth, frame = depth + 1, frame.f_back

    def down(frames: int) -> str:
        return show(nested) if frames <= 0 else down(frames - 1)

    assert show(nested).startswith("[[[[")  # with the stack to spare
    assert down(sys.getrecursionlimit() - depth - 300) == "an array nested too deeply to show"


def test_one_flooding_client_does_not_starve_another(sock_path: Path, recorder: Recorder) -> None:
    ticks = iter(range(10**9))
    clock = lambda: next(ticks) * 1e-5  # noqa: E731  (each reading of the clock: 10 µs)
    with CommandServer(sock_path, None, recorder, clock=clock) as server:
        flood, other = _connect(sock_path), _connect(sock_path)
        server.poll(1.0)
        flood.sendall(b'{"cmd": "status"}\n' * 200)
        other.sendall(b'{"cmd": "estop"}\n')
        first = server.poll(1e-4)
        assert 0 < first < 20  # the budget holds
        assert ApiCommand.ESTOP in [r.cmd for r in recorder.requests]
        while server.poll(1e-4):
            pass
        assert len(recorder.requests) == 201
        flood.close()
        other.close()


def test_zero_budget_answers_nothing(server: CommandServer, recorder: Recorder) -> None:
    with _connect(server.path) as sock:
        server.poll(0.01)
        sock.sendall(b'{"cmd": "status"}\n')
        assert server.poll(0.0) == 0 and recorder.requests == []
        assert _replies(server, sock, 1)[0][0]["ok"]


def test_idle_client_is_closed(sock_path: Path, recorder: Recorder) -> None:
    now = [0.0]
    with CommandServer(sock_path, None, recorder, clock=lambda: now[0],
                       idle_timeout_s=60.0) as server:
        sock = _connect(sock_path)
        server.poll(0.01)
        assert server.stats.accepted == 1 and server.is_connected(1)
        now[0] = 61.5
        server.poll(0.01)
        assert server.stats.errors[ErrorKind.IDLE] == 1 and not server.is_connected(1)
        assert _drain(sock) == (b"", True)
        sock.close()


# --------------------------------------------------------------------------- the handler


@pytest.mark.parametrize(
    ("reply", "error", "kind"),
    [
        (ZeroDivisionError("division by zero"), "internal error: ZeroDivisionError: division "
         "by zero", ErrorKind.INTERNAL),
        (CommandRejected("arm refused: the θ drive is in fault"),
         "arm refused: the θ drive is in fault", ErrorKind.REJECTED),
        ({"ok": 1}, "internal error: ValueError: the handler's reply uses the reserved key 'ok'",
         ErrorKind.INTERNAL),
        ({"pose": object()}, "internal error: TypeError: Object of type object is not JSON "
         "serializable", ErrorKind.INTERNAL),
        ([1, 2], "internal error: TypeError: the handler returned list, not a mapping",
         ErrorKind.INTERNAL),
    ],
)
def test_handler_failure_is_answered_and_the_server_goes_on(
    sock_path: Path, reply: Any, error: str, kind: ErrorKind
) -> None:
    def handler(request: Request) -> Mapping[str, Any]:
        if request.cmd is ApiCommand.STATUS:
            return {"state": "disarmed"}
        if isinstance(reply, Exception):
            raise reply
        return reply  # type: ignore[no-any-return]

    with CommandServer(sock_path, None, handler) as server:
        replies = _exchange(server, b'{"cmd": "arm", "id": 1}\n{"cmd": "status"}\n', 2)
        assert replies == [{"ok": False, "id": 1, "error": error},
                           {"ok": True, "state": "disarmed"}]
        assert server.stats.errors[kind] == 1 and server.stats.handled == 2


def test_non_finite_numbers_in_a_reply_go_out_as_null(sock_path: Path) -> None:
    recorder = Recorder(lambda request: {"force_n": math.nan, "pose": [1.0, math.inf]})
    with CommandServer(sock_path, None, recorder) as server:
        [reply] = _exchange(server, b'{"cmd": "status"}\n')
    assert reply == {"ok": True, "force_n": None, "pose": [1.0, None]}


# --------------------------------------------------------------------------- the socket file


def test_socket_file_mode_group_and_removal(sock_path: Path, recorder: Recorder) -> None:
    group = "daemon" if _group_exists("daemon") else grp.getgrgid(os.getegid()).gr_name
    with CommandServer(sock_path, group, recorder):
        st = os.stat(sock_path)
        assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o660
        assert st.st_gid == grp.getgrnam(group).gr_gid
        assert stat.S_IMODE(os.stat(sock_path.parent).st_mode) == 0o750
    assert not sock_path.exists()


def test_unknown_group_is_a_clear_error(sock_path: Path, recorder: Recorder) -> None:
    with pytest.raises(ApiError, match="group 'no-such-group-rk' does not exist"):
        CommandServer(sock_path, "no-such-group-rk", recorder)
    assert not sock_path.exists()


def test_stale_socket_is_replaced_but_a_live_one_is_not(
    sock_path: Path, recorder: Recorder
) -> None:
    sock_path.parent.mkdir()
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(sock_path))
    stale.close()  # the file stays, nobody listens
    with CommandServer(sock_path, None, recorder) as server:
        with pytest.raises(ApiError, match="already listening"):
            CommandServer(sock_path, None, recorder)
        assert _exchange(server, b'{"cmd": "status"}\n')[0]["ok"]


def test_a_file_that_is_not_a_socket_is_left_alone(sock_path: Path, recorder: Recorder) -> None:
    sock_path.parent.mkdir()
    sock_path.write_text("precious")
    with pytest.raises(ApiError, match="exists and is not a socket"):
        CommandServer(sock_path, None, recorder)
    assert sock_path.read_text() == "precious"


def test_directory_of_another_user_is_refused(tmp_path: Path, recorder: Recorder) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root to give a directory to another user")
    directory = tmp_path / "theirs"
    directory.mkdir()
    os.chown(directory, 65534, 65534)
    with pytest.raises(ApiError, match="refusing to put the command socket"):
        CommandServer(directory / "rakectl.sock", None, recorder)


# --------------------------------------------------------------------------- credentials


@settings(max_examples=300)
@given(uid=st.integers(0, 2**32 - 2), gid=st.integers(0, 2**32 - 2),
       groups=st.frozensets(st.integers(0, 70000), max_size=8),
       daemon_uid=st.integers(0, 70000), socket_gid=st.integers(0, 70000))
def test_credential_predicate(uid: int, gid: int, groups: frozenset[int], daemon_uid: int,
                              socket_gid: int) -> None:
    peer = Peer(pid=1234, uid=uid, gid=gid, groups=groups)
    allowed = peer_allowed(peer, daemon_uid, socket_gid)
    assert allowed == (uid == 0 or uid == daemon_uid or gid == socket_gid
                       or socket_gid in groups)
    assert peer_allowed(Peer(1, 0, gid, groups), daemon_uid, socket_gid)  # root
    assert peer_allowed(Peer(1, daemon_uid, gid, groups), daemon_uid, socket_gid)  # ourselves
    assert peer_allowed(Peer(1, uid, gid, groups | {socket_gid}), daemon_uid, socket_gid)
    stranger = Peer(1, daemon_uid + 1, socket_gid + 1, groups - {socket_gid})
    assert not peer_allowed(stranger, daemon_uid, socket_gid)


_CHILD = """
import json, socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
s.settimeout(5)
s.connect(sys.argv[1])
try:
    s.sendall(b'{"cmd": "status"}\\n')
except BrokenPipeError:
    pass  # turned away before the request went out: the reason is waiting to be read
data = b""
while True:
    chunk = s.recv(4096)
    if not chunk:
        break
    data += chunk
    if b"\\n" in data:
        break
print(data.decode().strip())
"""


@pytest.mark.parametrize("member", [False, True], ids=["stranger", "group-member"])
def test_peer_credentials_of_another_user(recorder: Recorder, member: bool) -> None:
    python = shutil.which("python3", path="/usr/bin:/bin")
    if os.geteuid() != 0 or python is None or not _group_exists("daemon"):
        pytest.skip("needs root, /usr/bin/python3 and the group daemon to run a client as nobody")
    nobody = pwd.getpwnam("nobody")
    with tempfile.TemporaryDirectory(prefix="rk-api-") as directory:
        os.chmod(directory, 0o755)
        path = Path(directory) / "rakectl.sock"
        with CommandServer(path, "daemon", recorder) as server:
            os.chmod(path, 0o666)  # as if the mode were wrong: only SO_PEERCRED guards now
            extra = ["daemon"] if member else []
            child = subprocess.Popen([python, "-c", _CHILD, str(path)], user=nobody.pw_uid,
                                     group=nobody.pw_gid, extra_groups=extra,
                                     stdout=subprocess.PIPE, text=True)
            while child.poll() is None:
                server.poll(0.01)
                time.sleep(0.001)
            reply = json.loads(child.communicate()[0])
    if member:
        assert reply == {"ok": True, "did": "status"}
    else:
        assert reply == {"ok": False, "error": f"permission denied: uid {nobody.pw_uid} is not "
                         "root, not the daemon's user and not in group daemon"}
        assert recorder.requests == [] and server.stats.errors[ErrorKind.PERMISSION] == 1


def _group_exists(name: str) -> bool:
    try:
        grp.getgrnam(name)
    except KeyError:
        return False
    return True


# --------------------------------------------------------------------------- fuzz

_JSON = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=10), children, max_size=4),
    max_leaves=12,
)
_NAMES = sorted({arg.name for spec in COMMANDS.values() for arg in spec.args} | {"id", "x"})
_REQUEST_LIKE = st.fixed_dictionaries(
    {"cmd": st.sampled_from([*COMMANDS, "bogus"])},
    optional={name: _JSON | st.floats(-1, 2) | st.sampled_from(list(JogSpace)) for name in _NAMES},
)
_LINES = (
    st.binary(max_size=5000)
    | _JSON.map(lambda value: json.dumps(value).encode())
    | _REQUEST_LIKE.map(lambda value: json.dumps(value).encode())
).map(lambda data: data.replace(b"\n", b""))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(line=_LINES)
def test_fuzz_never_raises_and_always_answers_or_closes(line: bytes) -> None:
    recorder = Recorder()
    with tempfile.TemporaryDirectory(prefix="rk-fuzz-") as directory, \
            CommandServer(Path(directory) / "s.sock", None, recorder) as server:
        with _connect(server.path) as sock:
            sock.sendall(line + b"\n")
            replies, closed = _replies(server, sock, 1, polls=5)
        if not line.strip():
            assert replies == [] and not closed
            return
        [reply] = replies
        assert isinstance(reply["ok"], bool)
        assert len(recorder.requests) == (1 if reply["ok"] else 0)
        if not reply["ok"]:
            assert isinstance(reply["error"], str) and reply["error"]
        assert closed == (len(line) > MAX_REQUEST_BYTES)


# --------------------------------------------------------------------------- client


@contextlib.contextmanager
def _serving(server: CommandServer) -> Iterator[None]:
    """Poll the server in a thread while a blocking client talks to it; joined on exit."""
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            server.poll(0.001)
            time.sleep(0.0002)

    thread = threading.Thread(target=run, name="test-api-server")
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5.0)


def test_call_returns_the_reply_and_raises_on_an_error_reply(server: CommandServer) -> None:
    with _serving(server):
        assert call(server.path, {"cmd": "status", "id": "x"}) == {
            "ok": True, "id": "x", "did": "status"}
        with pytest.raises(CommandRejected, match=r"^jog: space is required$") as info:
            call(server.path, {"cmd": "jog"})
    assert isinstance(info.value, RakeError)


def test_call_without_a_daemon(tmp_path: Path) -> None:
    missing = tmp_path / "rakectl.sock"
    with pytest.raises(DaemonUnreachable) as info:
        call(missing, {"cmd": "status"})
    assert str(info.value) == (f"cannot reach the rakectl daemon at {missing}: no such file (is "
                               "`rakectl run` or the service running?)")
    assert isinstance(info.value, ConnectionError)
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(missing))
    stale.close()
    with pytest.raises(DaemonUnreachable, match="connection refused"):
        call(missing, {"cmd": "status"})


def test_call_times_out_when_nobody_answers(sock_path: Path, recorder: Recorder) -> None:
    with CommandServer(sock_path, None, recorder), \
            pytest.raises(DaemonUnreachable, match=r"did not answer within 0\.2 s"):
        call(sock_path, {"cmd": "status"}, timeout_s=0.2)  # never polled


def test_client_turned_away_reads_the_reason(sock_path: Path, recorder: Recorder) -> None:
    with CommandServer(sock_path, None, recorder, max_clients=1) as server, \
            _connect(sock_path), _serving(server):
        time.sleep(0.05)  # the first connection is admitted
        for _ in range(20):  # whether the request goes out before the refusal or not
            with pytest.raises(CommandRejected, match=r"^too many clients \(limit 1\)"):
                call(sock_path, {"cmd": "status"})
    assert recorder.requests == []


def test_client_refuses_to_send_non_finite_numbers(server: CommandServer) -> None:
    with Client(server.path) as client, pytest.raises(ApiError, match="cannot send"):
        client.request({"cmd": "jog", "space": "task", "reach_m_per_s": math.nan})


def test_dead_man_hold_repeats_the_jog_then_stops(
    server: CommandServer, recorder: Recorder
) -> None:
    with _serving(server), Client(server.path) as client:
        sent = client.hold(JOG_TASK, duration_s=0.35, period_s=0.1)
        assert server.is_connected(recorder.requests[0].client)
    assert 3 <= sent <= 5
    cmds = [r.cmd for r in recorder.requests]
    assert cmds == [ApiCommand.JOG] * sent + [ApiCommand.STOP]
    assert len({r.client for r in recorder.requests}) == 1  # one connection


def test_dead_man_sends_stop_when_interrupted(server: CommandServer, recorder: Recorder) -> None:
    def interrupt(_: float) -> None:
        raise KeyboardInterrupt

    with _serving(server), Client(server.path) as client, pytest.raises(KeyboardInterrupt):
        client.hold(JOG_TASK, duration_s=10.0, sleep=interrupt)
    assert [r.cmd for r in recorder.requests] == [ApiCommand.JOG, ApiCommand.STOP]


# --------------------------------------------------------------------------- paths, docs


def test_socket_path_precedence(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(api_client, "SERVICE_RUNTIME_DIR", tmp_path / "absent")
    env = {"RAKECTL_SOCKET": "/srv/r.sock", "XDG_RUNTIME_DIR": "/run/user/1000"}
    assert socket_path("/x/y.sock", env) == Path("/x/y.sock")
    assert socket_path(None, env) == Path("/srv/r.sock")
    assert socket_path(None, {"XDG_RUNTIME_DIR": "/run/user/1000"}) == Path(
        "/run/user/1000/rakectl/rakectl.sock")
    assert default_socket_path({}) == Path(f"/tmp/rakectl-{os.geteuid()}/rakectl.sock")
    assert default_socket_path({"RUNTIME_DIRECTORY": "/run/rakectl:/run/other"}) == Path(
        "/run/rakectl/rakectl.sock")
    monkeypatch.setattr(api_client, "SERVICE_RUNTIME_DIR", tmp_path)  # the service's directory
    assert default_socket_path({"XDG_RUNTIME_DIR": "/run/user/1000"}) == tmp_path / "rakectl.sock"


def test_api_reference_documents_every_command_and_argument() -> None:
    text = api_reference()
    for spec in COMMANDS.values():
        assert f"| `{spec.command}` |" in text
        for arg in spec.args:
            assert f"| `{arg.name}` |" in text and arg.doc
    assert "| `space` | `task` \\| `joint` | yes |" in text
    assert "Only with space=joint." in text
    assert "Default: the configured lane.depth_step_m." in text


# --------------------------------------------------------------------------- cost (printed)


def test_poll_cost_is_printed(sock_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with CommandServer(sock_path, None, lambda request: {}) as server:
        idle_us = _median_poll_us(server, 20_000)
        clients = [_connect(sock_path) for _ in range(16)]
        server.poll(0.01)
        idle16_us = _median_poll_us(server, 20_000)
        status_us = _per_request_us(server, clients[0], b'{"cmd":"status"}\n')
        jog_us = _per_request_us(server, clients[0], (json.dumps(JOG_TASK) + "\n").encode())
        lone_us = _lone_request_us(server, clients[1], (json.dumps(JOG_TASK) + "\n").encode())
        for sock in clients:
            sock.close()
    with capsys.disabled():
        print(f"\npoll() no traffic: {idle_us:.1f} µs (no clients), {idle16_us:.1f} µs "
              f"(16 idle clients); per request, 100 per poll: status {status_us:.1f} µs, jog "
              f"{jog_us:.1f} µs; a poll answering one jog: {lone_us:.1f} µs (median)")


def _median_poll_us(server: CommandServer, polls: int) -> float:
    samples = []
    for _ in range(polls):
        start = time.perf_counter_ns()
        server.poll(0.001)
        samples.append(time.perf_counter_ns() - start)
    return sorted(samples)[polls // 2] / 1000


def _per_request_us(server: CommandServer, sock: socket.socket, line: bytes) -> float:
    batch, batches, spent_ns = 100, 20, 0
    target = server.stats.requests
    for _ in range(batches):
        sock.sendall(line * batch)
        target += batch
        while server.stats.requests < target:
            start = time.perf_counter_ns()
            server.poll(1.0)
            spent_ns += time.perf_counter_ns() - start
        _drain(sock)
    return spent_ns / (batch * batches) / 1000


def _lone_request_us(server: CommandServer, sock: socket.socket, line: bytes) -> float:
    """One request per poll, as a jog dead-man sends them: the poll that answers it."""
    samples = []
    for _ in range(2000):
        sock.sendall(line)
        start = time.perf_counter_ns()
        answered = server.poll(1.0)
        samples.append(time.perf_counter_ns() - start)
        assert answered == 1
        _drain(sock)
    return sorted(samples)[len(samples) // 2] / 1000
