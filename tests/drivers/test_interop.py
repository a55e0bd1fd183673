"""Tier 3: the emulated drives cycled by a CANopen master the project did not write,
and by the controller's own master configured as such a master would be.

The master is the ``canopen`` package's own (``Network``, ``RemoteNode`` over the
drives' EDS, its ``SyncProducer``, its PDO and SDO clients), on a python-can
``virtual`` bus; the emulator runs in a thread on its own bus object, lockstep
(one control period per SYNC). What a lab's tool does by default must work:
SYNC without a counter once 0x1019 is 0, PDO mapping read back over SDO as
the EDS declares it and remapped in CiA 301's order, heartbeats, EMCY.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
from can.interfaces.virtual import VirtualBus

from drivers.drive_spec import DriveKind, DriveSpec
from drivers.emulator import Emulator
from drivers.settings import EmulatorConfig
from rakectl.config.service import BusSettings, DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.canbus import open_trace
from rakectl.drive.client import DriveClient
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.nmt import EmcyCode
from tests.drivers.test_emulator_bus import RecordingLog

_channels = itertools.count()
R_NODE, THETA_NODE = 1, 2
TIMEOUT_S = 2.0


@pytest.fixture
def master() -> Iterator[tuple[canopen.Network, Emulator]]:
    """canopen's master on the controller's bus, and the emulator (emulated_drives)."""
    with emulated_drives() as (emulator, bus):
        network = canopen.Network(bus)
        network.connect()  # its Notifier on the bus given
        try:
            yield network, emulator
        finally:
            network.disconnect()


def _remote(network: canopen.Network, node_id: int, kind: DriveKind) -> canopen.RemoteNode:
    node = canopen.RemoteNode(node_id, str(kind.eds_path))
    network.add_node(node)
    return node


def _eds_mapping(node: canopen.RemoteNode, index: int) -> list[tuple[int, int]]:
    """(object index, subindex) of each mapped entry, as the EDS declares them."""
    record = node.object_dictionary[index]
    count = record[0].default
    return [((record[k].default >> 16) & 0xFFFF, (record[k].default >> 8) & 0xFF)
            for k in range(1, count + 1)]


def test_canopen_master_brings_up_and_cycles_the_drives(
        master: tuple[canopen.Network, Emulator]) -> None:
    network, _ = master
    r = _remote(network, R_NODE, DriveKind.DC_SERVO)
    theta = _remote(network, THETA_NODE, DriveKind.GEARED_MOTOR)

    # Boot-up after NMT reset communication; identity and device name over SDO.
    network.nmt.state = "RESET COMMUNICATION"
    r.nmt.wait_for_bootup(TIMEOUT_S)
    assert r.sdo[0x1018][2].raw == 1 and theta.sdo[0x1018][2].raw == 2
    assert r.sdo[0x1008].raw  # segmented upload of a VISIBLE_STRING

    # PDO communication and mapping parameters read back match the EDS.
    for node in (r, theta):
        node.tpdo.read()
        node.rpdo.read()
        tpdo1, rpdo1 = node.tpdo[1], node.rpdo[1]
        assert [(v.index, v.subindex) for v in tpdo1.map] == _eds_mapping(node, 0x1A00)
        assert [(v.index, v.subindex) for v in rpdo1.map] == _eds_mapping(node, 0x1600)
        assert tpdo1.cob_id == 0x180 + node.id and rpdo1.cob_id == 0x200 + node.id

    # The master's default SYNC has no counter: set 0x1019 = 0 in PRE-OPERATIONAL, with
    # the communication cycle period 0x1006 at 0 meanwhile (CiA 301), then restored.
    for node in (r, theta):
        _abort(0x08000022, lambda node=node: setattr(node.sdo[0x1019], "raw", 0))
        node.sdo[0x1006].raw = 0
        node.sdo[0x1019].raw = 0
        node.sdo[0x1006].raw = 1000
    network.nmt.state = "OPERATIONAL"
    assert r.nmt.wait_for_heartbeat(TIMEOUT_S) == "OPERATIONAL"

    # Enable r through CiA 402 over SDO (a 1 s command watchdog: this master is a
    # test, not a 1 kHz loop), command 2 V through its RPDO1, cycle by SYNC.
    r.sdo[0x2003].raw = 1000
    for controlword in (0x06, 0x07, 0x0F):
        r.sdo[0x6040].raw = controlword
    assert r.sdo[0x6041].raw & 0x6F == 0x27  # OPERATION ENABLED
    received: list[int] = []
    r.tpdo[1].add_callback(lambda pdo: received.append(pdo[0].raw))
    rpdo1 = r.rpdo[1]
    for cycle in range(60):
        rpdo1[0].raw, rpdo1[1].raw = 2000, 0x0F  # voltage mV (0x2000), controlword
        rpdo1.transmit()
        network.sync.transmit()
        deadline_s = time.monotonic() + TIMEOUT_S
        while len(received) <= cycle and time.monotonic() < deadline_s:
            time.sleep(0.0005)
        assert len(received) == cycle + 1, f"no TPDO1 answered SYNC {cycle}"
    assert r.tpdo[1][0].od.index == 0x6064
    assert received[-1] > received[0]  # the carriage moved out under +2 V
    assert r.sdo[0x6041].raw & 0x6F == 0x27  # no fault on the way

    # A SYNC with a counter is now the wrong length: EMCY 0x8240, ignored.
    network.sync.transmit(1)
    assert r.emcy.wait(EmcyCode.SYNC_DATA_LENGTH, TIMEOUT_S) is not None
    assert r.sdo[0x1003][0].raw >= 1  # the pre-defined error field, newest first
    assert r.sdo[0x1003][1].raw & 0xFFFF == EmcyCode.SYNC_DATA_LENGTH
    assert r.sdo[0x1001].raw == 0  # a warning: no error register bit stays set

    # Back to PRE-OPERATIONAL: 0 V at once, no PDOs (CiA 301).
    network.nmt.state = "PRE-OPERATIONAL"
    assert r.sdo[0x2000].raw == 0


def _abort(code: int, write: Callable[[], None]) -> None:
    with pytest.raises(canopen.SdoAbortedError) as refused:
        write()
    assert refused.value.code == code, f"0x{refused.value.code:08X}"


def test_a_canopen_master_remaps_the_pdos_in_the_cia301_order(
        master: tuple[canopen.Network, Emulator]) -> None:
    """canopen's PdoMap.save writes in CiA 301's order (COB-ID not valid, sub 0 = 0, the
    entries, sub 0 = n, COB-ID valid): TPDO1 of the r drive remapped to statusword and
    position, RPDO1 to the voltage alone. The mapping reads back, the frames carry what
    it names, and NMT reset communication restores the EDS's."""
    network, _ = master
    r = _remote(network, R_NODE, DriveKind.DC_SERVO)
    network.nmt.state = "RESET COMMUNICATION"
    r.nmt.wait_for_bootup(TIMEOUT_S)
    r.sdo[0x1006].raw = 0  # 0x1019 changes only while the communication cycle period is 0
    r.sdo[0x1019].raw = 0
    r.tpdo.read()
    r.rpdo.read()
    tpdo1, rpdo1 = r.tpdo[1], r.rpdo[1]
    tpdo1.clear()
    tpdo1.add_variable(0x6041)
    tpdo1.add_variable(0x6064)
    tpdo1.enabled = True
    tpdo1.save()
    rpdo1.clear()
    rpdo1.add_variable(0x2000)
    rpdo1.enabled = True
    rpdo1.save()
    assert [r.sdo[0x1A00][k].raw for k in (0, 1, 2)] == [2, 0x60410010, 0x60640020]
    assert [r.sdo[0x1600][k].raw for k in (0, 1)] == [1, 0x20000010]
    assert r.sdo[0x1800][1].raw == 0x181 and r.sdo[0x1400][1].raw == 0x201

    network.nmt.state = "OPERATIONAL"
    assert r.nmt.wait_for_heartbeat(TIMEOUT_S) == "OPERATIONAL"
    frames: list[bytes] = []
    tpdo1.add_callback(lambda pdo: frames.append(bytes(pdo.data)))
    rpdo1[0].raw = 1234  # mV, applied at the next SYNC
    rpdo1.transmit()
    for cycle in range(3):
        network.sync.transmit()
        deadline_s = time.monotonic() + TIMEOUT_S
        while len(frames) <= cycle and time.monotonic() < deadline_s:
            time.sleep(0.0005)
    assert len(frames) == 3 and all(len(f) == 6 for f in frames)  # 16 + 32 bits
    statusword, position = tpdo1[0].raw, tpdo1[1].raw
    assert statusword == r.sdo[0x6041].raw
    assert abs(position - r.sdo[0x6064].raw) <= 50  # the disarmed arm sinks slowly
    assert r.sdo[0x2000].raw == 1234  # the 2-byte RPDO1 was taken

    network.nmt.state = "RESET COMMUNICATION"
    r.nmt.wait_for_bootup(TIMEOUT_S)
    assert [r.sdo[0x1A00][k].raw for k in (0, 1, 2, 3)] == [3, 0x60640020, 0x606C0010,
                                                            0x21000010]
    assert [r.sdo[0x1600][k].raw for k in (0, 1, 2)] == [2, 0x20000010, 0x60400010]


