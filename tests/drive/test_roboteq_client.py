"""The controller's drive client on the Roboteq-class profile (``drives.profile: roboteq``),
against the emulator playing that drive, serviced in a thread on a virtual bus: bring-up
(limits in the drive's units, the supply check, the power stage switched off), the hot
path's codecs (the command in ‰ of the configured supply, the current in 0.1 A, the flags
read as CiA 402 states) and the power requests that stand in for the controlword."""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import replace

import can
import pytest

from drivers.emulator import Emulator
from drivers.settings import EmulatorConfig
from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.client import DriveClient
from rakectl.drive.joints import Joint
from rakectl.drive.profiles import drive_parameters
from rakectl.errors import DriveFault, NonFiniteError
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveCommand, DriveState
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import EmcyCode
from tests.drivers.test_interop import TIMEOUT_S, emulated_drives

# A loop that is not real-time: the drives' watchdog and heartbeat timeouts are long here
# (tests/drivers/test_roboteq.py shows the watchdog itself).
DRIVES = replace(DrivesSettings(), profile=DriveProfile.ROBOTEQ, watchdog_timeout_ms=1000,
                 heartbeat_timeout_ms=5000)


def roboteq_emulator() -> EmulatorConfig:
    config = EmulatorConfig()
    return replace(config, drives=replace(config.drives, profile=DriveProfile.ROBOTEQ))


@pytest.fixture
def rig() -> Iterator[tuple[DriveClient, Emulator]]:
    with emulated_drives(config=roboteq_emulator()) as (emulator, bus):
        client = DriveClient(bus, DRIVES, MotorsSettings(), rate_hz=1000.0)
        yield client, emulator


def tick(client: DriveClient, voltages: tuple[float, float] = (0.0, 0.0)) -> None:
    """One control cycle, waiting for both drives' TPDO1 (this loop is not real-time)."""
    deadline_s = time.monotonic() + TIMEOUT_S
    before = list(client.stats.tpdo_received)
    client.send(*voltages)
    client.sync()
    while time.monotonic() < deadline_s:
        client.receive()
        if all(a > b for a, b in zip(client.stats.tpdo_received, before, strict=True)):
            return
        time.sleep(0.0005)
    raise AssertionError("no TPDO1 from both drives")


def until(client: DriveClient, done: Callable[[], bool], voltages: tuple[float, float] = (0, 0),
          ticks: int = 300) -> int:
    for k in range(ticks):
        if done():
            return k
        tick(client, voltages)
    raise AssertionError("not reached")


def test_bring_up_writes_the_limits_in_the_drives_units_and_switches_them_off(
        rig: tuple[DriveClient, Emulator]) -> None:
    client, emulator = rig
    infos = client.bring_up(boot_timeout_s=TIMEOUT_S)
    for info, node in zip(infos, emulator.nodes, strict=True):
        assert info.identity.product_code == 3
        assert info.state is DriveState.SWITCH_ON_DISABLED  # the emergency stop flag
        assert info.statusword >> 16 == roboteq.FAULT_EMERGENCY_STOP
        assert info.limits.watchdog_timeout_ms == 1000  # 0x3001, read back
        assert info.limits.max_voltage_mv == 24000  # the configured supply: no limit object
        assert node.output_voltage_v == 0.0
    assert infos[Joint.R].limits.current_limit_ma == 6000  # 0x3002 = 60 × 0.1 A
    assert infos[Joint.THETA].limits.current_limit_ma == 10000
    assert emulator.theta_node.motor_params.current_limit_a == pytest.approx(10.0)
    client.shutdown()


def test_enable_drive_and_disable_through_power_requests(
        rig: tuple[DriveClient, Emulator]) -> None:
    client, emulator = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    tick(client)
    assert client.feedback.state == [DriveState.SWITCH_ON_DISABLED] * 2
    assert client.path_to_enabled(DriveState.SWITCH_ON_DISABLED) == [
        DriveCommand.ENABLE_OPERATION]
    client.command(None, DriveCommand.ENABLE_OPERATION)
    until(client, lambda: client.feedback.state == [DriveState.OPERATION_ENABLED] * 2)
    # 2.4 V = 100 ‰ of the configured 24 V: what the emulated bridge applies.
    until(client, lambda: emulator.r_node.output_voltage_v > 0, voltages=(2.4, -1.2))
    assert emulator.r_node.output_voltage_v == pytest.approx(2.4)
    assert emulator.theta_node.output_voltage_v == pytest.approx(-1.2)
    tick(client, (2.4, -1.2))
    current_a = emulator.r_node._current_a
    assert client.feedback.current_r_a == pytest.approx(round(current_a * 10) / 10, abs=0.11)
    assert not math.isnan(client.feedback.r_m) and not client.drive_faults()
    client.command(None, DriveCommand.DISABLE_VOLTAGE)
    until(client, lambda: client.feedback.state == [DriveState.SWITCH_ON_DISABLED] * 2,
          voltages=(2.4, -1.2))
    assert [n.output_voltage_v for n in emulator.nodes] == [0.0, 0.0]  # commands or not
    assert client.stats.sdo_answers >= 4  # each request answered by its drive
    client.shutdown()


