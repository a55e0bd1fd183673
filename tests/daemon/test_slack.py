"""The slack's work while the loop overruns: with no slack at all, requests are still
answered, an e-stop among them, within a bounded number of ticks, and systemd's watchdog
is still kicked (the lock-step rig's daemon and emulated drives, the daemon's own server
on a real Unix socket, sd_notify datagrams to a real socket)."""

from __future__ import annotations

import contextlib
import json
import socket
import time
from pathlib import Path

from rakectl.api.schema import Request, decode_request
from rakectl.api.server import CommandServer
from rakectl.bench.tick import LockstepRig
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.slack import STARVED_POLL_INTERVAL_S
from rakectl.daemon.states import DaemonState


def _overrunning_ticks_until_answered(rig: LockstepRig, sock: socket.socket,
                                      limit: int) -> tuple[int, bytes]:
    """Tick and run the slack, each time past the next deadline, until a whole reply
    line arrives; returns the ticks it took and the line."""
    daemon, reply = rig.daemon, b""
    for tick in range(1, limit + 1):
        rig.tick()
        # The lock-step rig's timer never started: every deadline is long past, so the
        # slack begins with no budget, as after a tick that overran.
        assert daemon.timer.deadline_of(daemon.timer.tick_index + 1) < time.monotonic_ns()
        daemon.slack()
        with contextlib.suppress(BlockingIOError):
            reply += sock.recv(4096)
        if reply.endswith(b"\n"):
            return tick, reply
    raise AssertionError(f"no answer in {limit} ticks with no slack (got {reply!r})")


def test_an_estop_is_answered_and_obeyed_while_every_tick_overruns(tmp_path: Path) -> None:
    rig = LockstepRig(tmp_path)
    daemon = rig.daemon
    systemd = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    systemd.bind(str(tmp_path / "notify"))
    systemd.setblocking(False)
    daemon.notifier = Notifier(str(tmp_path / "notify"))
    interval = round(STARVED_POLL_INTERVAL_S * daemon.settings.rate_hz)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        arm = decode_request(b'{"cmd": "arm"}')
        assert isinstance(arm, Request)
        make_handler(daemon)(arm)
        rig.until(DaemonState.ARMED, 8000)
        with CommandServer(tmp_path / "rakectl.sock", None, make_handler(daemon)) as server, \
                socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            daemon.slack_hook = server.poll
            sock.connect(str(tmp_path / "rakectl.sock"))
            sock.setblocking(False)
            sock.sendall(b'{"cmd": "status"}\n')
            # a new connection: one poll accepts it, the next answers
            ticks, line = _overrunning_ticks_until_answered(rig, sock, 3 * interval)
            assert ticks <= interval + 1, ticks
            assert json.loads(line)["state"] == "armed"
            sock.sendall(b'{"cmd": "estop"}\n')
            ticks, line = _overrunning_ticks_until_answered(rig, sock, 3 * interval)
            assert ticks <= interval, ticks  # an open connection: one poll
            assert json.loads(line)["ok"] is True
            assert daemon.state is DaemonState.ESTOP
            rig.tick()
            assert daemon.voltages == (0.0, 0.0)
        while True:  # what the daemon told systemd so far
            try:
                systemd.recv(4096)
            except BlockingIOError:
                break
        rate_hz = daemon.settings.rate_hz
        for _ in range(round(0.5 * rate_hz)):  # 0.5 s of ticks, none with slack
            rig.tick()
            daemon.slack()
        kicks = []
        with contextlib.suppress(BlockingIOError):
            while True:
                kicks.append(systemd.recv(4096))
        assert kicks.count(b"WATCHDOG=1") >= 4, kicks  # every 0.1 s: slow, not stuck
    finally:
        rig.close()
        systemd.close()
