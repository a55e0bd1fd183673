"""The daemon's command API on a Unix socket: the non-blocking server.

The 1 kHz loop owns the server's thread: it calls :meth:`CommandServer.poll` in the
slack of a tick with a time budget, and poll never blocks. Requests are decoded and
validated by :mod:`rakectl.api.schema`; the socket is set up, and its peers checked by
their credentials, by :mod:`rakectl.api.endpoint`.
"""

from __future__ import annotations

import collections
import contextlib
import os
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from rakectl.api.endpoint import group_name, listen, peer_allowed, peer_of
from rakectl.api.replies import error_reply, ok_reply, sentence
from rakectl.api.schema import (
    MAX_REQUEST_BYTES,
    ErrorKind,
    Handler,
    Peer,
    Refusal,
    Request,
    decode_request,
    too_large_message,
)
from rakectl.errors import RakeError

MAX_CLIENTS = 16
MAX_BACKLOG_BYTES = 256 * 1024  # replies queued for a client that does not read them
IDLE_TIMEOUT_S = 60.0  # a client silent this long is closed
EVICT_IDLE_S = 1.0  # with every slot taken, a client silent this long makes room for a new one
_RECV_BYTES = 8192
_POLLIN = select.POLLIN
_POLLOUT = select.POLLOUT


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
        self._listener = listen(self.path, group, max_clients)
        st = os.stat(self.path)
        self._identity, self._socket_gid = (st.st_dev, st.st_ino), st.st_gid
        self._group_name, self._uid = group_name(st.st_gid), os.geteuid()
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
            peer = peer_of(sock)
        except OSError:
            self._count(ErrorKind.SOCKET)
            sock.close()
            return
        if not peer_allowed(peer, self._uid, self._socket_gid):
            self._turn_away(sock, ErrorKind.PERMISSION, f"permission denied: uid {peer.uid} is "
                            f"not root, not the daemon's user and not in group {self._group_name}")
        elif len(self._conns) >= self._max_clients and not self._evict_idle():
            self._turn_away(sock, ErrorKind.BUSY,
                            f"too many clients (limit {self._max_clients}); try again later")
        else:
            self._serial += 1
            conn = _Conn(sock, sock.fileno(), self._serial, peer, self._clock())
            self._conns[conn.fd] = conn
            self._poller.register(conn.fd, _POLLIN)
            self.stats.accepted += 1
            self.stats.clients = len(self._conns)

    def _evict_idle(self) -> bool:
        """Make room for a new client by closing the one idle longest, if it has been idle
        EVICT_IDLE_S or more (forgotten connections must not keep an e-stop out; clients
        in use, a jog's dead-man or an excavation followed, are never idle that long)."""
        now_s = self._clock()
        idlest = min(self._conns.values(), key=lambda c: c.last_active_s, default=None)
        if idlest is None or now_s - idlest.last_active_s < EVICT_IDLE_S or idlest.outbuf:
            return False
        self._count(ErrorKind.IDLE)
        self._close(idlest)
        return True

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
            if conn.inbuf.strip():  # a last request without its newline: said, not dropped
                conn.lines.append(Refusal(ErrorKind.MALFORMED, "incomplete request at the end "
                                          "of input (a request ends with a newline)"))
                self._ready.append(conn)
            conn.closing, conn.inbuf = True, bytearray()
            self._watch(conn)
            if not conn.outbuf and not conn.lines:
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
        try:
            result = line if isinstance(line, Refusal) else decode_request(line, conn.serial,
                                                                           conn.peer)
        except Exception as exc:  # a bug in the validation must not end the loop either
            result = Refusal(ErrorKind.INTERNAL,
                             f"internal error: {type(exc).__name__} reading the request")
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
            return error_reply(sentence(exc), request.id)
        except Exception as exc:  # a bug in the handler must not end the server
            self._count(ErrorKind.INTERNAL)
            error = f"internal error: {type(exc).__name__}: {sentence(exc)}"
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
