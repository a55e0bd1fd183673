"""Hardware-in-the-loop on real SocketCAN: the emulator and the daemon as processes on vcan0.

Run with ``pytest -m vcan`` where vcan0 exists (a robot computer, a Linux
machine with root: see docs/development.md), or ``tests/vcan/run-in-vm.sh``, which
boots a kernel with SocketCAN in a VM when this one has none. Elsewhere they
skip, saying why.

Under software emulation Python runs ~50x slower, so the bench runs at 50 Hz
(config/rakectl-vcan.yaml) with the emulator lock-stepped to the SYNCs
(config/emulator-vcan.yaml): behaviour is asserted, never timing. Each bench
start costs two Python processes, so one bench covers bring-up, jog,
excavation, e-stop and the traces; SIGKILL and a silent drive need their own.
"""

from __future__ import annotations

import csv
import itertools
import json
import os
import select
import signal
import time
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.cli import load_config
from drivers.emulator import Emulator
from rakectl.config.loader import load_settings
from rakectl.config.service import BusInterface, BusSettings
from rakectl.config.settings import Settings
from rakectl.daemon.inputs import sidecar_path
from rakectl.daemon.replay import replay
from rakectl.drive.canbus import open_bus
from rakectl.protocol.cia402 import DriveCommand, DriveState, decode_statusword
from tests.vcan.vcan_bench import (
    CHANNEL,
    START_TIMEOUT_S,
    SdoExchange,
    VcanBench,
    WireRecorder,
    load_dbc,
    read_trace,
    sdo_exchanges,
    vcan_bench,
    vcan_unavailable,
)

CONFIG = Path(__file__).resolve().parents[2] / "config"
EMULATOR = CONFIG / "emulator-vcan.yaml"
DAEMON = CONFIG / "rakectl-vcan.yaml"
SETTINGS = load_settings(DAEMON, [], root=Settings)
NODES = (SETTINGS.drives.r_node_id, SETTINGS.drives.theta_node_id)
LIMIT_OBJECTS = (0x2001, 0x2002, 0x2003, 0x2004)  # voltage, current, watchdog, encoder

_reason = vcan_unavailable()
pytestmark = [pytest.mark.vcan,
              pytest.mark.skipif(_reason is not None, reason=f"no SocketCAN: {_reason}")]


def _truth(out: Path) -> list[dict[str, str]]:
    with open(out / "truth.csv", newline="") as f:
        return list(csv.DictReader(f))


def _events(out: Path, name: str, event: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in (out / name).read_text().splitlines()
            if line.startswith("{") and f'"event": "{event}"' in line]


def _armed(bench: VcanBench) -> None:
    bench.wait_for_state(["disarmed"], START_TIMEOUT_S)
    bench.request("arm")
    check = bench.wait_for_state(["armed"], 30.0)["weight_check"]  # through the weight check
    assert isinstance(check, dict) and check["passed"], check
    deadline = time.monotonic() + 30.0
    while any(d["state"] != "operation_enabled" for d in _drives(bench)):
        assert time.monotonic() < deadline, f"drives not enabled: {_drives(bench)}"
        time.sleep(0.1)


def _drives(bench: VcanBench) -> list[dict[str, object]]:
    drives = bench.request("status")["drives"]
    assert isinstance(drives, list)
    return drives


def _readable(bus: can.BusABC, timeout_s: float = 5.0) -> None:
    """Block until the bus's socket has a frame queued (the kernel's queue, not python-can's)."""
    fileno = bus.fileno()
    ready, _, _ = select.select([fileno], [], [], timeout_s)
    assert ready, "no frame arrived"


def _received_id(bus: can.BusABC, timeout_s: float) -> int | None:
    msg = bus.recv(timeout_s)
    return None if msg is None else msg.arbitration_id