def test_a_non_finite_voltage_raises_before_anything_is_sent(
        rig: tuple[DriveClient, Emulator]) -> None:
    client, _ = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    sends = client.stats.sends
    with pytest.raises(NonFiniteError):
        client.send(math.nan, 0.0)
    assert client.stats.sends == sends
    client.shutdown()


def test_a_lost_heartbeat_fault_is_reset_to_switched_off(
        rig: tuple[DriveClient, Emulator]) -> None:
    """The controller falls silent past the drives' heartbeat timeout (0x1016 set short in
    the emulated drives after bring-up): EMCY 0x8130, a fault; FAULT_RESET releases and
    switches the power stage off again, as a CiA 402 fault reset ends in SWITCH ON
    DISABLED."""
    client, emulator = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    client.command(None, DriveCommand.ENABLE_OPERATION)
    until(client, lambda: client.feedback.state == [DriveState.OPERATION_ENABLED] * 2)
    for node in emulator.nodes:
        node._consumer = node._consumer & ~0xFFFF | 30  # 30 ms
    time.sleep(0.2)  # silence
    until(client, lambda: client.drive_faults())
    assert {e.code for e in client.feedback.last_emcy if e} == {EmcyCode.HEARTBEAT_LOST}
    assert [n.output_voltage_v for n in emulator.nodes] == [0.0, 0.0]
    for node in emulator.nodes:
        node._consumer = node._consumer & ~0xFFFF | 5000
    for _ in range(101):  # the controller's heartbeat is back (every 100 ms): the cause gone
        tick(client)
    # Nothing releases them behind the daemon's back: faulted until the fault reset.
    assert client.drive_faults() and client.feedback.state == [DriveState.FAULT] * 2
    assert all(n.fault is EmcyCode.HEARTBEAT_LOST for n in emulator.nodes)
    assert [n.output_voltage_v for n in emulator.nodes] == [0.0, 0.0]
    client.command(None, DriveCommand.FAULT_RESET)
    until(client, lambda: not client.drive_faults()
          and client.feedback.state == [DriveState.SWITCH_ON_DISABLED] * 2)
    assert all(n.fault is None for n in emulator.nodes)
    client.shutdown()


def test_an_emergency_stop_the_controller_did_not_send_is_a_fault_until_reset(
        rig: tuple[DriveClient, Emulator]) -> None:
    """Another tool, or the drive's own e-stop input, switches r off while the daemon has it
    on: the client reads a fault (the flags alone read as switched off) and does not
    switch it back on; a fault reset leaves it off, the fault cleared."""
    client, emulator = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    client.command(None, DriveCommand.ENABLE_OPERATION)
    until(client, lambda: client.feedback.state == [DriveState.OPERATION_ENABLED] * 2)
    emulator.r_node._write_emergency_shutdown(1)  # as an SDO write from elsewhere does
    until(client, lambda: client.drive_faults(), voltages=(1.0, 0.0))
    assert client.feedback.state[Joint.R] is DriveState.SWITCH_ON_DISABLED
    problems = client.describe_problems(client.clock(), 1000)
    assert problems == ["r drive (node 1): its power stage went off by itself (fault flags "
                        "0x0010, status flags 0x0009)"], problems
    for _ in range(120):  # more than a request's period: no release goes out
        tick(client, (1.0, 0.0))
    assert client.drive_faults() and emulator.r_node.output_voltage_v == 0.0
    client.command(None, DriveCommand.FAULT_RESET)
    until(client, lambda: not client.drive_faults()
          and client.feedback.state == [DriveState.SWITCH_ON_DISABLED] * 2)
    assert [n.output_voltage_v for n in emulator.nodes] == [0.0, 0.0]
    client.shutdown()


def test_a_supply_above_the_configured_one_is_refused() -> None:
    """The command is ‰ of motors.<joint>.supply_voltage_v: a drive whose supply reads
    higher would apply more than commanded."""
    motors = MotorsSettings()
    motors = replace(motors, r=replace(motors.r, supply_voltage_v=20.0))
    with emulated_drives(config=roboteq_emulator()) as (_, bus):
        client = DriveClient(bus, DRIVES, motors, rate_hz=1000.0)
        with pytest.raises(DriveFault, match=r"r drive \(node 1\): its supply reads 24 V "
                           r"\(0x210D:2\), above the 20 V .*motors\.r\.supply_voltage_v"):
            client.bring_up(boot_timeout_s=TIMEOUT_S)