def test_a_remap_out_of_order_or_beyond_the_pdo_is_refused_with_cia301_aborts(
        master: tuple[canopen.Network, Emulator]) -> None:
    network, _ = master
    r = _remote(network, R_NODE, DriveKind.DC_SERVO)
    network.nmt.state = "RESET COMMUNICATION"
    r.nmt.wait_for_bootup(TIMEOUT_S)
    mapping, cob_id = r.sdo[0x1A00], r.sdo[0x1800][1]

    def write(variable: Any, value: int) -> Callable[[], None]:
        def do() -> None:
            variable.raw = value
        return do

    _abort(0x06010000, write(mapping[0], 0))  # the PDO is still valid
    _abort(0x06090030, write(cob_id, 0x80000182))  # another CAN-ID
    cob_id.raw = 0x80000181  # not valid
    _abort(0x06010000, write(mapping[1], 0x60410010))  # sub 0 is not 0 yet
    mapping[0].raw = 0
    _abort(0x06090030, write(cob_id, 0x181))  # valid over an empty mapping
    _abort(0x06020000, write(mapping[1], 0x70000010))  # no such object
    _abort(0x06040041, write(mapping[1], 0x10080000))  # the device name: not mappable
    _abort(0x06040041, write(mapping[1], 0x60640010))  # a 32-bit object as 16 bits
    for k, entry in ((1, 0x60640020), (2, 0x60640020), (3, 0x60640020)):
        mapping[k].raw = entry
    _abort(0x06040042, write(mapping[0], 3))  # 96 bits
    _abort(0x06040042, write(mapping[0], 4))  # beyond the entries the EDS gives it
    mapping[0].raw = 2
    cob_id.raw = 0x181
    assert [mapping[k].raw for k in (0, 1, 2)] == [2, 0x60640020, 0x60640020]
    rpdo_mapping = r.sdo[0x1600]
    r.sdo[0x1400][1].raw = 0x80000201
    rpdo_mapping[0].raw = 0
    _abort(0x06040041, write(rpdo_mapping[1], 0x60410010))  # the drive reports it, not takes it