def test_kernel_receive_filters_on_socketcan() -> None:
    """The controller's bus and the emulator's pass only their IDs, filtered in the kernel.

    python-can filters in software otherwise, where ``recv(0)`` returns None
    when the frame at the head of the queue does not match: here the frame
    sent first (an ID nobody listens to) never reaches the socket, so
    ``recv(0)`` returns the matching frame behind it.
    """
    sender = can.Bus(interface="socketcan", channel=CHANNEL)
    controller = open_bus(BusSettings(interface=BusInterface.SOCKETCAN, channel=CHANNEL),
                          receive_ids=[0x181, 0x701])
    config = load_config(EMULATOR)
    drives = can.Bus(interface="socketcan", channel=CHANNEL)
    try:
        emulator = Emulator(config, drives)
        emulator.bus.set_filters(emulator.bus_filters())  # what Emulator.start does
        for can_id in (0x123, 0x181, 0x080, 0x7FF):
            sender.send(can.Message(arbitration_id=can_id, data=b"\x01", is_extended_id=False))
        _readable(controller)
        assert _received_id(controller, 0.0) == 0x181
        assert _received_id(controller, 0.2) is None  # neither 0x080, 0x123 nor 0x7FF
        _readable(drives)
        assert _received_id(drives, 0.0) == 0x080  # SYNC, behind 0x123 and 0x181
        assert _received_id(drives, 0.2) is None
    finally:
        for bus in (sender, controller, drives):
            bus.shutdown()


def test_bring_up_jog_excavate_and_estop_on_the_wire(tmp_path: Path) -> None:
    wire, trace = tmp_path / "wire.log", tmp_path / "trace.log"
    with WireRecorder(wire) as recorder, vcan_bench(
            tmp_path, EMULATOR, DAEMON, daemon_args=["--set", f"bus.trace_path={trace}"]
    ) as bench:
        _armed(bench)
        recorder.close()  # bring-up and enabling are on record; it costs CPU in a VM
        before = bench.request("status")["tip"]
        assert isinstance(before, dict)
        for _ in range(10):  # 1 s of jog down at 3 cm/s, commands every 0.1 s
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        after = bench.wait_for_state(["hold"], 30.0)  # silence: the dead-man stops the jog
        tip = after["tip"]
        assert isinstance(tip, dict) and tip["depth_m"] > before["depth_m"] + 0.01
        final, lanes = _excavate(bench)
        excavation = final["excavation"]
        assert isinstance(excavation, dict)
        # the bus counters tell whether the emulator fell behind (late TPDOs) if not
        assert excavation["done"] and excavation["object_found"] is None, final["bus"]
        assert not excavation["stopped_by_force"]
        assert excavation["depth_m"] >= excavation["target_depth_m"] - 1e-9  # the whole lane
        force = final["force"]
        assert isinstance(force, dict)
        print(f"\nF̂ at most {force['f_hat_max_n']:.1f} N (one tick; the supervision judges "
              "it filtered)")
        bench.request("estop")
        bench.wait_for_state(["estop"], 30.0)
        bench.request("reset")
        bench.wait_for_state(["disarmed"], 30.0)
    assert bench.process.returncode == 0

    # a lane the supervision stopped was the motors' currents' to confirm: they read low
    back_offs = _events(tmp_path, "daemon.log", "force_limit")
    assert bool(back_offs) == (lanes > 1)
    caution_n = SETTINGS.supervision.caution_force_n
    assert all(float(e["f_current_n"]) < caution_n for e in back_offs), back_offs  # type: ignore[arg-type]
    states = [e["new"] for e in _events(tmp_path, "daemon.log", "state")]
    assert states == (["DISARMED", "CHECKING", "ARMED", "JOG", "HOLD"]
                      + ["EXCAVATE", "HOLD"] * lanes + ["ESTOP", "DISARMED"])
    truth = _truth(tmp_path)
    _check_truth(truth)
    _check_bring_up_on_the_wire(read_trace(wire))
    _check_daemon_trace(read_trace(trace))
    # the same trace, fed back offline through the controller, gives every frame it sent
    # on the wire (rakectl replay, docs/can-bus.md#replaying-a-field-trace)
    replayed = replay(trace, SETTINGS)
    assert replayed.ok, replayed.message()
    start = json.loads(sidecar_path(trace).read_text().splitlines()[0])["frame"]
    lines = [line for line in trace.read_text().splitlines() if line.strip()]
    assert replayed.reproduced == sum(1 for line in lines[start:] if line.endswith(" T"))
    print(f"\n{replayed.message()}")
    bus = final["bus"]
    assert isinstance(bus, dict)
    print(f"\nlane: deepest {-min(float(r['tip_height_m']) for r in truth) * 1e3:.1f} mm, "
          f"true force {max(float(r['force_down_n']) for r in truth):.1f} N, "
          f"F_hat {force['f_hat_max_n']:.1f} N; TPDO1 a cycle late "
          f"{bus['tpdo_late_r'] + bus['tpdo_late_theta']}, missing "
          f"{bus['tpdo_missed_r'] + bus['tpdo_missed_theta']} (2 per SYNC, {bus['syncs']} SYNCs); "
          f"lanes stopped by the supervision on F̂ {lanes - 1}")