@pytest.mark.parametrize(("voltage_v", "supply_v", "per_mille"), [
    (0.0, 24.0, 0), (24.0, 24.0, 1000), (-24.0, 24.0, -1000), (30.0, 24.0, 1000),
    (2.4, 24.0, 100), (0.0119, 24.0, 0), (0.0121, 24.0, 1), (-6.0, 12.0, -500)])
def test_volts_to_per_mille_by_hand(voltage_v: float, supply_v: float, per_mille: int) -> None:
    assert roboteq.volts_to_per_mille(voltage_v, supply_v) == per_mille


@pytest.mark.parametrize(("limit_a", "written"), [(6.0, 60), (5.96, 59), (0.35, 3)])
def test_the_amps_limit_is_rounded_down_to_the_drives_step(limit_a: float, written: int) -> None:
    """The clamp takes the configured current limit as the drive's: never above it."""
    motors = MotorsSettings()
    motors = replace(motors, r=replace(motors.r, current_limit_a=limit_a))
    amps = drive_parameters(Joint.R, DRIVES, motors)[0]
    assert (amps.index, amps.value, amps.limit_scale) == (0x3002, written, 100)


def test_a_profile_that_does_not_match_the_drives_is_refused_naming_both() -> None:
    """drives.profile: roboteq on the project's own drives (and the other way round):
    bring-up stops at the identity, before it writes a limit."""
    with emulated_drives() as (emulator, bus):
        client = DriveClient(bus, DRIVES, MotorsSettings(), rate_hz=1000.0)
        with pytest.raises(DriveFault, match=r"r drive \(node 1\): wrong identity: product "
                           r"code 1, expected 3 \(roboteq_class_drive\.eds\)"):
            client.bring_up(boot_timeout_s=TIMEOUT_S)
        assert emulator.r_node.watchdog_timeout_s == 0.02  # its power-on value: not written
    with emulated_drives(config=roboteq_emulator()) as (_, bus):
        client = DriveClient(bus, DrivesSettings(), MotorsSettings(), rate_hz=1000.0)
        with pytest.raises(DriveFault, match=r"r drive \(node 1\): wrong identity: product "
                           r"code 3, expected 1 \(dc_servo_drive\.eds\)"):
            client.bring_up(boot_timeout_s=TIMEOUT_S)


def test_a_watchdog_expiry_gone_within_one_drain_is_latched_naming_it(
        rig: tuple[DriveClient, Emulator]) -> None:
    """A Roboteq-class drive's watchdog lets go at the next command: its flags can read
    expired, then driving again, in the TPDO2s of one drain (a tick late by more than the
    watchdog). The client looked only at the last and went on; now the expiry while
    enabled is latched, and the fault names the flag (no EMCY reports it)."""
    client, emulator = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    client.command(None, DriveCommand.ENABLE_OPERATION)
    until(client, lambda: client.feedback.state == [DriveState.OPERATION_ENABLED] * 2)
    client.enabled()
    tick(client)
    assert not client.drive_faults()
    serial = roboteq.STATUS_SERIAL_MODE
    for status in (serial | roboteq.STATUS_WATCHDOG_EXPIRED, serial):  # as r would send
        emulator.bus.send(can.Message(arbitration_id=0x281, is_extended_id=False,
                                      data=struct.pack("<HH", 0, status)))
    until(client, lambda: client.stats.tpdo2_received[Joint.R] >= 2 and client.drive_faults())
    assert client.feedback.state[Joint.R] is DriveState.OPERATION_ENABLED  # the last read
    assert client.describe_problems(client.clock(), 1000) == [
        "r drive (node 1): left OPERATION ENABLED for FAULT while armed (not by this daemon: "
        "another CANopen master, or the drive itself) (fault flags 0x0000, status flags "
        "0x0021; its command watchdog expired)"]
    client.shutdown()


def test_enabled_asks_the_power_stages_on_even_when_they_already_read_on(
        rig: tuple[DriveClient, Emulator]) -> None:
    """Re-armed a few ticks after a disarm, both drives still read on (their shutdown on
    its way): the daemon took them as enabled without asking them on, and sat ARMED with
    both power stages off and no fault. Now they are asked on, and one that then goes off
    is a fault."""
    client, emulator = rig
    client.bring_up(boot_timeout_s=TIMEOUT_S)
    client.command(None, DriveCommand.ENABLE_OPERATION)
    until(client, lambda: client.feedback.state == [DriveState.OPERATION_ENABLED] * 2)
    client.command(None, DriveCommand.DISABLE_VOLTAGE)  # disarm: the shutdowns go out
    client.send(0.0, 0.0)
    client.sync()
    assert client.feedback.state == [DriveState.OPERATION_ENABLED] * 2  # not read yet
    client.enabled()  # armed again at once
    until(client, lambda: client.drive_faults())
    assert [n.output_voltage_v for n in emulator.nodes] == [0.0, 0.0]
    assert "its power stage went off by itself" in "; ".join(
        client.describe_problems(client.clock(), 1000))
    client.shutdown()
