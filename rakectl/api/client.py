"""The command API's client side: where the socket is, one connection for several
requests (the jog dead-man), and one-shot calls."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from rakectl.api.schema import (
    DEAD_MAN_PERIOD_S,
    MAX_REPLY_BYTES,
    SERVICE_RUNTIME_DIR,
    SOCKET_ENV,
    SOCKET_NAME,
    ApiCommand,
    show,
)
from rakectl.errors import ApiError, CommandRejected, DaemonUnreachable


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


# --------------------------------------------------------------------------- client

_STOP: Mapping[str, str] = types.MappingProxyType({"cmd": ApiCommand.STOP.value})
CHECK_STATUS = "check `rakectl status`"  # what to do once the daemon's answer is missing


class DaemonSilent(DaemonUnreachable):
    """The daemon took the connection or the request and did not answer in time: it may be
    alive, frozen or overloaded."""


class Refused(CommandRejected):
    """An error reply: the daemon's sentence, and its state when the reply carries one."""

    def __init__(self, error: str, state: str | None = None) -> None:
        super().__init__(error)
        self.state = state


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
            raise DaemonSilent(f"the rakectl daemon at {self.path} did not answer within "
                               f"{self._timeout_s:g} s (busy, frozen or stuck): "
                               f"{CHECK_STATUS}") from exc
        except OSError as exc:
            self.close()
            raise DaemonUnreachable(f"lost the connection to the rakectl daemon at {self.path}: "
                                    f"{exc.strerror or exc}: {CHECK_STATUS}") from exc

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
                                        "connection without answering (it ended or restarted; "
                                        f"a daemon that starts again starts disarmed): "
                                        f"{CHECK_STATUS}")
            self._inbuf += chunk
            if len(self._inbuf) > MAX_REPLY_BYTES:
                raise ApiError(f"the reply of the daemon at {self.path} is over "
                               f"{MAX_REPLY_BYTES} bytes")
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
        unreachable = DaemonSilent if isinstance(exc, TimeoutError | BlockingIOError) \
            else DaemonUnreachable
        raise unreachable(f"cannot reach the rakectl daemon at {path}: "
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
        raise ApiError(f"unusable reply from the rakectl daemon at {path}: {show(reply)}")
    if not reply["ok"]:
        state = reply.get("state")
        raise Refused(str(reply.get("error") or "the daemon refused without a reason"),
                      state if isinstance(state, str) else None)
    return reply