def _excavate(bench: VcanBench, attempts: int = 3) -> tuple[dict[str, Any], int]:
    """The test's lane, asked again, as an operator would, while the supervision stops it:
    (the status at its end, the lanes asked). F̂ reads the depth's motion over one 20 ms
    period, so a VM that delays TPDO1s makes it bursty (a 0.5 mm step in one period is
    100 N), and the hard level on F̂ filtered may stop a lane whose tip barely presses
    (a loaded VM: F̂ 115.8 N with 12.1 N from the currents, where the plunge began)."""
    for lanes in range(1, attempts + 1):
        bench.request("excavate", reach_far_m=1.25, reach_near_m=1.15, target_depth_m=0.01,
                      depth_step_m=0.01, stroke_speed_m_per_s=0.05)
        final = bench.wait_for_state(["hold", "fault"], 600.0)
        assert final["state"] == "hold", final.get("fault")
        excavation = final["excavation"]
        assert isinstance(excavation, dict)
        if not excavation["stopped_by_force"]:
            return final, lanes
    return final, attempts


def _check_truth(truth: list[dict[str, str]]) -> None:
    """The emulator's ground truth: the lane's depth reached, under 90 N, e-stop at 0 V."""
    enabled = [row for row in truth if row["r_state"] == "OPERATION_ENABLED"]
    heights = [float(row["tip_height_m"]) for row in enabled]
    assert min(heights) == pytest.approx(-0.01, abs=0.004)  # the lane's depth, really reached
    assert max(float(row["force_down_n"]) for row in truth) < 90.0
    last_enabled = truth.index(enabled[-1])
    after = truth[last_enabled + 1:]
    assert any(row["r_state"] == "QUICK_STOP_ACTIVE" for row in after)  # the e-stop
    assert all(float(row["voltage_r_v"]) == 0.0 and float(row["voltage_theta_v"]) == 0.0
               for row in after)


def _decode(dbc: Any, frame: can.Message) -> dict[str, Any]:
    """A frame's signals by the DBC, as numbers (choices not applied)."""
    signals = dbc.decode_message(frame.arbitration_id, bytes(frame.data), decode_choices=False)
    assert isinstance(signals, dict)
    return signals


# The aborts a bring-up meets by design: it probes for objects a drive may lack (PDOs
# beyond the EDS's, 0x1006, 0x1019) and reads "no such object" or "no such subindex".
PROBE_ABORTS = (0x06020000, 0x06090011)


def _answered(exchange: SdoExchange) -> bool:
    """An SDO exchange that succeeded, or a probe's read of an object the drive lacks."""
    return exchange.abort_code is None or (not exchange.write
                                           and exchange.abort_code in PROBE_ABORTS)


def _check_bring_up_on_the_wire(frames: list[can.Message]) -> None:
    """NMT, SDO configuration read back, CiA 402 enabling: as every node on vcan0 saw it."""
    assert frames and all(f.channel == CHANNEL for f in frames)
    dbc = load_dbc()
    nmt = [_decode(dbc, f) for f in frames if f.arbitration_id == 0]
    for node in NODES:
        assert {"command": 0x82, "node_id": node} in nmt  # reset communication
        assert {"command": 0x01, "node_id": node} in nmt  # start
    exchanges = sdo_exchanges(frames)
    assert exchanges and all(_answered(e) for e in exchanges), [
        e for e in exchanges if not _answered(e)]
    for node in NODES:
        written, read = _sdo_values(exchanges, node)
        assert {index for index, _ in written} >= set(LIMIT_OBJECTS)
        assert written[0x2003, 0] == SETTINGS.drives.watchdog_timeout_ms  # as configured
        assert written.items() <= read.items(), (written, read)  # each value read back
        assert (0x1018, 2) in read  # the identity checked
        controlwords = [_decode(dbc, f)["controlword"]
                        for f in frames if f.arbitration_id == 0x200 + node]
        sequence = [DriveCommand.SHUTDOWN.value, DriveCommand.SWITCH_ON.value,
                    DriveCommand.ENABLE_OPERATION.value]
        firsts = [controlwords.index(word) for word in sequence]
        assert firsts == sorted(firsts), controlwords[:20]  # 0x06, 0x07, 0x0F in that order
        statuswords = [_decode(dbc, f)["statusword"]
                       for f in frames if f.arbitration_id == 0x280 + node]
        assert decode_statusword(statuswords[-1]) is DriveState.OPERATION_ENABLED


