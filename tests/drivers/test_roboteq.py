"""The emulated Roboteq-class drive (drivers/roboteq.py).

Tier 2: one drive by scripted exchange (frames in, frames out, an injected clock), as
tests/drivers/test_node.py does for the project's own drive. Tier 3: the emulator told
to play two of them (``drives.profile: roboteq``), driven by the canopen package as an
independent master over the drive's EDS.
"""

from __future__ import annotations

import dataclasses
import struct
import time
from collections.abc import Iterator

import canopen
import pytest

from drivers.drive_spec import DriveKind, DriveSpec
from drivers.drives import drive_specs
from drivers.emulator import Emulator
from drivers.node import DriveNode
from drivers.roboteq import RoboteqNode
from drivers.settings import EmulatorConfig
from rakectl.core.motor_model import R_MOTOR_DEFAULT, joint_resolution
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import EmcyCode, NmtCommand
from rakectl.protocol.roboteq import (
    FAULT_COMMUNICATION,
    FAULT_EMERGENCY_STOP,
    FAULT_SENSOR,
    STATUS_POWER_STAGE_OFF,
    STATUS_SERIAL_MODE,
    STATUS_WATCHDOG_EXPIRED,
    per_mille_to_mv,
)
from tests.drivers.test_interop import TIMEOUT_S, emulated_drives
from tests.drivers.test_node import (
    CONTROLLER,
    NODE_ID,
    RPDO1,
    SDO_RX,
    TPDO1,
    TPDO2,
    Bench,
    emcys,
    sdo_download,
    sdo_reply,
    sdo_upload,
)

SUPPLY_MV = 24000


def make_node(**changes: object) -> RoboteqNode:
    spec = DriveSpec(NODE_ID, DriveKind.ROBOTEQ_CLASS, R_MOTOR_DEFAULT, serial_number=4242,
                     controller_node_id=CONTROLLER)
    return RoboteqNode(dataclasses.replace(spec, **changes))


@pytest.fixture
def drive() -> Bench:
    bench = Bench(make_node())
    bench.nmt(NmtCommand.START)
    return bench


def command(bench: Bench, per_mille: int) -> list[tuple[int, bytes]]:
    """One control cycle: SYNC (the drive answers), then the motor command in RPDO1."""
    frames = bench.sync()
    bench.rx(RPDO1, struct.pack("<i", per_mille))
    return frames


def flags(frames: list[tuple[int, bytes]]) -> list[tuple[int, int]]:
    """(fault flags, status flags) of each TPDO2."""
    return [struct.unpack("<HH", data) for can_id, data in frames if can_id == TPDO2]


# ----------------------------------------------------------------------------- tier 2


@pytest.mark.parametrize(("per_mille", "mv"), [
    (0, 0), (1000, 24000), (-1000, -24000), (500, 12000), (1, 24), (-1, -24), (333, 7992)])
def test_the_motor_command_is_a_share_of_the_supply(per_mille: int, mv: int) -> None:
    """Hand-computed: ‰ × 24 000 mV / 1000."""
    assert per_mille_to_mv(per_mille, SUPPLY_MV) == mv


def test_it_drives_in_operational_with_no_enable_sequence(drive: Bench) -> None:
    assert drive.node.output_voltage_v == 0.0
    command(drive, 250)
    assert drive.node.output_voltage_v == 0.0  # applied at the next SYNC
    command(drive, 250)
    assert drive.node.output_voltage_v == pytest.approx(6.0)
    assert drive.sdo(sdo_upload(0x2000, 1)) == ("value", 250)
    drive.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    assert drive.node.output_voltage_v == 0.0  # leaving OPERATIONAL: 0 V at once


def test_tpdo1_carries_counts_rpm_and_tenths_of_an_ampere(drive: Bench) -> None:
    node = drive.node
    resolution = joint_resolution(R_MOTOR_DEFAULT)
    node.sense(1234 * resolution, 10.0 * 3.141592653589793 / 30, 2.34, False, 0.001)
    (frame,) = [d for i, d in command(drive, 0) if i == TPDO1]
    assert struct.unpack("<ihh", frame) == (1234, 10, 23)


