"""sd_notify: a test-owned datagram socket plays systemd."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from rakectl.daemon.sdnotify import Notifier


@pytest.fixture
def systemd(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound where NOTIFY_SOCKET would point, and that address."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = tmp_path / "notify"
    sock.bind(str(path))
    sock.settimeout(1.0)
    yield sock, str(path)
    sock.close()


def _received(sock: socket.socket, count: int) -> list[str]:
    return [sock.recv(4096).decode() for _ in range(count)]


def test_messages_arrive_in_order(systemd: tuple[socket.socket, str]) -> None:
    sock, address = systemd
    notifier = Notifier.from_environ({"NOTIFY_SOCKET": address})
    assert notifier.enabled and notifier.problem is None
    assert notifier.ready()
    assert notifier.status("armed,\n  jogging")
    assert notifier.watchdog()
    assert notifier.stopping()
    notifier.close()
    assert _received(sock, 4) == ["READY=1", "STATUS=armed, jogging", "WATCHDOG=1", "STOPPING=1"]
    assert (notifier.sent, notifier.errors) == (4, 0)


def test_ready_with_status_is_one_datagram(systemd: tuple[socket.socket, str]) -> None:
    sock, address = systemd
    notifier = Notifier(address)
    notifier.ready("listening on /run/rakectl/rakectl.sock")
    notifier.close()
    assert _received(sock, 1) == ["READY=1\nSTATUS=listening on /run/rakectl/rakectl.sock"]


def test_abstract_namespace_address() -> None:
    name = f"rakectl-test-{os.getpid()}-{id(object())}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        sock.bind("\0" + name)
        sock.settimeout(1.0)
        notifier = Notifier(f"@{name}")
        assert notifier.ready()
        notifier.close()
        assert sock.recv(64) == b"READY=1"
    finally:
        sock.close()


def test_watchdog_only_when_the_tick_counter_advanced(systemd: tuple[socket.socket, str]) -> None:
    sock, address = systemd
    notifier = Notifier(address)
    sent = [notifier.watchdog(ticks) for ticks in (0, 0, 5, 5, 4, 6)]
    notifier.close()
    assert sent == [True, False, True, False, False, True]
    assert _received(sock, 3) == ["WATCHDOG=1"] * 3


def test_disabled_without_notify_socket() -> None:
    notifier = Notifier.from_environ({})
    assert not notifier.enabled and notifier.problem is None
    assert not any([notifier.ready(), notifier.status("x"), notifier.watchdog(),
                    notifier.stopping()])
    assert (notifier.sent, notifier.errors) == (0, 0)
    assert notifier.watchdog_interval_s() is None


def test_send_failures_are_counted_not_raised(tmp_path: Path) -> None:
    notifier = Notifier(str(tmp_path / "nobody-listens"))
    assert notifier.enabled
    assert not notifier.ready()
    assert not notifier.watchdog()
    assert (notifier.sent, notifier.errors) == (0, 2)
    notifier.close()


def test_full_receiver_does_not_block(systemd: tuple[socket.socket, str]) -> None:
    _, address = systemd
    notifier = Notifier(address)
    for _ in range(5000):  # nobody reads: the queue fills, sends fail at once
        notifier.status("x" * 200)
    notifier.close()
    assert notifier.errors > 0 and notifier.sent + notifier.errors == 5000


def test_unsupported_address_is_reported() -> None:
    notifier = Notifier("vsock:2:1234")
    assert not notifier.enabled
    assert notifier.problem is not None and "vsock:2:1234" in notifier.problem
    assert not notifier.ready()


@pytest.mark.parametrize(
    ("usec", "pid", "expected_s"),
    [("500000", None, 0.5), ("2000000", "OWN", 2.0), ("500000", "1", None), ("0", None, None),
     ("soon", None, None), (None, None, None)],
)
def test_watchdog_interval(usec: str | None, pid: str | None, expected_s: float | None) -> None:
    own = str(os.getpid()) if pid == "OWN" else pid
    environ = {k: v for k, v in {"WATCHDOG_USEC": usec, "WATCHDOG_PID": own}.items() if v}
    assert Notifier.from_environ(environ).watchdog_interval_s() == expected_s