def _sdo_values(exchanges: list[Any], node: int) -> tuple[dict[tuple[int, int], int | None],
                                                          dict[tuple[int, int], int | None]]:
    """(written, read back) of one node's SDO exchanges, by (index, subindex)."""
    written = {(e.index, e.subindex): e.value for e in exchanges if e.node_id == node and e.write}
    read = {(e.index, e.subindex): e.value for e in exchanges
            if e.node_id == node and not e.write}
    return written, read


def _check_daemon_trace(frames: list[can.Message]) -> None:
    """The daemon's own trace (bus.trace_path): the bring-up's SDO in it, every frame once,
    every cyclic frame decodes with the DBC.

    Sent frames are marked T, received ones R (python-can's candump format).
    """
    dbc = load_dbc()
    known = {m.frame_id for m in dbc.messages}
    sdo = [f for f in frames if 0x580 < f.arbitration_id < 0x680]  # the bring-up's, traced
    assert any(f.is_rx for f in sdo) and any(not f.is_rx for f in sdo)
    own = {0x000, 0x080, *(0x200 + n for n in NODES), *(0x600 + n for n in NODES)}
    assert not [f for f in frames if f.is_rx and f.arbitration_id in own]  # each frame once
    cyclic = [f for f in frames if f.arbitration_id in known]
    sent = [(f.arbitration_id, _decode(dbc, f)) for f in cyclic if not f.is_rx]
    received = [(f.arbitration_id, _decode(dbc, f)) for f in cyclic if f.is_rx]
    syncs = [d["sync_counter"] for can_id, d in sent if can_id == 0x080]
    assert len(syncs) > 250  # 5 s at 50 Hz
    assert all(b == a % 240 + 1 for a, b in itertools.pairwise(syncs))  # none lost from the trace
    for node in NODES:
        tpdo1 = [d for can_id, d in received if can_id == 0x180 + node]
        rpdo1 = [d for can_id, d in sent if can_id == 0x200 + node]
        assert len(tpdo1) > 0.9 * len(syncs) and len(rpdo1) >= len(syncs)
        assert all(abs(d["voltage_v"]) <= 24.0 for d in rpdo1)
        assert any(d["voltage_v"] != 0 for d in rpdo1)


def test_sigkill_of_the_controller_leaves_the_drives_at_0_v(tmp_path: Path) -> None:
    with vcan_bench(tmp_path, EMULATOR, DAEMON) as bench:
        _armed(bench)
        pid = bench.request("status")["pid"]
        assert isinstance(pid, int)
        os.kill(pid, signal.SIGKILL)
        bench.process.wait(30.0)
        bench.wait_for_log("emulator.log", "COMMAND_WATCHDOG_TIMEOUT", 2, 60.0)
        time.sleep(1.0)  # the physics runs on without SYNC; its truth is written at the end
    watchdog = [f for f in _events(tmp_path, "emulator.log", "drive_fault")
                if f.get("detail") == "COMMAND_WATCHDOG_TIMEOUT"]
    assert {f["node_id"] for f in watchdog} == set(NODES)
    faulted_s = max(float(str(f["t_s"])) for f in watchdog)
    after = [row for row in _truth(tmp_path) if float(row["t_s"]) > faulted_s]
    assert after, f"no physics step recorded after both watchdogs ({faulted_s} s)"
    assert all(float(row["voltage_r_v"]) == 0.0 and float(row["voltage_theta_v"]) == 0.0
               and row["r_state"] == "FAULT" and row["theta_state"] == "FAULT" for row in after)


