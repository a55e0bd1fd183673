"""sd_notify(3) without libsystemd: READY, STATUS, WATCHDOG and STOPPING for systemd.

One datagram per message to ``$NOTIFY_SOCKET`` (a path, or ``@name`` in the abstract
namespace), sent without blocking. Without NOTIFY_SOCKET every call does nothing; a
failed send is counted, never raised, so the control loop can call it in its slack.
The composition root reads the environment and passes it to :meth:`Notifier.from_environ`.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping


class Notifier:
    """The service's line to systemd (Type=notify, WatchdogSec=)."""

    def __init__(self, address: str | None, watchdog_usec: str | None = None,
                 watchdog_pid: str | None = None, pid: int | None = None) -> None:
        self.sent = 0
        self.errors = 0
        self.problem: str | None = None  # why notifications are off although asked for
        self._interval_s = _interval_s(watchdog_usec, watchdog_pid, os.getpid() if pid is None
                                       else pid)
        self._last_ticks: int | None = None
        self._address = _address(address) if address else None
        self._sock: socket.socket | None = None
        if address and self._address is None:
            self.problem = f"NOTIFY_SOCKET={address!r} is neither a path nor @abstract"
        elif self._address is not None:
            self._sock = self._open()

    @classmethod
    def from_environ(cls, environ: Mapping[str, str]) -> Notifier:
        return cls(environ.get("NOTIFY_SOCKET"), environ.get("WATCHDOG_USEC"),
                   environ.get("WATCHDOG_PID"))

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def ready(self, status: str | None = None) -> bool:
        return self.notify("READY=1", *(() if status is None else (_status(status),)))

    def status(self, text: str) -> bool:
        return self.notify(_status(text))

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def extend_start(self, seconds: float, status: str) -> bool:
        """A start-up phase that may take up to ``seconds``: systemd's start timeout
        (TimeoutStartSec) is extended to that from now (EXTEND_TIMEOUT_USEC, systemd 236
        and later), so that the phase ends with the daemon's own word on it."""
        return self.notify(f"EXTEND_TIMEOUT_USEC={round(seconds * 1e6)}", _status(status))

    def watchdog(self, ticks: int | None = None) -> bool:
        """Send WATCHDOG=1; given the loop's tick counter, only if it advanced since."""
        if ticks is not None:
            if self._last_ticks is not None and ticks <= self._last_ticks:
                return False
            self._last_ticks = ticks
        return self.notify("WATCHDOG=1")

    def watchdog_interval_s(self) -> float | None:
        """WatchdogSec= of the service (kick at half of it), or None when off or not ours."""
        return self._interval_s

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=value`` lines as one datagram; True if it went out."""
        if self._sock is None or self._address is None:
            return False
        try:
            self._sock.sendto("\n".join(assignments).encode(), self._address)
        except OSError:  # full queue (BlockingIOError), systemd gone, …: never into the loop
            self.errors += 1
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _open(self) -> socket.socket | None:
        try:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            sock.setblocking(False)
        except OSError as exc:
            self.errors += 1
            self.problem = f"cannot create the notification socket: {exc.strerror or exc}"
            return None
        return sock


def _address(value: str) -> str | None:
    if value.startswith("@"):
        return "\0" + value[1:]  # Linux abstract namespace
    return value if value.startswith("/") else None


def _status(text: str) -> str:
    return "STATUS=" + " ".join(text.split())


def _interval_s(usec: str | None, pid: str | None, own_pid: int) -> float | None:
    if not usec or (pid and pid.strip() != str(own_pid)):
        return None
    try:
        microseconds = int(usec)
    except ValueError:
        return None
    return microseconds / 1e6 if microseconds > 0 else None
