"""Tier 3: the emulator on a python-can ``virtual`` bus, driven by a scripted controller.

The controller is this test, in the same thread: it sends frames on its own
bus object, lets the emulator service them (:meth:`Emulator.service`) and
reads the answers. No threads; every bus is shut down.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.cli import load_config, main
from drivers.emulator import Emulator
from drivers.records import TRUTH_COLUMNS
from drivers.settings import EmulatorConfig, TimingMode
from drivers.stats import BadInput
from rakectl.core.motor_model import MotorParams, joint_per_motor_rad, joint_resolution
from rakectl.errors import ConfigError
from rakectl.protocol import codec
from rakectl.protocol.cia402 import DriveCommand, DriveState, decode_statusword
from rakectl.protocol.nmt import EmcyCode, NmtCommand, decode_emcy, encode_nmt
from tests.drivers.test_node import sdo_download, sdo_reply, sdo_upload

ROOT = Path(__file__).resolve().parents[2]
NODES = (1, 2)
_channels = itertools.count()

Frames = list[tuple[int, bytes]]


class RecordingLog:
    """A structlog-like logger that keeps its events."""

    def __init__(self) -> None:
        self.events: list[tuple[str, dict[str, Any]]] = []

    def info(self, event: str, **fields: Any) -> None:
        self.events.append((event, fields))

    warning = info


class Controller:
    """The scripted controller: its own bus on the emulator's channel."""

    def __init__(self, bus: can.BusABC, emulator: Emulator) -> None:
        self.bus, self.emulator, self.counter = bus, emulator, 0

    def send(self, can_id: int, data: bytes, **flags: bool) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data,
                                  is_extended_id=flags.pop("is_extended_id", False), **flags))

    def receive(self) -> Frames:
        frames = []
        while (msg := self.bus.recv(0.0)) is not None:
            frames.append((msg.arbitration_id, bytes(msg.data)))
        return frames

    def exchange(self, timeout_s: float = 0.0) -> Frames:
        self.emulator.service(timeout_s)
        return self.receive()

    def sdo(self, node_id: int, request: bytes) -> tuple[str, int]:
        self.send(0x600 + node_id, request)
        return sdo_reply(self.exchange(), 0x580 + node_id)

    def nmt(self, command: NmtCommand, node_id: int = 0) -> Frames:
        self.send(codec.NMT_COB_ID, encode_nmt(command, node_id))
        return self.exchange()

    def cycle(self, commands: dict[int, tuple[int, int]]) -> Frames:
        """SYNC, the drives' answers, then one RPDO1 (voltage mV, controlword) per node."""
        self.counter = codec.next_sync_counter(self.counter)
        self.send(codec.SYNC_COB_ID, codec.encode_sync(self.counter))
        frames = self.exchange()
        for node_id, (voltage_mv, controlword) in commands.items():
            self.send(0x200 + node_id, codec.encode_rpdo(voltage_mv, controlword))
        return frames


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[Controller, Emulator, io.StringIO]]:
    """Emulator + controller on a fresh virtual channel; ``config`` via indirect param."""
    config = getattr(request, "param", EmulatorConfig())
    channel = f"test-emulator-{os.getpid()}-{next(_channels)}"
    controller_bus = can.Bus(interface="virtual", channel=channel)
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    truth = io.StringIO()
    try:
        emulator = Emulator(config, emulator_bus, truth=truth, log=RecordingLog())
        emulator.start()
        yield Controller(controller_bus, emulator), emulator, truth
        emulator.close()
    finally:
        controller_bus.shutdown()
        emulator_bus.shutdown()


def of(frames: Frames, can_id: int) -> list[bytes]:
    return [data for i, data in frames if i == can_id]


def emcy_codes(frames: Frames) -> dict[int, list[int]]:
    return {n: [decode_emcy(d).code for d in of(frames, 0x80 + n)] for n in NODES}


