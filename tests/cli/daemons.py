"""Daemons on a real Unix socket for the operator's commands run as processes: one that
answers each request as a test says (late, never, or after a restart), and the
project's own daemon in-process (the lock-step rig, its command server polled each
tick in a thread)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import selectors
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from rakectl.api.client import call
from rakectl.api.server import CommandServer
from rakectl.bench.tick import LockstepRig
from rakectl.config.settings import Settings
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.states import DaemonState

Answer = Callable[[dict[str, Any]], dict[str, Any] | None]


@dataclasses.dataclass
class _Connection:
    sock: socket.socket
    inbuf: bytes = b""
    due: list[tuple[float, bytes]] = dataclasses.field(default_factory=list)  # (time, line)


class AnsweringDaemon:
    """A Unix socket that answers each request line with ``answer(request)`` (the reply's
    fields; ``"ok"`` is true unless given), ``delay_s`` after it came, or never when
    ``answer`` returns None (a daemon frozen). Records the requests' commands; serves
    every connection at once from one thread."""

    def __init__(self, path: Path, answer: Answer, delay_s: float = 0.0) -> None:
        self.path, self.answer, self.delay_s = path, answer, delay_s
        self.requests: list[str] = []
        self.received_s: list[float] = []  # when each request came (monotonic)
        self.answered = 0
        self._lock = threading.Lock()
        self._selector = selectors.DefaultSelector()
        self._conns: dict[socket.socket, _Connection] = {}
        self._server: socket.socket | None = None
        self._listen()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="answering-daemon")
        self._thread.start()

    def __enter__(self) -> AnsweringDaemon:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _listen(self) -> None:
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(str(self.path))
        server.listen(8)
        server.setblocking(False)
        self._selector.register(server, selectors.EVENT_READ)
        self._server = server

    def restart(self, answer: Answer) -> None:
        """Close every connection and answer with ``answer`` from now on (a new daemon)."""
        with self._lock:
            self.answer = answer
            for sock in list(self._conns):
                self._drop(sock)

    def drop_connections(self) -> None:
        """Close every connection; the same daemon goes on listening."""
        self.restart(self.answer)

    def gone(self) -> None:
        """Close every connection and the socket, and remove its file (the daemon ended)."""
        with self._lock:
            for sock in list(self._conns):
                self._drop(sock)
            if self._server is not None:
                self._selector.unregister(self._server)
                self._server.close()
                self._server = None
                self.path.unlink()

    def _drop(self, sock: socket.socket) -> None:
        self._selector.unregister(sock)
        del self._conns[sock]
        sock.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            events = self._selector.select(0.01)
            with self._lock:
                for key, _ in events:
                    self._on_readable(key.fileobj)  # type: ignore[arg-type]
                self._send_due()

    def _on_readable(self, sock: socket.socket) -> None:
        if sock is self._server:
            conn, _ = sock.accept()
            conn.setblocking(False)
            self._selector.register(conn, selectors.EVENT_READ)
            self._conns[conn] = _Connection(conn)
            return
        connection = self._conns.get(sock)
        if connection is None:
            return
        try:
            data = sock.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._drop(sock)
            return
        connection.inbuf += data
        *lines, connection.inbuf = connection.inbuf.split(b"\n")
        for line in lines:
            request = json.loads(line)
            self.requests.append(request["cmd"])
            self.received_s.append(time.monotonic())
            reply = self.answer(request)
            if reply is not None:
                line_out = json.dumps({"ok": True, **reply}).encode() + b"\n"
                connection.due.append((time.monotonic() + self.delay_s, line_out))

    def _send_due(self) -> None:
        now_s = time.monotonic()
        for sock, connection in list(self._conns.items()):
            while connection.due and connection.due[0][0] <= now_s:
                _, line = connection.due.pop(0)
                with contextlib.suppress(OSError):
                    sock.sendall(line)
                self.answered += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        with self._lock:
            for sock in list(self._conns):
                self._drop(sock)
            if self._server is not None:
                self._server.close()
        self._selector.close()


class InProcessDaemon:
    """The daemon of the lock-step rig (emulated drives, its own handler) behind its
    command server on a real Unix socket at ``path``, ticked in a thread."""

    def __init__(self, directory: Path, settings: Settings | None = None) -> None:
        self.path = directory / "rakectl.sock"
        self.rig = LockstepRig(directory, settings)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="in-process-daemon")
        self._server: CommandServer | None = None

    def start(self) -> None:
        """Bring the drives up, open the socket, tick; then arm (over the socket)."""
        self.rig.bring_up()
        self.rig.until(DaemonState.DISARMED, 3000)
        daemon = self.rig.daemon
        self._server = CommandServer(self.path, None, make_handler(daemon))
        daemon.connected = self._server.is_connected  # as the service wires it
        self._thread.start()
        self.request("arm")
        self.wait_for("armed", 60.0)

    def _run(self) -> None:
        assert self._server is not None
        while not self._stop.is_set():
            self.rig.tick()
            self._server.poll(0.001)

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        return call(self.path, {"cmd": cmd, **args}, timeout_s=10.0)

    def wait_for(self, state: str, timeout_s: float) -> dict[str, Any]:
        deadline_s = time.monotonic() + timeout_s
        while True:
            reply = self.request("status")
            if reply["state"] == state:
                return reply
            if time.monotonic() > deadline_s:
                raise AssertionError(f"the daemon is {reply['state']}, not {state} "
                                     f"({reply.get('fault')})")
            time.sleep(0.02)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(10.0)
        if self._server is not None:
            self._server.close()
        self.rig.close()


@contextlib.contextmanager
def in_process_daemon(directory: Path, settings: Settings | None = None
                      ) -> Iterator[InProcessDaemon]:
    daemon = InProcessDaemon(directory, settings)
    try:
        daemon.start()
        yield daemon
    finally:
        daemon.close()
