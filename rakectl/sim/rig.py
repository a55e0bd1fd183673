"""An emulated bench: the emulator and the daemon as separate processes on one bus.

This machine kind has no SocketCAN, so the bus is python-can's udp_multicast
inside a private network namespace made for the purpose (``unshare -n`` as root, ``unshare -rn``
otherwise: no root needed): traffic never leaves it. Both processes run inside; the caller
stays outside and talks to the daemon over its Unix socket (file-system
sockets are not namespaced). Used by ``rakectl demo`` and the cross-process
tests.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from rakectl.api.client import call
from rakectl.errors import ApiError, CommsTimeout, RakeError

NAMESPACE_SETUP = ("ip link set lo up && ip link set lo multicast on && "
                   "ip route add 224.0.0.0/4 dev lo")
_SCRIPT = """\
set -u
{setup} || {{ echo "bench: cannot set up the namespace's loopback multicast" >&2; exit 3; }}
$EMU_PREFIX "$PY" -m "$EMU_MODULE" --config "$EMU_CONFIG" --truth "$OUT/truth.csv" $EMU_ARGS \\
    > "$OUT/emulator.log" 2>&1 &
EMU=$!
trap 'kill -TERM $EMU 2>/dev/null; kill -TERM $DMN 2>/dev/null' TERM INT
for _ in $(seq 200); do
    grep -q "emulator: ready" "$OUT/emulator.log" 2>/dev/null && break
    kill -0 $EMU 2>/dev/null || {{ echo "bench: the emulator died" >&2; exit 4; }}
    sleep 0.1
done
"$PY" -m rakectl run --config "$DAEMON_CONFIG" --set daemon.socket_path="$SOCK" \\
    --set daemon.dump_dir="$OUT" $DAEMON_ARGS > "$OUT/daemon.log" 2>&1 &
DMN=$!
wait $DMN
rc=$?
sleep 1  # the drives outlive the controller: let their watchdogs act and be recorded
kill -TERM $EMU 2>/dev/null
wait $EMU
exit $rc
"""


def unshare_command() -> list[str]:
    """A new network namespace; as root keep real root (SCHED_FIFO, mlockall work inside),
    otherwise map the user to root in a new user namespace (no privileges needed)."""
    return ["unshare", "-n"] if os.geteuid() == 0 else ["unshare", "-rn"]


def namespaces_unavailable() -> str | None:
    """Why a private network namespace cannot be made here, or None if it can."""
    for tool in ("unshare", "ip"):
        if shutil.which(tool) is None:
            return f"`{tool}` is not installed (util-linux / iproute2)"
    probe = subprocess.run([*unshare_command(), "sh", "-c", NAMESPACE_SETUP],
                           capture_output=True, text=True, timeout=20)
    if probe.returncode != 0:
        return f"cannot create a network namespace: {probe.stderr.strip() or probe.returncode}"
    return None


@dataclass
class Bench:
    """A running bench: where its files are and how to reach the daemon."""

    out: Path
    socket: Path
    process: subprocess.Popen[bytes]
    request_timeout_s: ClassVar[float] = 2.0  # how long a request waits for the answer

    def request(self, cmd: str, **args: object) -> dict[str, object]:
        return call(self.socket, {"cmd": cmd, **args}, self.request_timeout_s)

    def arm_when_timed(self, timeout_s: float) -> dict[str, object]:
        """Arm, asking again while the daemon is still measuring its own timing (with
        rt_mode enforce it arms only after daemon.arm_timing_s of ticks)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return self.request("arm")
            except ApiError as error:
                if "measured its timing" not in str(error) or time.monotonic() > deadline:
                    raise
            time.sleep(0.2)

    def wait_for_state(self, states: Sequence[str], timeout_s: float) -> dict[str, object]:
        """Poll status until the daemon is in one of ``states``; CommsTimeout otherwise."""
        deadline, reply = time.monotonic() + timeout_s, {}
        while time.monotonic() < deadline:
            with contextlib.suppress(ApiError):
                reply = self.request("status")
                if reply.get("state") in states:
                    return reply
            if self.process.poll() is not None:
                said = "; ".join(f"{log}: {line}" for log in ("daemon.log", "emulator.log")
                                 if (line := _last_line(self.out / log)))
                raise RakeError(f"the bench stopped (exit {self.process.returncode})"
                                f"{': ' + said if said else ''}; see {self.out}/daemon.log "
                                f"and {self.out}/emulator.log")
            time.sleep(0.1)
        raise CommsTimeout(f"daemon not {'/'.join(states)} within {timeout_s:g} s "
                           f"(last: {reply.get('state')}); see {self.out}/daemon.log")


def _last_line(path: Path) -> str:
    """The last non-empty line of a log, cut to 300 characters ("" if none)."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    return next((line.strip()[:300] for line in reversed(lines) if line.strip()), "")


@contextlib.contextmanager
def emulated_bench(out: Path, emulator_config: Path, daemon_config: Path,
                   emulator_args: Sequence[str] = (), daemon_args: Sequence[str] = (),
                   stop_timeout_s: float = 20.0, emulator_rt_priority: int = 0,
                   emulator_module: str = "drivers") -> Iterator[Bench]:
    """Start emulator + daemon in a fresh namespace; stop both (SIGTERM) on exit.

    ``emulator_module`` is run as ``python -m MODULE --config FILE --truth CSV ARGS`` and
    prints ``emulator: ready`` once its drives are on the bus: the emulator by default,
    or any other slave that takes the same command line.

    ``emulator_rt_priority`` > 0 runs the emulator at that SCHED_FIFO priority
    (``chrt``): needed when the daemon runs real-time on the same cores, or the
    emulated drives miss frames and their watchdogs fire.
    """
    out.mkdir(parents=True, exist_ok=True)
    socket_path = out / "rakectl.sock"
    script = out / "bench.sh"
    script.write_text(_SCRIPT.format(setup=NAMESPACE_SETUP))
    env = dict(os.environ, PY=sys.executable, OUT=str(out), SOCK=str(socket_path),
               EMU_MODULE=emulator_module,
               EMU_CONFIG=str(emulator_config), DAEMON_CONFIG=str(daemon_config),
               EMU_ARGS=" ".join(emulator_args), DAEMON_ARGS=" ".join(daemon_args),
               EMU_PREFIX=f"chrt -f {emulator_rt_priority}" if emulator_rt_priority > 0 else "")
    process = subprocess.Popen([*unshare_command(), "sh", str(script)], env=env,
                               process_group=0)  # its own group: killpg ends it and its children
    bench = Bench(out, socket_path, process)
    try:
        yield bench
    finally:
        _stop(bench, stop_timeout_s)


def _stop(bench: Bench, timeout_s: float) -> None:
    if bench.process.poll() is None:
        with contextlib.suppress(ApiError):
            bench.request("shutdown")
        try:
            bench.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(bench.process.pid, signal.SIGTERM)
            try:
                bench.process.wait(5.0)
            except subprocess.TimeoutExpired:
                os.killpg(bench.process.pid, signal.SIGKILL)
                bench.process.wait()