def bring_up(ctl: Controller, watchdog_ms: int = 1000) -> None:
    """Identity by SDO, the watchdog set, NMT start, CiA 402 bring-up by RPDO1. The
    watchdog runs on the wall clock: this scripted controller is not real-time, so only a
    test of the watchdog sets it short."""
    for node_id in NODES:
        assert ctl.sdo(node_id, sdo_download(0x2003, 0, watchdog_ms, 2)) == ("ok", 0)
    assert of(ctl.nmt(NmtCommand.START), 0x281)  # TPDO2 on entering OPERATIONAL
    for command in (DriveCommand.SHUTDOWN, DriveCommand.SWITCH_ON, DriveCommand.ENABLE_OPERATION):
        ctl.cycle({n: (0, command.value) for n in NODES})
    frames = ctl.cycle({n: (0, DriveCommand.ENABLE_OPERATION.value) for n in NODES})
    for node_id in NODES:
        (tpdo2,) = of(frames, 0x280 + node_id)
        assert decode_statusword(codec.decode_tpdo2(tpdo2)[0]) is DriveState.OPERATION_ENABLED


def joint_state(tpdo1: bytes, motor: MotorParams) -> tuple[float, float, float]:
    """(position, joint velocity, current A) from a TPDO1, with the shared motor model."""
    counts, rpm, current_ma = codec.decode_tpdo1(tpdo1)
    return (counts * joint_resolution(motor),
            codec.rpm_to_rad_per_s(rpm) * joint_per_motor_rad(motor), current_ma / 1000)


GAINS = {1: (2000.0, 40.0), 2: (1200.0, 40.0)}  # V per m or rad, V·s per m or rad


def hold(ctl: Controller, emulator: Emulator, cycles: int) -> list[Frames]:
    """A PD loop on the TPDO1 feedback holding the start pose."""
    config = emulator.config
    motors = {1: config.physics.motor_r, 2: config.physics.motor_theta}
    targets = {1: config.drives.start_r_m, 2: config.drives.start_theta_rad}
    commands = {n: (0, DriveCommand.ENABLE_OPERATION.value) for n in NODES}
    history = []
    for _ in range(cycles):
        frames = ctl.cycle(commands)
        history.append(frames)
        for node_id in NODES:
            (tpdo1,) = of(frames, 0x180 + node_id)
            position, velocity, _ = joint_state(tpdo1, motors[node_id])
            kp, kd = GAINS[node_id]
            voltage_v = max(-24.0, min(24.0, kp * (targets[node_id] - position) - kd * velocity))
            enable = DriveCommand.ENABLE_OPERATION.value
            commands[node_id] = (codec.voltage_v_to_mv(voltage_v), enable)
    return history


# ----------------------------------------------------------------------------- closed loop


