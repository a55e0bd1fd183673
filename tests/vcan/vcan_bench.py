"""The emulated bench on real SocketCAN: emulator and daemon as two processes on vcan0.

Unlike :func:`rakectl.sim.rig.emulated_bench` (udp_multicast inside a
private network namespace), the processes run in the test's own network
namespace, where vcan0 is: a Linux machine with vcan0, or the VM that
``tests/vcan/run-in-vm.sh`` boots. The caller talks to the daemon over its
Unix socket, as on the other bench.

Also here: why SocketCAN is unusable (the tests' skip reason), a recorder of
every frame on the wire (a socket of the test's own), and decoders of a
candump ``.log`` trace: the DBC for the cyclic frames, CiA 301 for SDO.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import can
import cantools

from rakectl.errors import ApiError, CommsTimeout, RakeError
from rakectl.protocol.files import DBC_PATH
from rakectl.sim.rig import Bench

CHANNEL = "vcan0"
ROOT = Path(__file__).resolve().parents[2]
DBC = DBC_PATH
DAEMON_NICE, EMULATOR_NICE = 10, -5  # the emulator first (see vcan_bench)
START_TIMEOUT_S = 240.0  # both processes started and the daemon disarmed (Python is slow in a VM)
# The daemon serves requests in the slack its tick leaves (rakectl.daemon.slack); under
# emulation the emulator can fall behind the lock-step SYNCs and the loop overrun for
# seconds, so an answer may wait longer than the 2 s an operator's CLI allows
REQUEST_TIMEOUT_S = 15.0
IN_VM = "run tests/vcan/run-in-vm.sh (it boots a kernel with SocketCAN in a VM)"
CREATE = ("`sudo modprobe vcan && sudo ip link add dev {0} type vcan && "
          "sudo ip link set up {0}`")


def vcan_unavailable(channel: str = CHANNEL) -> str | None:
    """Why the tests cannot use SocketCAN on ``channel`` here, or None if they can."""
    if not hasattr(socket, "AF_CAN"):
        return f"this Python has no socket.AF_CAN (not Linux?); {IN_VM}"
    try:
        probe = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as error:
        return f"this kernel has no SocketCAN ({error.strerror or error}); {IN_VM}"
    with probe:
        try:
            probe.bind((channel,))
        except OSError as error:
            return (f"no {channel} ({error.strerror or error}): create it with "
                    f"{CREATE.format(channel)}, or {IN_VM}")
    flags = Path(f"/sys/class/net/{channel}/flags")
    if flags.exists() and not int(flags.read_text(), 16) & 0x1:  # IFF_UP
        return f"{channel} is down: `sudo ip link set up {channel}`"
    return None


@dataclass
class VcanBench(Bench):
    """A running bench on vcan0: ``process`` is the daemon, ``emulator`` the drives."""

    emulator: subprocess.Popen[bytes]
    request_timeout_s: ClassVar[float] = REQUEST_TIMEOUT_S

    def alive(self) -> None:
        """Raise, naming the logs, if either process has ended."""
        for name, process in (("daemon", self.process), ("emulator", self.emulator)):
            if process.poll() is not None:
                raise RakeError(f"the {name} stopped (exit {process.returncode}); see "
                                f"{self.out}/daemon.log and {self.out}/emulator.log")

    def wait_for_state(self, states: Sequence[str], timeout_s: float) -> dict[str, object]:
        """Poll status every 0.5 s (each request costs CPU under emulation) until the
        daemon is in one of ``states``; CommsTimeout otherwise, RakeError if a process ended."""
        deadline, reply = time.monotonic() + timeout_s, {}
        while time.monotonic() < deadline:
            with contextlib.suppress(ApiError):
                reply = self.request("status")
                if reply.get("state") in states:
                    return reply
            self.alive()
            time.sleep(0.5)
        raise CommsTimeout(f"daemon not {'/'.join(states)} within {timeout_s:g} s "
                           f"(last: {reply.get('state')}); see {self.out}/daemon.log")

    def wait_for_log(self, name: str, text: str, count: int, timeout_s: float) -> list[str]:
        """Poll ``out/name`` until ``count`` lines contain ``text``; CommsTimeout otherwise."""
        deadline = time.monotonic() + timeout_s
        while True:
            path = self.out / name
            lines = ([line for line in path.read_text().splitlines() if text in line]
                     if path.exists() else [])
            if len(lines) >= count:
                return lines
            if time.monotonic() > deadline:
                raise CommsTimeout(f"{count} line(s) with {text!r} not in {path} within "
                                   f"{timeout_s:g} s (found {len(lines)})")
            time.sleep(0.2)


def _start(args: Sequence[str], log: Path, nice: int = 0, **env: str
           ) -> subprocess.Popen[bytes]:
    prefix = ["nice", "-n", str(nice)] if nice else []
    with open(log, "wb") as out:
        return subprocess.Popen([*prefix, sys.executable, *args], stdout=out,
                                stderr=subprocess.STDOUT,
                                env=dict(os.environ, PYTHONUNBUFFERED="1", **env),
                                process_group=0)  # its own group: killpg ends it and its children


@contextlib.contextmanager
def vcan_bench(out: Path, emulator_config: Path, daemon_config: Path,
               emulator_args: Sequence[str] = (), daemon_args: Sequence[str] = (),
               emulator_at_bring_up: bool = False) -> Iterator[VcanBench]:
    """Start the emulator and the daemon on vcan0; stop both on exit.

    Both start at once (their imports take many seconds under emulation; the
    daemon's bring-up waits ``daemon.boot_timeout_s`` for the drives' first
    heartbeat). With ``emulator_at_bring_up``, the emulator starts only once
    the daemon is on the bus, waiting for the drives (its sd_notify status
    "bringing up the drives", on a socket of the bench's own): the emulator's
    clock, which times injected faults (``faults.silence_after_s``), then
    starts with the bring-up however slow the daemon's start was.

    The emulator runs at a higher CPU priority than the daemon (nice -5 as
    root, else 0; the daemon 10): a late tick only delays the next SYNC, which
    the lock-stepped physics waits for, but a late emulator answers late, and
    the daemon works on stale feedback (a tip still moving looks settled).

    On exit: ``shutdown`` to the daemon if it still runs, then SIGTERM to the
    emulator, which flushes its ground truth (truth.csv).
    """
    out.mkdir(parents=True, exist_ok=True)
    socket_path, notify_path = out / "rakectl.sock", out / "notify.sock"
    daemon_cmd = ["-m", "rakectl", "run", "--config", str(daemon_config),
                  "--set", f"daemon.socket_path={socket_path}",
                  "--set", f"daemon.dump_dir={out}", *daemon_args]
    emulator_cmd = ["-m", "drivers", "--config", str(emulator_config),
                    "--truth", str(out / "truth.csv"), *emulator_args]
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as notify:
        env = {}
        if emulator_at_bring_up:
            notify.bind(str(notify_path))
            env["NOTIFY_SOCKET"] = str(notify_path)
        daemon = _start(daemon_cmd, out / "daemon.log", nice=DAEMON_NICE, **env)
        emulator: subprocess.Popen[bytes] | None = None
        try:
            if emulator_at_bring_up:
                _wait_for_bring_up(daemon, notify, out)
            emulator = _start(emulator_cmd, out / "emulator.log",
                              nice=EMULATOR_NICE if os.geteuid() == 0 else 0)
            yield VcanBench(out, socket_path, daemon, emulator)
        finally:
            _stop_daemon(daemon, socket_path)
            if emulator is not None:
                _terminate(emulator)


def _wait_for_bring_up(daemon: subprocess.Popen[bytes], notify: socket.socket,
                       out: Path) -> None:
    notify.settimeout(0.2)
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        with contextlib.suppress(TimeoutError):
            if b"bringing up" in notify.recv(4096):
                return
        if daemon.poll() is not None:
            raise RakeError(f"the daemon stopped (exit {daemon.returncode}); "
                            f"see {out}/daemon.log")
    raise CommsTimeout(f"the daemon did not start its bring-up within {START_TIMEOUT_S:g} s; "
                       f"see {out}/daemon.log")


def _stop_daemon(daemon: subprocess.Popen[bytes], socket_path: Path) -> None:
    if daemon.poll() is None:
        with contextlib.suppress(ApiError):
            Bench(socket_path.parent, socket_path, daemon).request("shutdown")
        with contextlib.suppress(subprocess.TimeoutExpired):
            daemon.wait(60.0)
    _terminate(daemon)


def _terminate(process: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after 60 s, to the process's own process group."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(60.0)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


class WireRecorder:
    """Every frame on ``channel`` to a candump .log, from a socket of the test's own.

    No receive filter (everything on the wire); a :class:`can.Notifier` thread
    writes the frames. Stop it with :meth:`close` (it costs CPU under emulation).
    """

    def __init__(self, path: Path, channel: str = CHANNEL) -> None:
        self.path = path
        self._bus = can.Bus(interface="socketcan", channel=channel)
        self._writer = can.CanutilsLogWriter(str(path), channel=channel)
        self._notifier = can.Notifier(self._bus, [self._writer], timeout=0.2)
        self._closed = False

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._notifier.stop()
            self._writer.stop()
            self._bus.shutdown()

    def __enter__(self) -> WireRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- decoding


def read_trace(path: Path) -> list[can.Message]:
    """The frames of a candump .log file, in order."""
    return list(can.CanutilsLogReader(str(path)))


def load_dbc() -> Any:
    return cantools.database.load_file(str(DBC))


@dataclass(frozen=True)
class SdoExchange:
    """One expedited SDO request and its reply (CiA 301), as seen on the wire."""

    node_id: int
    write: bool  # download (write) or upload (read)
    index: int
    subindex: int
    value: int | None  # written, or read back; None for an abort
    abort_code: int | None


def sdo_exchanges(frames: Sequence[can.Message]) -> list[SdoExchange]:
    """Pair each SDO request (0x600+n) with the next reply (0x580+n) of the same node.

    Values of expedited transfers only (what bring-up uses: at most 4 bytes).
    """
    pending: dict[int, can.Message] = {}
    result: list[SdoExchange] = []
    for msg in frames:
        can_id, data = msg.arbitration_id, bytes(msg.data)
        if 0x601 <= can_id <= 0x67F and len(data) == 8:
            pending[can_id - 0x600] = msg
        elif 0x581 <= can_id <= 0x5FF and len(data) == 8 and (can_id - 0x580) in pending:
            node_id = can_id - 0x580
            request = bytes(pending.pop(node_id).data)
            write = request[0] >> 5 == 1  # ccs 1: initiate download
            index, subindex = int.from_bytes(request[1:3], "little"), request[3]
            if data[0] == 0x80:
                result.append(SdoExchange(node_id, write, index, subindex, None,
                                          int.from_bytes(data[4:8], "little")))
                continue
            source = request if write else data
            size = 4 - ((source[0] >> 2) & 0x3) if source[0] & 0x1 else 4
            result.append(SdoExchange(node_id, write, index, subindex,
                                      int.from_bytes(source[4:4 + size], "little"), None))
    return result