@contextlib.contextmanager
def emulated_drives(receive_own: bool = False, config: EmulatorConfig | None = None, *,
                    specs: tuple[DriveSpec, DriveSpec] | None = None,
                    bus_class: type[VirtualBus] = VirtualBus, heard_boot: bool = True,
                    period_s: float = 0.005) -> Iterator[tuple[Emulator, can.BusABC]]:
    """The emulator serviced in a thread (every ``period_s``) on one virtual channel (its
    end a ``bus_class``), and the controller's bus on the same channel (``receive_own``:
    it echoes what it sends, as udp_multicast does), opened before the drives power on
    and send their boot-up, or with ``heard_boot`` False after: it has heard nothing of
    them."""
    channel = f"test-interop-{os.getpid()}-{next(_channels)}"
    emulator_bus = bus_class(channel=channel)

    def controller() -> VirtualBus:
        return VirtualBus(channel=channel, receive_own_messages=receive_own)

    controller_bus = controller() if heard_boot else None
    emulator = Emulator(config or EmulatorConfig(), emulator_bus, log=RecordingLog(),
                        specs=specs)
    stop = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop.is_set, period_s), daemon=True)
    try:
        emulator.start()
        if controller_bus is None:
            controller_bus = controller()
        thread.start()
        yield emulator, controller_bus
    finally:
        stop.set()
        thread.join(5.0)
        emulator.close()
        if controller_bus is not None:
            controller_bus.shutdown()
        emulator_bus.shutdown()