def test_bring_up_by_sdo_nmt_and_rpdo_then_hold_the_arm(rig: Any) -> None:
    ctl, emulator, truth = rig
    assert sorted(ctl.receive()) == [(0x701, b"\x00"), (0x702, b"\x00")]  # boot-up
    for node_id, product, serial in ((1, 1, 1001), (2, 2, 2001)):
        assert ctl.sdo(node_id, sdo_upload(0x1018, 2)) == ("value", product)
        assert ctl.sdo(node_id, sdo_upload(0x1018, 4)) == ("value", serial)
        assert ctl.sdo(node_id, sdo_download(0x2001, 0, 30000, 2)) == ("abort", 0x06090031)
    bring_up(ctl)
    started_s = time.perf_counter()
    history = hold(ctl, emulator, 400)
    per_cycle_us = (time.perf_counter() - started_s) / 400 * 1e6
    protocol_us, physics_us = emulator.stats.per_sync_us()
    print(f"\nemulator on virtual, per SYNC: protocol {protocol_us:.1f} µs, physics "
          f"{physics_us:.1f} µs; whole cycle with the test's controller {per_cycle_us:.1f} µs")

    plant, config = emulator.plant, emulator.config
    assert plant.r_m == pytest.approx(config.drives.start_r_m, abs=2e-3)
    assert plant.theta_rad == pytest.approx(config.drives.start_theta_rad, abs=5e-3)
    r_position, _, r_current_a = joint_state(of(history[-1], 0x181)[0], config.physics.motor_r)
    theta_position, _, theta_current_a = joint_state(of(history[-1], 0x182)[0],
                                                     config.physics.motor_theta)
    assert r_position == pytest.approx(plant.r_m, abs=1e-4)
    assert theta_position == pytest.approx(plant.theta_rad, abs=1e-3)
    assert -3.0 < theta_current_a < -0.1  # holding the half of the rake's weight left
    assert abs(r_current_a) < 3.0
    assert all(len(of(frames, 0x181)) == len(of(frames, 0x182)) == 1 for frames in history)
    assert emulator.stats.bad.total == 0 and emulator.r_node.stats.lost_syncs == 0
    emulator.close()  # flushes the ground truth
    lines = truth.getvalue().splitlines()
    assert lines[0].split(",") == list(TRUTH_COLUMNS)
    assert len(lines) == 1 + emulator.stats.physics_steps
    last = dict(zip(TRUTH_COLUMNS, lines[-1].split(","), strict=True))
    assert [last[k] for k in ("r_state", "r_nmt", "theta_state", "theta_nmt")] == [
        "OPERATION_ENABLED", "OPERATIONAL", "OPERATION_ENABLED", "OPERATIONAL"]
    assert (last["mine_plate_max_n"], last["mine_side_max_n"]) == ("0.0000", "0.0000")
    assert abs(float(last["wall_time_s"]) - time.time()) < 60.0  # the wall clock


def test_silence_faults_both_drives_within_the_watchdog_and_the_arm_brakes(rig: Any) -> None:
    ctl, emulator, _ = rig
    bring_up(ctl, watchdog_ms=50)
    hold(ctl, emulator, 200)
    last_command_s = time.monotonic()  # the controller dies here: no SYNC, no RPDO
    time_before_s = emulator.time_s
    frames: Frames = []
    while not all(emcy_codes(frames).values()) and time.monotonic() - last_command_s < 2.0:
        frames += ctl.exchange(timeout_s=0.005)
    latency_s = time.monotonic() - last_command_s
    print(f"\nwatchdog 50 ms: both EMCYs after {latency_s * 1e3:.1f} ms")
    assert emcy_codes(frames) == {1: [EmcyCode.COMMAND_WATCHDOG_TIMEOUT],
                                  2: [EmcyCode.COMMAND_WATCHDOG_TIMEOUT]}
    # The watchdog's 50 ms, plus the slack of a shared, loaded machine; the heartbeat's
    # timeout is not what fired (the codes above say so).
    assert latency_s < 0.050 + 0.200
    for node in emulator.nodes:
        assert node.state is DriveState.FAULT and node.output_voltage_v == 0.0
        (tpdo2,) = of(frames, 0x280 + node.node_id)
        assert decode_statusword(codec.decode_tpdo2(tpdo2)[0]) is DriveState.FAULT
    # LOCKSTEP, no SYNC, communication lost: the physics runs on by the wall clock at 0 V
    # (as fast as the machine lets it: a loaded one drops the periods it cannot keep up with).
    theta_before = emulator.plant.theta_rad
    give_up_s = time.monotonic() + 10.0
    while emulator.time_s - time_before_s <= 0.3 and time.monotonic() < give_up_s:
        ctl.exchange(timeout_s=0.01)
    assert emulator.time_s - time_before_s > 0.3
    assert abs(emulator.plant.theta_vel_rad_per_s) < 0.1  # shorted motor: it brakes
    assert abs(emulator.plant.theta_rad - theta_before) < 0.03


