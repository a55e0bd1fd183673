"""``rakectl bench --loop``: the daemon's 1 kHz loop on the emulated bench, with figures.

In one run: cyclictest (the machine's own wake-up latency, the reference),
then the daemon armed and holding for ``seconds`` idle, ``seconds`` with a
client calling ``status`` at 100 Hz and, with the [view] extra, ``seconds`` with
``rakectl view`` polling at 50 Hz and a Foxglove client subscribed to it, all
real-time (daemon SCHED_FIFO 80, emulator 70) over udp_multicast in a private
network namespace. Printed, never asserted: these machines are shared and noisy.
The header says the priority the daemon's set-up applied, or why it fell short; a
phase the daemon did not spend armed (a fault: the bench file's drive watchdog
tripped) is named, and the daemon is reset and armed again before the next.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rakectl.api.client import Client
from rakectl.config.files import config_dir
from rakectl.config.settings import CYCLE_BITS
from rakectl.daemon.cyclictest import run_cyclictest
from rakectl.errors import RakeError
from rakectl.sim.rig import Bench, emulated_bench, namespaces_unavailable

FRAME_OVERHEAD_BITS = 47  # a standard-ID data frame without stuffing: 47 + 8 × data bytes
# the daemon's settings over config/rakectl-emulated.yaml: real-time set up, its failures
# reported (the header says what was applied). Not enforce: enforce arms only with a drive
# watchdog the clamp carries (the robot's 3 ms), and on a shared machine a stall of a few
# milliseconds trips that (measured: an 8.5 ms stall faulted the daemon during the weight
# check); the benchmark measures the loop, so the drives keep the bench file's 100 ms
DAEMON_SETTINGS = ("daemon.rt_mode=ignore",)


def _phase(bench_socket: Path, seconds: float, status_hz: float) -> dict[str, Any]:
    # one connection per part: a client silent for api.IDLE_TIMEOUT_S (60 s, a phase's
    # default length) is closed by the daemon, so the idle phase keeps none open
    with Client(bench_socket) as client:
        client.request({"cmd": "timing_reset"})
        start = client.request({"cmd": "status"})
    end_at = time.monotonic() + seconds
    calls = 0
    if status_hz > 0:
        with Client(bench_socket) as client:
            while time.monotonic() < end_at:
                client.request({"cmd": "status"})
                calls += 1
                time.sleep(1.0 / status_hz)
    else:
        time.sleep(max(0.0, end_at - time.monotonic()))
    with Client(bench_socket) as client:
        final = client.request({"cmd": "status"})
    gen2 = final["timing"]["gc_collections"][2] - start["timing"]["gc_collections"][2]
    return {"status": final, "status_calls": calls, "gc_gen2": gen2,
            "start_state": start["state"]}


def not_armed(phase: dict[str, Any]) -> str:
    """What to say of a phase the daemon did not spend armed ("" if it did): a fault (a
    drive's watchdog tripped by a stall of the machine) leaves its loop ticking with less
    to do, so those figures are not the armed loop's."""
    start, final = phase.get("start_state", "armed"), phase["status"].get("state")
    if start == "armed" and final == "armed":
        return ""
    when = "by the phase's end" if start == "armed" else "throughout the phase"
    return (f"NOT ARMED {when} ({final}: {phase['status'].get('fault') or 'no fault named'}): "
            "these figures are not the armed loop's")


def _armed(bench: Bench, timeout_s: float = 120.0) -> None:
    """Armed for the next phase: a fault (during a phase or during the checks that
    arming runs first) is reset and the daemon armed again, until it stays armed."""
    deadline = time.monotonic() + timeout_s
    while (state := bench.request("status").get("state")) != "armed":
        if time.monotonic() > deadline:
            raise RakeError(f"the loop benchmark could not arm the daemon within "
                            f"{timeout_s:g} s (last: {state}); see {bench.out}/daemon.log")
        if state == "fault":
            bench.request("reset")
            bench.wait_for_state(["disarmed"], 15.0)
            bench.arm_when_timed(30.0)
        elif state == "disarmed":
            bench.arm_when_timed(30.0)
        time.sleep(0.2)  # checking: the weight check takes about 3 s
    time.sleep(1.0)


def _viewer_phase(bench_socket: Path, seconds: float, out: Path) -> dict[str, Any]:
    """The idle phase with ``rakectl view`` running (its own process, status at 50 Hz)
    and a Foxglove client subscribed to every topic (when websockets is installed)."""
    log = out / "view.log"
    with log.open("wb") as stderr:
        viewer = subprocess.Popen([sys.executable, "-m", "rakectl", "view", "--socket",
                                   str(bench_socket), "--port", "0", "--rate-hz", "50"],
                                  stderr=stderr)
    received = [0]
    stop = threading.Event()
    subscriber = None
    try:
        port = _viewer_port(viewer, log)
        subscriber = threading.Thread(target=_subscribe, args=(port, stop, received),
                                      daemon=True)
        subscriber.start()
        phase = _phase(bench_socket, seconds, 0.0)
    finally:
        stop.set()
        if subscriber is not None:
            subscriber.join(timeout=5.0)
        viewer.terminate()
        try:
            viewer.wait(10.0)
        except subprocess.TimeoutExpired:
            viewer.kill()
            viewer.wait()
    return phase | {"viewer_messages": received[0], "viewer_log": log.read_text().strip()}


def _viewer_port(viewer: subprocess.Popen[bytes], log: Path) -> int:
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        found = re.search(r"ws://[^:]+:(\d+)", log.read_text())
        if found:
            return int(found.group(1))
        if viewer.poll() is not None:
            break
        time.sleep(0.1)
    raise RakeError(f"rakectl view did not start: {log.read_text().strip()}")


def _subscribe(port: int, stop: threading.Event, received: list[int]) -> None:
    """A Foxglove client subscribed to every channel, counting the messages."""
    try:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect
    except ImportError:
        received[0] = -1  # no client: the viewer polled, nobody watched
        return
    protocols: Any = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
    try:
        ws_context = connect(f"ws://127.0.0.1:{port}", subprotocols=protocols)
    except (OSError, ConnectionClosed, ValueError):
        received[0] = -2  # the client could not connect: said so in the report
        return
    with ws_context as ws:
        subscribed = False
        while not stop.is_set():
            try:
                frame = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            except ConnectionClosed:  # the viewer stopped first
                return
            if isinstance(frame, bytes):
                received[0] += 1
            elif not subscribed and json.loads(frame).get("op") == "advertise":
                channels = json.loads(frame)["channels"]
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": c["id"], "channelId": c["id"]} for c in channels]}))
                subscribed = True


@dataclass(frozen=True)
class LoopFigures:
    """What one loop benchmark measured (``status`` replies' timing, in ns)."""

    seconds: float
    cyclictest: dict[str, Any] | None
    cyclictest_reasons: tuple[str, ...]
    idle: dict[str, Any]
    loaded: dict[str, Any]
    bus: dict[str, Any]
    viewed: dict[str, Any] | None = None  # idle, with the live view polling and watched
    priority: int | None = 80  # the daemon's SCHED_FIFO priority as applied; None: not
    rt_problems: tuple[str, ...] = ()  # why the real-time set-up fell short

    def phases(self) -> list[tuple[str, dict[str, Any]]]:
        """(name, phase) of every phase measured, in order."""
        phases = [("idle", self.idle), ("status at 100 Hz", self.loaded)]
        if self.viewed is not None:
            phases.append(("rakectl view at 50 Hz, watched", self.viewed))
        return phases

    def wakeup_ratio(self, phase: dict[str, Any]) -> float:
        """The daemon's p99 OS wake-up over cyclictest's p99 (nan without cyclictest)."""
        if self.cyclictest is None or self.cyclictest["latency_ns"]["p99"] <= 0:
            return math.nan
        return float(phase["status"]["timing"]["oversleep_ns"]["p99"]
                     / self.cyclictest["latency_ns"]["p99"])

    def bits_per_cycle(self) -> float:
        """Bits on the bus per SYNC from the frames the daemon counted (sent: SYNC, RPDO1 and
        heartbeats, all counted as 4-byte frames but SYNC; received: TPDO1, TPDO2, heartbeats,
        EMCY), before bit stuffing; nan without counters."""
        b, syncs = self.bus, self.bus.get("syncs", 0)
        if not syncs:
            return math.nan
        bits = (syncs * (FRAME_OVERHEAD_BITS + 8)
                + (b.get("sends", 0) - syncs) * (FRAME_OVERHEAD_BITS + 32)
                + (b.get("tpdo_received_r", 0) + b.get("tpdo_received_theta", 0)
                   + b.get("emcy_received", 0)) * (FRAME_OVERHEAD_BITS + 64)
                + (b.get("tpdo2_received_r", 0) + b.get("tpdo2_received_theta", 0))
                * (FRAME_OVERHEAD_BITS + 24)
                + b.get("heartbeats_received", 0) * (FRAME_OVERHEAD_BITS + 8))
        return float(bits / syncs)

    def tpdo_missed(self) -> tuple[int, int]:
        """(missed, expected) TPDO1s over the whole cross-process run."""
        bus = self.bus
        missed = bus.get("tpdo_missed_r", 0) + bus.get("tpdo_missed_theta", 0)
        received = bus.get("tpdo_received_r", 0) + bus.get("tpdo_received_theta", 0)
        return missed, missed + received


def measure_loop(seconds: float, out: Path) -> LoopFigures:
    reason = namespaces_unavailable()
    if reason:
        raise RakeError(f"the loop benchmark needs a network namespace: {reason}")
    reasons: list[str] = []
    cyclictest = run_cyclictest(seconds, why_not=reasons.append)
    config = config_dir()
    with emulated_bench(out, config / "emulator-demo.yaml", config / "rakectl-emulated.yaml",
                        daemon_args=[a for key in DAEMON_SETTINGS for a in ("--set", key)],
                        emulator_rt_priority=70) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        bench.arm_when_timed(30.0)
        _armed(bench)
        idle = _phase(bench.socket, seconds, 0.0)
        _armed(bench)
        loaded = _phase(bench.socket, seconds, 100.0)
        _armed(bench)
        viewed = _viewer_phase(bench.socket, seconds, out) if _viewer_installed() else None
    priority, problems = _realtime(out / "daemon.log")
    return LoopFigures(seconds, cyclictest, tuple(reasons), idle, loaded,
                       _bus_latency(out / "daemon.log"), viewed, priority, problems)


def _viewer_installed() -> bool:
    try:
        import rakectl.view.topics  # noqa: F401
    except RakeError:
        return False
    return True


def _events(log: Path, name: str) -> list[dict[str, Any]]:
    """The daemon log's JSON events called ``name``, in order."""
    marker = f'"event": "{name}"'
    return [json.loads(line) for line in log.read_text().splitlines()
            if line.startswith("{") and marker in line]


def _realtime(log: Path) -> tuple[int | None, tuple[str, ...]]:
    """The SCHED_FIFO priority the daemon's start-up applied (None: none) and its
    real-time set-up's warnings, from its log."""
    started = _events(log, "started")
    return (started[-1].get("priority") if started else None,
            tuple(str(e.get("problem")) for e in _events(log, "realtime")))


def _bus_latency(log: Path) -> dict[str, Any]:
    latency = _events(log, "bus_latency")
    return dict(latency[-1]) if latency else {}


def _us(ns: float) -> str:
    return f"{ns / 1e3:8.0f}"


def _row(label: str, p: dict[str, Any], extra: str = "") -> str:
    return f"{label:<46}{_us(p['p50'])}{_us(p['p99'])}{_us(p['p99.9'])}{_us(p['max'])}  {extra}"


def format_loop(f: LoopFigures) -> str:
    cyclictest, bus = f.cyclictest, f.bus
    daemon = (f"daemon SCHED_FIFO {f.priority}" if f.priority is not None else
              "daemon NOT real-time")
    lines = [f"loop benchmark: {f.seconds:g} s per phase, {daemon}, emulator SCHED_FIFO 70",
             *(f"  real-time set-up: {problem}" for problem in f.rt_problems),
             f"{'wake-up latency, µs':<46}{'p50':>8}{'p99':>8}{'p99.9':>8}{'max':>8}"]
    if cyclictest is not None:
        lines.append(_row(cyclictest["label"], cyclictest["latency_ns"],
                          f"{cyclictest['samples']} samples"))
    else:
        reasons = "; ".join(f.cyclictest_reasons) or "unavailable"
        lines.append(f"cyclictest: not measured ({reasons})")
    if f.viewed is None:
        lines.append("rakectl view: not measured (the [view] extra is not installed)")
    for name, phase in f.phases():
        t = phase["status"]["timing"]
        lines.append(_row(f"daemon, {name}: OS wake-up (before the spin)", t["oversleep_ns"],
                          f"{t['overruns']} late ticks, gen-2 GC {phase['gc_gen2']}"))
        lines.append(_row(f"daemon, {name}: tick start after the deadline", t["latency_ns"],
                          f"longest gap {t['longest_gap_ns'] / 1e3:.0f} µs"))
        lines.append(_row(f"daemon, {name}: tick execution", t["exec_ns"]))
        if not_armed_text := not_armed(phase):
            lines.append("  " + not_armed_text)
        ratio = f.wakeup_ratio(phase)
        if math.isfinite(ratio):
            lines.append(f"  p99 OS wake-up / cyclictest p99: {ratio:.2f}× (goal ≤ 2×)")
        if "viewer_messages" in phase:
            watched = phase["viewer_messages"]
            lines.append("  the viewer's client received " + (
                f"{watched} messages" if watched >= 0 else
                "nothing (websockets not installed)" if watched == -1 else
                "nothing (it could not connect)"))
    missed, expected = f.tpdo_missed()
    lines += [
        "cross-process bus (udp_multicast, the whole run):",
        f"  TPDO1 missed their tick: {missed} of {expected}; SYNC → TPDO1 p50 "
        f"{bus.get('sync_to_tpdo_p50_us', float('nan'))} µs, p99 "
        f"{bus.get('sync_to_tpdo_p99_us', float('nan'))} µs, max "
        f"{bus.get('sync_to_tpdo_max_us', float('nan'))} µs",
        f"  bus load at 1 Mbit/s, 1 kHz: {CYCLE_BITS} bits per cycle = "
        f"{CYCLE_BITS / 10:.1f} % before bit stuffing (design); from the frames "
        f"counted in this run {f.bits_per_cycle():.0f} bits = {f.bits_per_cycle() / 10:.1f} %",
    ]
    return "\n".join(lines)