def test_the_watchdog_stops_the_motor_and_the_next_command_drives_it_again(
        drive: Bench) -> None:
    assert drive.sdo(sdo_download(0x3001, 0, 5, 2)) == ("ok", 0)  # RWD 5 ms
    command(drive, 500)
    command(drive, 500)
    assert drive.node.output_voltage_v == pytest.approx(12.0)
    frames = drive.at(drive.now_s + 0.005).poll()  # no command for 5 ms
    assert drive.node.output_voltage_v == 0.0
    assert flags(frames) == [(0, STATUS_SERIAL_MODE | STATUS_POWER_STAGE_OFF
                              | STATUS_WATCHDOG_EXPIRED)]
    assert not emcys(frames) and drive.node.fault is None  # not a fault
    command(drive, 100)
    frames = command(drive, 100)
    assert drive.node.output_voltage_v == pytest.approx(2.4)
    assert flags(frames) == [(0, STATUS_SERIAL_MODE)]


def test_a_command_beyond_full_scale_is_applied_at_full_scale_with_one_emcy(
        drive: Bench) -> None:
    command(drive, 1500)
    frames = command(drive, 1500) + command(drive, 1500)
    assert drive.node.output_voltage_v == pytest.approx(24.0)
    assert emcys(frames) == [EmcyCode.INVALID_COMMAND]


def test_emergency_shutdown_latches_until_released(drive: Bench) -> None:
    command(drive, 500)
    command(drive, 500)
    frames = drive.rx(SDO_RX, sdo_download(0x200C, 0, 1, 1))
    assert sdo_reply(frames) == ("ok", 0)
    assert drive.node.output_voltage_v == 0.0
    assert flags(frames) == [(FAULT_EMERGENCY_STOP, STATUS_SERIAL_MODE | STATUS_POWER_STAGE_OFF)]
    command(drive, 500)
    command(drive, 500)
    assert drive.node.output_voltage_v == 0.0  # commands do not lift it
    assert drive.sdo(sdo_download(0x200D, 0, 1, 1)) == ("ok", 0)
    assert drive.node.output_voltage_v == 0.0  # released: from 0 V …
    command(drive, 500)
    command(drive, 500)
    assert drive.node.output_voltage_v == pytest.approx(12.0)  # … the next command drives


def test_controller_heartbeat_loss_is_a_communication_fault_released_once_it_is_back(
        drive: Bench) -> None:
    heartbeat = 0x700 + CONTROLLER
    drive.rx(heartbeat, b"\x05")
    command(drive, 500)
    command(drive, 500)
    frames = drive.at(drive.now_s + 0.25).poll()  # 0x1016: 250 ms
    assert emcys(frames) == [EmcyCode.HEARTBEAT_LOST]
    assert drive.node.output_voltage_v == 0.0
    assert flags(frames)[-1][0] == FAULT_COMMUNICATION
    assert drive.sdo(sdo_download(0x200D, 0, 1, 1)) == ("abort", 0x08000022)  # still lost
    drive.rx(heartbeat, b"\x05")
    frames = drive.rx(SDO_RX, sdo_download(0x200D, 0, 1, 1))
    assert sdo_reply(frames) == ("ok", 0)
    assert emcys(frames) == [EmcyCode.NO_ERROR]
    assert drive.sdo(sdo_upload(0x2112)) == ("value", 0)


def test_a_hard_stop_hit_is_a_sensor_fault(drive: Bench) -> None:
    command(drive, 500)
    command(drive, 500)
    frames = [(i, bytes(d)) for i, d in drive.node.sense(0.0, 0.0, 0.0, True, 0.001)]
    assert emcys(frames) == [EmcyCode.HARD_STOP_HIT]
    assert flags(frames)[-1][0] == FAULT_SENSOR
    assert drive.node.output_voltage_v == 0.0


def test_limits_in_the_drives_own_units(drive: Bench) -> None:
    node = drive.node
    assert drive.sdo(sdo_upload(0x3002)) == ("value", 60)  # 6.0 A: the hardware's
    assert drive.sdo(sdo_download(0x3002, 0, 25, 2)) == ("abort", 0x08000022)  # driving
    drive.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)  # the power stage off: limits may change
    assert drive.sdo(sdo_download(0x3002, 0, 61, 2)) == ("abort", 0x06090031)
    assert drive.sdo(sdo_download(0x3002, 0, 25, 2)) == ("ok", 0)
    assert node.motor_params.current_limit_a == pytest.approx(2.5)
    assert drive.sdo(sdo_download(0x3003, 0, 4096, 4)) == ("ok", 0)
    assert drive.sdo(sdo_upload(0x3003)) == ("value", 4096)
    assert drive.sdo(sdo_upload(0x210D, 2)) == ("value", 240)  # 24.0 V
    # The project's own objects are not there.
    assert drive.sdo(sdo_upload(0x6041)) == ("abort", 0x06020000)
    assert drive.sdo(sdo_download(0x2001, 0, 1000, 2)) == ("abort", 0x06020000)