def test_a_drive_that_goes_silent_faults_the_controller(tmp_path: Path) -> None:
    """θ falls silent 15 s after the emulator started, which is when the bring-up started."""
    emulator_args = ["--set", "faults.silence_node_id=2", "--set", "faults.silence_after_s=15"]
    with vcan_bench(tmp_path, EMULATOR, DAEMON, emulator_args=emulator_args,
                    emulator_at_bring_up=True) as bench:
        _armed(bench)
        final = bench.wait_for_state(["fault"], 120.0)
    assert "θ drive (node 2)" in str(final["fault"])
    bus = final["bus"]
    assert isinstance(bus, dict)
    assert bus["tpdo_received_r"] > bus["tpdo_received_theta"]  # r kept answering


def test_roboteq_class_drives_on_the_wire(tmp_path: Path) -> None:
    """drives.profile: roboteq on both processes: bring-up writes the Roboteq-class limits
    (0x3001-0x3003) and reads them back (on the wire), the daemon arms through the weight
    check by releasing the power stages (0x200D), jogs on commands in ‰ of the supply, and
    the e-stop switches them off (0x200C; the daemon's trace): 0 V in the ground truth
    from then on, the drives switched off, not faulted."""
    profile = ["--set", "drives.profile=roboteq"]
    wire, trace = tmp_path / "wire.log", tmp_path / "trace.log"
    with WireRecorder(wire) as recorder, vcan_bench(
            tmp_path, EMULATOR, DAEMON, emulator_args=profile,
            daemon_args=[*profile, "--set", f"bus.trace_path={trace}"]) as bench:
        _armed(bench)
        recorder.close()  # bring-up and arming on the wire; it costs CPU in a VM
        before = bench.request("status")["tip"]
        assert isinstance(before, dict)
        for _ in range(10):
            bench.request("jog", space="task", height_m_per_s=-0.03)
            time.sleep(0.1)
        tip = bench.wait_for_state(["hold"], 30.0)["tip"]
        assert isinstance(tip, dict) and tip["depth_m"] > before["depth_m"] + 0.01
        bench.request("estop")
        bench.wait_for_state(["estop"], 30.0)
        deadline = time.monotonic() + 30.0
        while any(d["state"] != "switch_on_disabled" for d in _drives(bench)):
            assert time.monotonic() < deadline, f"drives not switched off: {_drives(bench)}"
            time.sleep(0.1)
    assert bench.process.returncode == 0
    frames = read_trace(wire)
    exchanges = sdo_exchanges(frames)
    assert exchanges and all(_answered(e) for e in exchanges), [
        e for e in exchanges if not _answered(e)]
    for node in NODES:
        written, read = _sdo_values(exchanges, node)
        assert written[0x3001, 0] == SETTINGS.drives.watchdog_timeout_ms
        assert {(0x3002, 0), (0x3003, 0)} <= written.keys()
        assert {k: written[k] for k in ((0x3001, 0), (0x3002, 0), (0x3003, 0))}.items() <= (
            read.items())
        # the daemon's own trace, to its end: the power requests and the jog's commands
        sent = [f for f in read_trace(trace) if not f.is_rx]
        power = [f.data[1] for f in sent if f.arbitration_id == 0x600 + node
                 and f.data[0] == 0x2F and f.data[2] == 0x20]  # 0x200C off, 0x200D on
        assert power[0] == 0x0C and 0x0D in power and power[-1] == 0x0C, power  # off at the end
        commands = [int.from_bytes(f.data[:4], "little", signed=True) for f in sent
                    if f.arbitration_id == 0x200 + node]
        assert commands and all(abs(c) <= 1000 for c in commands)
        assert any(c != 0 for c in commands)
    truth = _truth(tmp_path)
    stopped = [k for k, row in enumerate(truth) if row["r_state"] == "OPERATION_ENABLED"][-1]
    after = truth[stopped + 1:]
    assert after and all(row["r_state"] == row["theta_state"] == "SWITCH_ON_DISABLED"
                         for row in after)  # the emergency stop flag, not a fault
    assert all(float(row["voltage_r_v"]) == 0.0 and float(row["voltage_theta_v"]) == 0.0
               for row in after)
    assert max(float(row["force_down_n"]) for row in truth) < 90.0