def test_controller_heartbeat_loss_and_fault_reset(rig: Any) -> None:
    ctl, emulator, _ = rig
    ctl.nmt(NmtCommand.START)
    ctl.send(0x70A, b"\x05")
    frames: Frames = []
    started_s = time.monotonic()
    while not all(emcy_codes(frames).values()) and time.monotonic() - started_s < 1.0:
        frames += ctl.exchange(timeout_s=0.01)
    assert emcy_codes(frames) == {1: [EmcyCode.HEARTBEAT_LOST], 2: [EmcyCode.HEARTBEAT_LOST]}
    assert time.monotonic() - started_s >= 0.25
    ctl.send(0x70A, b"\x05")
    ctl.cycle({n: (0, DriveCommand.FAULT_RESET.value) for n in NODES})
    frames = ctl.cycle({})  # the rising edge, taken at this SYNC: acted on at the next cycle
    frames += ctl.cycle({})
    assert emcy_codes(frames) == {1: [EmcyCode.NO_ERROR], 2: [EmcyCode.NO_ERROR]}
    assert all(node.state is DriveState.SWITCH_ON_DISABLED for node in emulator.nodes)


def test_current_limit_write_rebuilds_the_physics_in_the_same_state(rig: Any) -> None:
    ctl, emulator, _ = rig
    plant, state = emulator.plant, emulator.plant.state()
    assert ctl.sdo(2, sdo_download(0x2002, 0, 5000, 2)) == ("ok", 0)
    assert emulator.plant is not plant
    assert emulator.plant.state() == state
    assert emulator.theta_node.motor_params.current_limit_a == 5.0
    bring_up(ctl)
    assert ctl.sdo(2, sdo_download(0x2002, 0, 4000, 2)) == ("abort", 0x08000022)


# ----------------------------------------------------------------------------- bad input


def test_bad_frames_are_counted_logged_at_most_once_a_second_and_ignored() -> None:
    channel = f"test-emulator-bad-{os.getpid()}"
    controller_bus = can.Bus(interface="virtual", channel=channel)
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    now_s = [100.0]
    log = RecordingLog()
    try:
        emulator = Emulator(EmulatorConfig(), emulator_bus, clock=lambda: now_s[0], log=log)
        emulator.start()
        ctl = Controller(controller_bus, emulator)
        ctl.nmt(NmtCommand.START)
        for _ in range(30):
            ctl.send(codec.SYNC_COB_ID, b"\x01\x02")  # wrong length
        ctl.send(0x123, b"\x00")  # filtered out by the bus
        ctl.send(codec.SYNC_COB_ID, b"", is_remote_frame=True)
        while emulator.service(0.0):
            pass
        emulator.handle(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False),
                        now_s[0])
        emulator.handle(can.Message(arbitration_id=0x080, data=b"\x01", is_extended_id=True),
                        now_s[0])
        assert emulator.r_node.stats.bad.counts[BadInput.WRONG_LENGTH] == 30
        assert emulator.stats.bad.counts[BadInput.UNSUPPORTED] == 2
        assert emulator.stats.bad.counts[BadInput.UNKNOWN_ID] == 1
        assert emulator.stats.syncs == 0 and emulator.time_s == 0.0  # no physics step
        now_s[0] += 0.3
        emulator.service(0.0)
        first = {(f["node_id"], f["kind"]): f["count"]
                 for event, f in log.events if event == "bad_frame"}
        assert first == {(1, "wrong_length"): 30, (2, "wrong_length"): 30,
                         (None, "unknown_id"): 1, (None, "unsupported"): 2}
        for _ in range(30):
            ctl.send(0x201, b"\x00")  # wrong length
        now_s[0] += 0.5
        emulator.service(0.0)
        assert len([e for e, _ in log.events if e == "bad_frame"]) == 4  # not within 1 s
        now_s[0] += 0.6
        emulator.service(0.0)
        last = [f for e, f in log.events if e == "bad_frame"][4:]
        assert [(f["node_id"], f["kind"], f["count"], f["new"]) for f in last] == [
            (1, "wrong_length", 60, 30)]
        assert emulator.r_node.state is DriveState.SWITCH_ON_DISABLED
        emulator.close()
    finally:
        controller_bus.shutdown()
        emulator_bus.shutdown()