def test_the_controller_runs_the_drives_on_sync_without_counter() -> None:
    """drives.sync_counter_overflow = 0: bring-up writes 0x1019 = 0 to both emulated
    drives and reads it back; every SYNC then goes out without data and each drive
    answers it with a TPDO1, with no EMCY and no drive fault. The watchdog and heartbeat
    timeouts are long: this test's loop is not real-time, and a loaded machine can hold
    it past the robot's 3 ms."""
    drives = replace(DrivesSettings(), sync_counter_overflow=0, watchdog_timeout_ms=1000,
                     heartbeat_timeout_ms=5000)
    with emulated_drives() as (emulator, controller_bus):
        client = DriveClient(controller_bus, drives, MotorsSettings(), rate_hz=1000.0)
        r_info, theta_info = client.bring_up(boot_timeout_s=TIMEOUT_S)
        assert r_info.limits.sync_counter_overflow == theta_info.limits.sync_counter_overflow == 0
        for _ in range(50):
            client.sync()
            deadline_s = time.monotonic() + TIMEOUT_S
            while client.receive() == 0 and time.monotonic() < deadline_s:
                time.sleep(0.0005)
        assert min(client.stats.tpdo_received) >= 40  # a few may land after the next SYNC
        assert not client.drive_faults()
        assert [node.stats.bad.total for node in emulator.nodes] == [0, 0]
        deadline_s = time.monotonic() + TIMEOUT_S  # the emulator's thread takes the last
        while emulator.stats.syncs < 50 and time.monotonic() < deadline_s:
            time.sleep(0.001)
        assert emulator.stats.syncs == 50
        client.shutdown()


def test_a_fault_the_previous_run_left_is_cleared_at_bring_up() -> None:
    """A controller that stops (its heartbeat lost: both drives fault, 0x8130) and a new
    one that brings the same drives up: they are fault-reset during bring-up, once reset
    communication has cleared the cause, and start SWITCH ON DISABLED, not in FAULT."""
    with emulated_drives() as (emulator, controller_bus):
        first = DriveClient(controller_bus, DrivesSettings(), MotorsSettings(), rate_hz=1000.0)
        first.bring_up(boot_timeout_s=TIMEOUT_S)
        for _ in range(20):  # the drives monitor the controller's heartbeat from now on
            first.sync()
            time.sleep(0.001)
        deadline_s = time.monotonic() + TIMEOUT_S  # the controller dies: silence
        while any(node.fault is None for node in emulator.nodes):
            assert time.monotonic() < deadline_s, "the drives did not fault"
            time.sleep(0.01)
        assert {node.fault for node in emulator.nodes} == {EmcyCode.HEARTBEAT_LOST}
        second = DriveClient(controller_bus, DrivesSettings(), MotorsSettings(), rate_hz=1000.0)
        infos = second.bring_up(boot_timeout_s=TIMEOUT_S)
        assert [i.cleared_fault for i in infos] == [EmcyCode.HEARTBEAT_LOST] * 2
        assert [i.state for i in infos] == [DriveState.SWITCH_ON_DISABLED] * 2
        assert all(node.fault is None for node in emulator.nodes)
        second.shutdown()


def test_the_bus_trace_holds_the_bring_up_and_each_frame_once(tmp_path: Path) -> None:
    """The daemon's trace (bus.trace_path) from the bring-up on: its SDO and NMT frames are
    in it, and a frame the controller sent is in it once, as sent, even on a bus that
    echoes it back (as udp_multicast does; python-can's virtual bus here, told to)."""
    path = tmp_path / "trace.log"
    trace = open_trace(BusSettings(trace_path=str(path)))
    assert trace is not None
    with emulated_drives(receive_own=True) as (_, controller_bus):
        client = DriveClient(controller_bus, DrivesSettings(), MotorsSettings(), 1000.0, trace)
        client.bring_up(boot_timeout_s=TIMEOUT_S)
        for _ in range(20):
            client.sync()
            time.sleep(0.002)
            client.receive()
        client.shutdown()
        trace.drain(1_000_000)
        trace.close()
    frames = list(can.CanutilsLogReader(str(path)))
    sent = [f for f in frames if not f.is_rx]
    received = [f for f in frames if f.is_rx]
    assert any(f.arbitration_id == 0x601 for f in sent)  # the bring-up's SDO requests …
    assert any(f.arbitration_id == 0x581 for f in received)  # … and the drives' answers
    assert any(f.arbitration_id == 0x000 for f in sent)  # NMT
    assert len([f for f in sent if f.arbitration_id == 0x080]) == 20 + 1  # + stop_all's SYNC
    own = {0x000, 0x080, 0x201, 0x202, 0x601, 0x602, 0x70A}
    assert not [f for f in received if f.arbitration_id in own]  # no echo twice, as R