def test_the_drive_type_must_match() -> None:
    with pytest.raises(ValueError, match="ROBOTEQ_CLASS"):
        make_node(kind=DriveKind.DC_SERVO)


def test_the_default_profile_plays_the_projects_own_drives() -> None:
    config = EmulatorConfig()
    assert config.drives.profile is DriveProfile.CIA402
    assert [s.kind for s in drive_specs(config)] == [DriveKind.DC_SERVO,
                                                    DriveKind.GEARED_MOTOR]


# ----------------------------------------------------------------------------- tier 3


@pytest.fixture
def master() -> Iterator[tuple[canopen.Network, Emulator]]:
    config = EmulatorConfig()
    config = dataclasses.replace(config, drives=dataclasses.replace(
        config.drives, profile=DriveProfile.ROBOTEQ))
    with emulated_drives(config=config) as (emulator, bus):
        network = canopen.Network(bus)
        network.connect()
        try:
            yield network, emulator
        finally:
            network.disconnect()


def test_canopen_master_brings_up_and_drives_the_roboteq_class_drives(
        master: tuple[canopen.Network, Emulator]) -> None:
    network, emulator = master
    assert all(isinstance(n, RoboteqNode) for n in emulator.nodes)
    assert not any(type(n) is DriveNode for n in emulator.nodes)
    nodes = [canopen.RemoteNode(k, str(DriveKind.ROBOTEQ_CLASS.eds_path)) for k in (1, 2)]
    for node in nodes:
        network.add_node(node)
    r = nodes[0]

    network.nmt.state = "RESET COMMUNICATION"
    r.nmt.wait_for_bootup(TIMEOUT_S)
    assert r.sdo[0x1018][2].raw == 3
    assert r.sdo[0x1008].raw == "Roboteq-class motor controller"  # segmented
    for node in nodes:
        node.tpdo.read()
        node.rpdo.read()
        assert [(v.index, v.subindex) for v in node.tpdo[1].map] == [
            (0x2104, 1), (0x2103, 1), (0x2100, 1)]
        assert [(v.index, v.subindex) for v in node.tpdo[2].map] == [(0x2112, 0), (0x2111, 0)]
        assert [(v.index, v.subindex) for v in node.rpdo[1].map] == [(0x2000, 1)]
        node.sdo[0x1006].raw = 0  # CiA 301: 0x1019 changes only while the period is 0
        node.sdo[0x1019].raw = 0  # the master's SYNC has no counter
    r.sdo[0x3001].raw = 1000  # RWD 1 s: this master is a test, not a 1 kHz loop
    network.nmt.state = "OPERATIONAL"
    assert r.nmt.wait_for_heartbeat(TIMEOUT_S) == "OPERATIONAL"

    counts: list[int] = []
    r.tpdo[1].add_callback(lambda pdo: counts.append(pdo[0].raw))
    rpdo1 = r.rpdo[1]
    for cycle in range(60):
        rpdo1[0].raw = 100  # 10 % of the supply: 2.4 V
        rpdo1.transmit()
        network.sync.transmit()
        deadline_s = time.monotonic() + TIMEOUT_S
        while len(counts) <= cycle and time.monotonic() < deadline_s:
            time.sleep(0.0005)
        assert len(counts) == cycle + 1, f"no TPDO1 answered SYNC {cycle}"
    assert emulator.r_node.output_voltage_v == pytest.approx(2.4)
    assert counts[-1] > counts[0]  # the carriage moved out
    assert r.sdo[0x2112].raw == 0

    # Emergency shutdown by SDO: 0 V, fault flag 4 in TPDO2; release: drives again.
    tpdo2: list[int] = []
    r.tpdo[2].add_callback(lambda pdo: tpdo2.append(pdo[0].raw))
    r.sdo[0x200C].raw = 1
    deadline_s = time.monotonic() + TIMEOUT_S
    while FAULT_EMERGENCY_STOP not in tpdo2 and time.monotonic() < deadline_s:
        time.sleep(0.001)
    assert FAULT_EMERGENCY_STOP in tpdo2
    assert emulator.r_node.output_voltage_v == 0.0
    r.sdo[0x200D].raw = 1
    assert r.sdo[0x2112].raw == 0
    network.nmt.state = "PRE-OPERATIONAL"
    assert emulator.r_node.output_voltage_v == 0.0