@pytest.mark.parametrize("foreign", [
    can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False),
    can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=True),
], ids=["unknown-id", "29-bit"])
def test_a_frame_the_filters_drop_holds_back_nothing_behind_it(
        rig: tuple[Controller, Emulator, io.StringIO], foreign: can.Message) -> None:
    """On ``virtual`` (and ``udp_multicast``) python-can filters in software and
    ``recv(0)`` returns None at the first frame that fails: with the filters set on the
    bus, three such frames held the SYNC behind them for one service round, and a
    lock-stepped daemon faulted ("no TPDO1 for 3 cycles"). Each round now handles the
    SYNC that follows them."""
    ctl, emulator, _ = rig
    ctl.nmt(NmtCommand.START)
    for cycle in range(3):
        for _ in range(3):
            ctl.bus.send(foreign)
        frames = ctl.cycle({})
        assert emulator.stats.syncs == cycle + 1
        assert [can_id for can_id, _ in frames if can_id in (0x181, 0x182)] == [0x181, 0x182]
    assert emulator.stats.bad.total == 0  # dropped as a drive's acceptance filter drops them


def test_heartbeats_go_on_while_frames_come_faster_than_they_are_handled() -> None:
    """Every reading of the injected clock costs 15 ms, so 100 queued frames take over a
    second to handle: the drives' heartbeat (100 ms) still goes out every 100 ms, between
    frames, instead of waiting until the queue is empty (what stopped them in the
    service VM)."""
    channel = f"test-emulator-flood-{os.getpid()}"
    controller_bus = can.Bus(interface="virtual", channel=channel)
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    now_s = [100.0]

    def clock() -> float:
        now_s[0] += 0.015
        return now_s[0]

    try:
        emulator = Emulator(EmulatorConfig(), emulator_bus, clock=clock, log=RecordingLog())
        emulator.start()
        ctl = Controller(controller_bus, emulator)
        for node_id in NODES:  # heartbeat producer 0x1017 = 100 ms
            assert ctl.sdo(node_id, sdo_download(0x1017, 0, 100, 2))[0] == "ok"
        ctl.receive()
        for _ in range(100):
            ctl.send(0x600 + 1, sdo_upload(0x1017, 0))
        started_s = now_s[0]
        while emulator.service(0.0):
            pass
        elapsed_s = now_s[0] - started_s
        beats = [f for f in ctl.receive() if f[0] == 0x700 + 1]
        assert elapsed_s > 1.0
        assert len(beats) >= int(elapsed_s / 0.1) - 2, (len(beats), elapsed_s)
        emulator.close()
    finally:
        controller_bus.shutdown()
        emulator_bus.shutdown()


# ----------------------------------------------------------------------------- faults, timing


def _with(**sections: dict[str, Any]) -> EmulatorConfig:
    config = EmulatorConfig()
    return dataclasses.replace(config, **{
        name: dataclasses.replace(getattr(config, name), **values)
        for name, values in sections.items()})


@pytest.mark.parametrize("rig", [_with(faults={"silence_node_id": 2, "silence_after_s": 0.0,
                                                "tx_loss_probability": 0.5,
                                                "loss_node_id": 1})], indirect=True)
def test_injected_silence_and_tx_loss(rig: Any) -> None:
    ctl, emulator, _ = rig
    frames = ctl.receive() + ctl.nmt(NmtCommand.START)
    tpdo1_r = 0
    for _ in range(400):
        cycle = ctl.cycle({})
        tpdo1_r += len(of(cycle, 0x181))
        frames += cycle
    assert not [i for i, _ in frames if i & 0x7F == 2]  # node 2 silent from the start
    assert 120 < tpdo1_r < 280  # node 1 loses half of what it sends
    assert emulator.stats.tx_dropped >= 400 - tpdo1_r
    assert emulator.theta_node.stats.syncs == 400  # it hears, it does not speak
    assert emulator.stats.tx_silenced >= 400


def test_wallclock_physics_follows_the_wall_clock() -> None:
    """In wall-clock mode the physics follows the emulator's clock between SYNCs and
    catches up at a SYNC; the clock is injected, so the machine's load does not matter."""
    now = [0.0]
    channel = f"test-emulator-{os.getpid()}-{next(_channels)}"
    controller_bus = can.Bus(interface="virtual", channel=channel)
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    try:
        emulator = Emulator(_with(drives={"timing": TimingMode.WALLCLOCK}), emulator_bus,
                            clock=lambda: now[0], log=RecordingLog())
        emulator.start()
        ctl = Controller(controller_bus, emulator)
        for _ in range(200):  # 0.2 s, serviced every millisecond
            now[0] += 0.001
            ctl.exchange()
        assert emulator.time_s == pytest.approx(0.2, abs=0.0025)  # at most 2 periods behind
        ctl.nmt(NmtCommand.START)
        now[0] += 0.01  # 10 ms with nothing serviced
        ctl.cycle({})
        assert emulator.time_s == pytest.approx(now[0], abs=0.0015)  # caught up at the SYNC
        emulator.close()
    finally:
        controller_bus.shutdown()
        emulator_bus.shutdown()


# ----------------------------------------------------------------------------- the process


def test_config_file_loads_and_errors_name_file_and_line(tmp_path: Path) -> None:
    config = load_config(ROOT / "config" / "emulator.yaml", ["drives.timing=wallclock"])
    assert config.drives.timing is TimingMode.WALLCLOCK
    defaults = EmulatorConfig().physics
    assert dataclasses.replace(config.physics, ground=defaults.ground) == defaults
    (anvil,) = config.physics.ground.objects.stones  # the tine-mount check's (config/rakectl.yaml)
    assert (anvil.reach_m, -anvil.depth_m) == (0.45, 0.1)
    bad = tmp_path / "emulator.yaml"
    bad.write_text("drives:\n  start_r_m: 0.2\n")
    with pytest.raises(ConfigError, match=r"emulator.yaml:2: drives.start_r_m must lie"):
        load_config(bad)
    assert main(["--config", str(bad)]) == 2


def test_bad_command_lines_are_one_line_and_start_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A file that cannot be written is said before the bus opens; --bench takes at
    least one cycle (0 used to start the emulator, -5 to time minus five cycles)."""
    for argv, expected in (
            (["--truth", str(tmp_path / "no" / "truth.csv")], "cannot write "),
            (["--set", f"bus.trace_path={tmp_path / 'no' / 'trace.log'}"], "cannot write ")):
        assert main([*argv, "--interface", "virtual"]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"python -m drivers: {expected}{tmp_path / 'no'}")
        assert len(err.strip().splitlines()) == 1
    for count in ("0", "-5", "two"):
        with pytest.raises(SystemExit) as exit_:
            main(["--bench", count])
        assert exit_.value.code == 2
        assert "argument --bench: must be" in capsys.readouterr().err


def test_process_prints_ready_and_exits_cleanly_on_sigterm(tmp_path: Path) -> None:
    truth = tmp_path / "truth.csv"
    process = subprocess.Popen(
        [sys.executable, "-m", "drivers", "--config", str(ROOT / "config" / "emulator.yaml"),
         "--interface", "virtual", "--channel", "proc", "--truth", str(truth)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        assert process.stdout.readline() == "emulator: ready node-ids 1,2 on virtual:proc\n"
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, stderr
    assert '"event": "emulator_stopped"' in stderr
    assert truth.read_text().splitlines() == [",".join(TRUTH_COLUMNS)]
