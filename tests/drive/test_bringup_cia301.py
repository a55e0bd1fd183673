"""Bring-up (rakectl.drive.bringup) against drives that behave as real CiA 301/402 drives
do where the standard lets them: silent until reset (producer heartbeat 0), a fault reset
acted on in the drive's own cycle, TPDO COB-IDs with bit 30 (no RTR) set, 0x1019 writable
only while 0x1006 is 0 or absent, a stored event timer, a TPDO beyond the EDS's, a short
SDO answer.

Tier 3 (``virtual`` bus): the emulated drives, serviced in a joined thread, varied through
their ``DriveSpec`` (stored values, RTR); the controller's bus is opened only once the
drives have sent their power-on boot-up, as a controller started after the drives is.
Tier 2 (no bus, no thread): canopen ``LocalNode`` servers on the bus-less network of
tests/drive/test_client.py, for what the emulator does not play.
"""

from __future__ import annotations

import contextlib
import itertools
import threading
import time
from dataclasses import replace
from typing import Any

import can
import canopen
import pytest
from can.interfaces.virtual import VirtualBus
from canopen.objectdictionary import ODRecord, ODVariable, datatypes

from drivers.drive_spec import DriveSpec
from drivers.drives import drive_specs
from drivers.emulator import Emulator
from drivers.settings import EmulatorConfig
from rakectl.cli.drives import report, text
from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive import profiles
from rakectl.drive.bringup import BringUp, run_bring_up
from rakectl.drive.joints import DriveInfo, ExtraPdo, Joint, PdoReading, load_drive_od
from rakectl.drive.profiles import drive_parameters
from rakectl.errors import CommsTimeout, DriveFault
from rakectl.protocol import cia402, codec, roboteq
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import EmcyCode, NmtCommand, NmtState, decode_nmt
from tests.drive.test_client import (
    FAST,
    R_NODE,
    THETA_NODE,
    FakeDrive,
    LoopbackNetwork,
    _announce_and_run,
    make_bring_up,
)
from tests.drivers.test_interop import emulated_drives
from tests.drivers.test_node import sdo_reply, sdo_upload

DRIVES = DrivesSettings()
MOTORS = MotorsSettings()
BOOT_TIMEOUT_S = 1.0
ANSWER_TIMEOUT_S = 2.0
NODES = (R_NODE, THETA_NODE)
NO_RTR = 1 << 30
_channels = itertools.count()


# =========================================================================== tier 3: the emulator


def drives_on_a_bus(specs: tuple[DriveSpec, DriveSpec] | None = None,
                    config: EmulatorConfig | None = None,
                    emulator_bus_class: type[VirtualBus] = VirtualBus
                    ) -> contextlib.AbstractContextManager[tuple[Emulator, can.BusABC]]:
    """The emulated drives powered on (their boot-up sent), then the controller's bus
    opened on the same virtual channel: it has heard nothing of them."""
    return emulated_drives(config=config, specs=specs, bus_class=emulator_bus_class,
                           heard_boot=False, period_s=0.002)


def specs_with(**changes: Any) -> tuple[DriveSpec, DriveSpec]:
    r, theta = drive_specs(EmulatorConfig())
    return replace(r, **changes), replace(theta, **changes)


def bring_up(bus: can.BusABC, drives: DrivesSettings = DRIVES) -> Any:
    """The dry run's bring-up (``rakectl drives``): the drives stay PRE-OPERATIONAL."""
    return run_bring_up(bus, drives, MOTORS, BOOT_TIMEOUT_S, start=False)


def sdo_read(bus: can.BusABC, node_id: int, index: int, subindex: int = 0) -> int:
    """One expedited upload by hand, once bring-up's Notifier has stopped."""
    bus.send(can.Message(arbitration_id=0x600 + node_id, data=sdo_upload(index, subindex),
                         is_extended_id=False))
    deadline_s = time.monotonic() + ANSWER_TIMEOUT_S
    while (msg := bus.recv(max(0.0, deadline_s - time.monotonic()))) is not None:
        if msg.arbitration_id == 0x580 + node_id:
            kind, value = sdo_reply([(msg.arbitration_id, bytes(msg.data))], 0x580 + node_id)
            assert kind == "value", f"0x{index:04X}:{subindex}: {kind} 0x{value:08X}"
            return value
    raise AssertionError(f"no SDO answer for 0x{index:04X}:{subindex}")


def test_a_drive_silent_until_reset_is_reset_first_and_brought_up() -> None:
    """Producer heartbeat 0 (CiA 301's default) and powered before the controller: it
    says nothing until NMT reset communication, which bring-up now sends first (it waited
    for a heartbeat before: "no heartbeat or boot-up within 1 s")."""
    with drives_on_a_bus(specs_with(stored=((0x1017, 0, 0),))) as (_, bus):
        sniffer = VirtualBus(channel=bus.channel_id)
        try:
            assert bus.recv(0.3) is None  # silent: no heartbeat
            infos = bring_up(bus)
            first = sniffer.recv(0.0)
        finally:
            sniffer.shutdown()
        assert first is not None and first.arbitration_id == codec.NMT_COB_ID
        assert decode_nmt(first.data) == (NmtCommand.RESET_COMMUNICATION, R_NODE)
        assert [i.limits.heartbeat_period_ms for i in infos] == [DRIVES.heartbeat_period_ms] * 2
        assert [sdo_read(bus, n, 0x1017) for n in NODES] == [DRIVES.heartbeat_period_ms] * 2


def test_a_drive_that_never_answers_is_named_after_the_resets() -> None:
    with drives_on_a_bus(specs_with(stored=((0x1017, 0, 0),))) as (_, bus):
        drives = replace(DRIVES, r_node_id=5)
        started_s = time.monotonic()
        with pytest.raises(CommsTimeout) as raised:
            bring_up(bus, drives)
        assert str(raised.value) == ("r drive (node 5): no heartbeat or boot-up within 1 s "
                                     "(NMT reset communication sent 3 times)")
        assert time.monotonic() - started_s < 2 * BOOT_TIMEOUT_S  # boot_timeout_s in all


def _fault_both_drives(emulator: Emulator, bus: can.BusABC) -> None:
    """A controller that brings the drives up, sends SYNCs (and so its heartbeat), and
    dies: both drives fault, the controller's heartbeat lost (0x8130)."""
    run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
    bus.send(can.Message(arbitration_id=0x700 + DRIVES.controller_node_id, data=b"\x05",
                         is_extended_id=False))
    deadline_s = time.monotonic() + ANSWER_TIMEOUT_S
    while any(node.fault is None for node in emulator.nodes):
        assert time.monotonic() < deadline_s, "the drives did not fault"
        time.sleep(0.01)


def test_a_fault_left_is_reset_in_the_drives_own_cycle() -> None:
    """The emulated drive acts on a fault reset at its next cycle, as a real one does: the
    reset holds 0 then 0x80 a drive cycle each and reads the statusword until it leaves
    FAULT (it wrote 0, 0x80, 0 back to back and read FAULT at once: refused)."""
    with drives_on_a_bus() as (emulator, bus):
        _fault_both_drives(emulator, bus)
        sniffer = VirtualBus(channel=bus.channel_id)
        try:
            infos = bring_up(bus)
            frames = []
            while (msg := sniffer.recv(0.0)) is not None:
                frames.append(msg)
        finally:
            sniffer.shutdown()
    assert [i.cleared_fault for i in infos] == [EmcyCode.HEARTBEAT_LOST] * 2
    assert [i.state for i in infos] == [DriveState.SWITCH_ON_DISABLED] * 2
    for node_id in NODES:
        writes = [(m.timestamp, int.from_bytes(m.data[4:6], "little")) for m in frames
                  if m.arbitration_id == 0x600 + node_id and m.data[:4] == b"\x2b\x40\x60\x00"]
        assert [value for _, value in writes] == [0x0000, 0x0080, 0x0000]
        (zero_s, _), (edge_s, _), (after_s, _) = writes
        assert edge_s - zero_s >= profiles.FAULT_RESET_HOLD_S  # each held a drive cycle
        assert after_s - edge_s >= profiles.FAULT_RESET_HOLD_S


def test_tpdo_cob_ids_with_bit_30_are_the_drives_own() -> None:
    """Drives whose TPDOs answer no RTR report 0x40000181 and refuse a COB-ID without bit
    30: bring-up compares bits 0-29 and 31 only, and writes nothing (it wrote 0x181)."""
    with drives_on_a_bus(specs_with(tpdo_rtr=False)) as (_, bus):
        infos = bring_up(bus)
        for info in infos:
            assert [p.cob_id for p in info.pdos] == [
                0x200 + info.node_id, NO_RTR | 0x180 + info.node_id,
                NO_RTR | 0x280 + info.node_id]
            assert info.rewritten == ()
        assert sdo_read(bus, R_NODE, 0x1800, 1) == NO_RTR | 0x181
    printed = text(report(infos[0], drive_parameters(Joint.R, DRIVES, MOTORS),
                          "dc_servo_drive.eds", "cia402"))  # rakectl drives
    assert "    TPDO1  COB-ID 0x181, no RTR, every SYNC: 0x6064:0 (32 bit)," in printed


def test_a_remap_keeps_bit_30_as_the_drive_holds_it() -> None:
    """TPDO2 stored with the statusword alone, by a tool that set bit 30 in CiA 301's
    order: written back to the EDS's with bit 30 in every COB-ID written."""
    stored = ((0x1801, 1, 1 << 31 | NO_RTR | 0x280 + R_NODE), (0x1A01, 0, 0),
              (0x1A01, 1, 0x60410010), (0x1A01, 0, 1), (0x1801, 1, NO_RTR | 0x280 + R_NODE))
    r, theta = specs_with(tpdo_rtr=False)
    with drives_on_a_bus((replace(r, stored=stored), theta)) as (_, bus):
        r_info, _ = bring_up(bus)
        assert [(p.name, p.mapped) for p in r_info.rewritten] == [("TPDO2", (0x60410010,))]
        assert [sdo_read(bus, R_NODE, 0x1A01, k) for k in (0, 1, 2)] == [2, 0x60410010,
                                                                         0x10010008]
        assert sdo_read(bus, R_NODE, 0x1801, 1) == NO_RTR | 0x281


@pytest.mark.parametrize("overflow", [0, 240])
def test_the_sync_counter_is_written_while_the_cycle_period_is_0(overflow: int) -> None:
    """CiA 301 lets 0x1019 change only while 0x1006 is 0 (the emulated drive aborts
    0x08000022 otherwise, as CANopenNode does; the EDS's 0x1006 is 1000 µs): bring-up clears
    0x1006 around it and restores it."""
    with drives_on_a_bus() as (_, bus):
        infos = bring_up(bus, replace(DRIVES, sync_counter_overflow=overflow))
        assert [i.limits.sync_counter_overflow for i in infos] == [overflow] * 2
        assert [sdo_read(bus, n, 0x1019) for n in NODES] == [overflow] * 2
        assert [sdo_read(bus, n, 0x1006) for n in NODES] == [1000] * 2


def test_an_event_timer_another_tool_stored_is_written_back() -> None:
    """TPDO2 stored with a 1 ms event timer (a status frame every millisecond, beyond the
    bus-load budget): bring-up writes the EDS's 0 back (it did not look at it)."""
    with drives_on_a_bus(specs_with(stored=((0x1801, 5, 1),))) as (_, bus):
        assert sdo_read(bus, R_NODE, 0x1801, 5) == 1
        infos = bring_up(bus)
        assert [sdo_read(bus, n, 0x1801, 5) for n in NODES] == [0, 0]
        assert [[(p.name, p.mapped == pdo_of(i, "TPDO2").mapped, p.timers)
                 for p in i.rewritten] for i in infos] == [
                     [("TPDO2", True, (("event timer", 1),))]] * 2
    printed = text(report(infos[0], drive_parameters(Joint.R, DRIVES, MOTORS),
                          "dc_servo_drive.eds", "cia402"))  # rakectl drives
    assert "    TPDO2  COB-ID 0x281, transmission type 255, event timer 1, mapped [" in printed


def pdo_of(info: DriveInfo, name: str) -> PdoReading:
    return next(p for p in info.pdos if p.name == name)


def sdo_answer_to(index: int) -> tuple[int, bytes]:
    """The r drive's answer to an expedited read of ``index``:0 (CAN-ID, its first bytes)."""
    return 0x580 + R_NODE, b"\x4b" + index.to_bytes(2, "little") + b"\0"


class RestartsDuringBringUp(VirtualBus):
    """The drives' bus edge, where the r drive restarts (an NMT reset node from another
    node, as a brown-out would) right after it sends the ``nth`` frame that starts with
    ``after`` (CAN-ID, first bytes), and its boot-up is lost (``boot_up_lost``) or heard."""

    after, nth, boot_up_lost = sdo_answer_to(0x6041), 1, True

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        self._other_node = VirtualBus(channel)
        self._answers, self.restarted = 0, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if (msg.arbitration_id == 0x700 + R_NODE and bytes(msg.data) == b"\0"
                and self.restarted and self.boot_up_lost):
            return
        super().send(msg, timeout)
        can_id, start = self.after
        if msg.arbitration_id == can_id and bytes(msg.data).startswith(start):
            self._answers += 1
            if self._answers == self.nth:
                self.restarted = True
                self._other_node.send(can.Message(arbitration_id=0, data=bytes((0x81, R_NODE)),
                                                  is_extended_id=False))

    def shutdown(self) -> None:
        self._other_node.shutdown()
        super().shutdown()


RESTARTED_TEXT = ("the drive restarted during bring-up (its boot-up lost) and holds its "
                  "power-on values; bring-up again (restart the service)")


STATUSWORD_READ = sdo_answer_to(0x6041)
OPERATIONAL_HEARTBEAT = (0x700 + R_NODE, bytes((NmtState.OPERATIONAL,)))


@pytest.mark.parametrize(("after", "boot_up_lost", "expected"), [
    (STATUSWORD_READ, True, "r drive (node 1): before NMT start, 0x2003 watchdog timeout "
     f"reads 20 ms, 3 ms was written and read back: {RESTARTED_TEXT}"),
    (OPERATIONAL_HEARTBEAT, True, "r drive (node 1): after NMT start, 0x2003 watchdog "
     f"timeout reads 20 ms, 3 ms was written and read back: {RESTARTED_TEXT}"),
    (STATUSWORD_READ, False, "r drive (node 1): 1 boot-up(s) heard after its "
     "configuration: the drive restarted during bring-up and holds its power-on values; "
     "bring-up again (restart the service)")])
def test_a_drive_that_restarts_during_bring_up_is_refused(
        monkeypatch: pytest.MonkeyPatch, after: tuple[int, bytes], boot_up_lost: bool,
        expected: str) -> None:
    """A drive that restarted after its configuration holds its power-on values (its own
    watchdog time, its power-on heartbeat times, its stored PDOs): it was started with them
    as if configured. Restarted once its statusword was read (the old fault's check) or
    once it said OPERATIONAL after NMT start, its boot-up lost or heard: a boot-up heard,
    or the values read again before NMT start and once it says OPERATIONAL, refuse it, and
    both drives are left PRE-OPERATIONAL, taking no PDO."""
    monkeypatch.setattr(RestartsDuringBringUp, "after", after)
    monkeypatch.setattr(RestartsDuringBringUp, "boot_up_lost", boot_up_lost)
    with drives_on_a_bus(emulator_bus_class=RestartsDuringBringUp) as (emulator, bus):
        with pytest.raises(DriveFault) as raised:
            run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
        assert emulator.bus.restarted
        deadline_s = time.monotonic() + ANSWER_TIMEOUT_S
        while (time.monotonic() < deadline_s
               and any(n.nmt is not NmtState.PRE_OPERATIONAL for n in emulator.nodes)):
            time.sleep(0.01)
        assert [n.nmt for n in emulator.nodes] == [NmtState.PRE_OPERATIONAL] * 2
    assert str(raised.value) == expected


class SlowBootUp(VirtualBus):
    """The drives' bus edge, where the r drive's boot-up after the first NMT reset
    communication bring-up sends comes ``delay_s`` late (a slow reset, a drive still
    finishing its power-on): after bring-up has sent the reset again."""

    delay_s = 0.4

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        self.boot_ups, self._timers = 0, []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0x700 + R_NODE and bytes(msg.data) == b"\0":
            self.boot_ups += 1
            if self.boot_ups == 2:  # the first after power-on's: the answer to the reset
                timer = threading.Timer(self.delay_s, super().send, (msg, timeout))
                self._timers.append(timer)
                timer.start()
                return
        super().send(msg, timeout)

    def shutdown(self) -> None:
        for timer in self._timers:
            timer.join()
        super().shutdown()


def test_a_late_boot_up_is_configured_again_not_taken_for_a_restart() -> None:
    """The boot-up answering the first reset comes after bring-up sent the reset again (each
    attempt waits boot_timeout_s / 3, 0.33 s): the second reset's boot-up followed, and was
    refused as a restart of a correct drive. A boot-up during the configuration now starts
    it again from the reset."""
    with drives_on_a_bus(emulator_bus_class=SlowBootUp) as (emulator, bus):
        infos = run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
        assert emulator.bus.boot_ups >= 3  # power-on, the late one, the reset's again
    assert infos[0].limits.watchdog_timeout_ms == DRIVES.watchdog_timeout_ms


class RestartsBeforeARequest(VirtualBus):
    """The drives' bus edge, where the r drive restarts (NMT reset communication that it
    alone sees, as a brown-out would) just before it takes the ``nth`` SDO request that
    starts with ``request``: between a write and its reading back."""

    request, nth = b"", 1

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        self.seen = 0

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, filtered = super()._recv_internal(timeout)
        if (msg is not None and msg.arbitration_id == 0x600 + R_NODE
                and bytes(msg.data).startswith(self.request)):
            self.seen += 1
            if self.seen == self.nth:  # the reset first, the request after it
                self.queue.put_nowait(msg)  # type: ignore[attr-defined]
                return can.Message(arbitration_id=0, data=bytes((0x82, R_NODE)),
                                   is_extended_id=False), filtered
        return msg, filtered


@pytest.mark.parametrize(("request_", "nth"), [
    (b"\x40\x17\x10\x00", 1),  # reading back the producer heartbeat just written
    (b"\x40\x01\x18\x05", 2)],  # reading back TPDO2's event timer just written back
    ids=["heartbeat-read-back", "event-timer-read-back"])
def test_a_restart_between_a_write_and_its_reading_configures_again(
        monkeypatch: pytest.MonkeyPatch, request_: bytes, nth: int) -> None:
    """The r drive stores values another tool saved (no heartbeat, a 1 ms TPDO2 event
    timer) and restarts, its boot-up heard, between a write and its reading back: the
    reading found the stored value and refused the drive ("read-back mismatch", "the
    drive kept it when the EDS's mapping was written"), though it had only restarted. A
    boot-up heard with the failure configures it again from its reset."""
    monkeypatch.setattr(RestartsBeforeARequest, "request", request_)
    monkeypatch.setattr(RestartsBeforeARequest, "nth", nth)
    with drives_on_a_bus(specs_with(stored=((0x1017, 0, 0), (0x1801, 5, 1))),
                         emulator_bus_class=RestartsBeforeARequest) as (emulator, bus):
        run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
        assert emulator.bus.seen >= nth
        assert sdo_read(bus, R_NODE, 0x1801, 5) == 0
        assert sdo_read(bus, R_NODE, 0x1017) == DRIVES.heartbeat_period_ms


def test_a_restart_after_nmt_start_is_found_in_the_pdos(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The r drive stores the configured limits and heartbeats (nothing there differs after
    a restart) and a TPDO2 event timer of 1 ms (a status frame every millisecond, beyond
    the bus-load budget). It restarts, its boot-up lost, once it has said OPERATIONAL. Its
    limits read again match; its PDOs are read again after NMT start too: refused, naming
    the timer."""
    r, theta = drive_specs(EmulatorConfig())
    stored = (*((p.index, p.subindex, p.value) for p in drive_parameters(Joint.R, DRIVES, MOTORS)
                if p.index >= 0x1010 and p.index != 0x1019), (0x1801, 5, 1))
    monkeypatch.setattr(RestartsDuringBringUp, "after", OPERATIONAL_HEARTBEAT)
    with drives_on_a_bus((replace(r, stored=stored), theta),
                         emulator_bus_class=RestartsDuringBringUp) as (emulator, bus), \
            pytest.raises(DriveFault) as raised:
        run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
    assert emulator.bus.restarted
    assert str(raised.value) == (
        "r drive (node 1): after NMT start, 0x1801:5 TPDO2 event timer is 0x1, "
        f"dc_servo_drive.eds declares 0x0: {RESTARTED_TEXT}")


def test_a_roboteq_class_drive_that_restarts_with_its_own_values_is_refused(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A Roboteq-class drive whose stored limits are the configured ones, restarted after
    bring-up switched its power stage off (emergency shutdown 0x200C) and read its flags,
    its boot-up lost: no value read again differs, but the restart cleared the emergency
    shutdown, and NMT start let it drive while bring-up reported it off. Its flags are read
    again once it says OPERATIONAL."""
    monkeypatch.setattr(RestartsDuringBringUp, "after", sdo_answer_to(0x2111))
    config = EmulatorConfig()
    config = replace(config, drives=replace(config.drives, profile=DriveProfile.ROBOTEQ))
    drives = replace(DRIVES, profile=DriveProfile.ROBOTEQ)
    r, theta = drive_specs(config)
    stored = tuple((p.index, p.subindex, p.value)
                   for p in drive_parameters(Joint.R, drives, MOTORS) if p.index >= 0x2000)
    with drives_on_a_bus((replace(r, stored=stored), theta), config=config,
                         emulator_bus_class=RestartsDuringBringUp) as (emulator, bus), \
            pytest.raises(DriveFault) as raised:
        run_bring_up(bus, drives, MOTORS, BOOT_TIMEOUT_S)
    assert emulator.bus.restarted
    assert str(raised.value).startswith("r drive (node 1): after NMT start, it reads as ")
    assert str(raised.value).endswith(f", SWITCH_ON_DISABLED before: {RESTARTED_TEXT}")


@pytest.mark.parametrize(("index", "subindex", "value", "named"), [
    (0x1A00, 1, 0x60410010, "0x1A00:1 TPDO1 mapped object 1 is 0x60410010, "
     "geared_motor_drive.eds declares 0x60640020"),
    (0x1802, 1, 0x382, "0x1802:1 TPDO3 COB-ID is 0x382, valid again")])
def test_pdos_that_change_before_nmt_start_are_refused(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork, index: int,
        subindex: int, value: int, named: str) -> None:
    """The θ drive's stored PDOs come back before NMT start, as a drive that restarted
    unseen holds them (its limits kept, so that only the PDOs' reading finds it): a mapping
    another tool stored, or a TPDO that was made not valid. Read again just before NMT
    start."""
    theta = fake_drives[1]
    _add_pdo(theta, 0x1802, 0x382)

    def restore_stored(can_id: int, data: bytearray, timestamp: float) -> None:
        if data[0] == 0x40 and bytes(data[1:4]) == b"\x41\x60\0":  # its statusword read
            theta.node.set_data(index, subindex, value.to_bytes(4, "little"))

    network.subscribe(0x600 + THETA_NODE, restore_stored)
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(make_bring_up(network), fake_drives)
    assert str(raised.value) == (
        f"θ drive (node 2): before NMT start, {named}: the drive restarted during bring-up "
        "(its boot-up lost) and holds its power-on values; bring-up again (restart the "
        "service)")


class ShortIdentityAnswers(VirtualBus):
    """The drives' bus edge, answering 0x1018:2 (UNSIGNED32) in 2 bytes, as some drives
    answer an object they keep narrower."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if 0x581 <= msg.arbitration_id <= 0x5FF and bytes(msg.data[:4]) == b"\x43\x18\x10\x02":
            msg = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False,
                              data=b"\x4b\x18\x10\x02" + bytes(msg.data[4:6]) + b"\0\0")
        super().send(msg, timeout)


def test_a_short_sdo_answer_is_one_line_naming_both_sizes() -> None:
    """canopen raised ObjectDictionaryError, which escaped bring-up as a traceback."""
    with drives_on_a_bus(emulator_bus_class=ShortIdentityAnswers) as (_, bus), pytest.raises(
            DriveFault) as raised:
        bring_up(bus)
    assert str(raised.value) == ("r drive (node 1): reading 0x1018:2 identity: the drive "
                                 "answered 2 byte(s), the EDS's UNSIGNED32 takes 4")
    assert isinstance(raised.value.__cause__, canopen.objectdictionary.ObjectDictionaryError)


# =========================================================================== tier 2: LocalNode


@pytest.fixture
def network() -> LoopbackNetwork:
    return LoopbackNetwork()


@pytest.fixture
def fake_drives(network: LoopbackNetwork) -> tuple[FakeDrive, FakeDrive]:
    return (FakeDrive(network, Joint.R, R_NODE), FakeDrive(network, Joint.THETA, THETA_NODE))


class TruncatingNetwork(LoopbackNetwork):
    """Hands the r drive's SDO answers on cut to ``length`` bytes."""

    def __init__(self, length: int) -> None:
        super().__init__()
        self.length = length

    def notify(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if can_id == 0x580 + R_NODE:
            data = data[:self.length]
        super().notify(can_id, data, timestamp)


def test_an_sdo_frame_too_short_to_decode_is_one_line() -> None:
    """canopen unpacked it with struct and raised struct.error out of bring-up."""
    network = TruncatingNetwork(3)
    drives = (FakeDrive(network, Joint.R, R_NODE), FakeDrive(network, Joint.THETA, THETA_NODE))
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(make_bring_up(network), drives)
    assert str(raised.value).startswith("r drive (node 1): SDO answer reading 0x1018:1 "
                                        "identity shorter than CiA 301's 8 bytes: ")


def _without(drive: FakeDrive, index: int) -> None:
    del drive.node.object_dictionary[index]


@pytest.mark.parametrize("absent", [0x1019, 0x1006])
def test_a_drive_without_0x1019_or_0x1006_takes_sync_without_a_counter(
        network: LoopbackNetwork, absent: int) -> None:
    """0x1019 is optional (such a drive takes SYNC without data), so is 0x1006: asked for
    0, bring-up accepts a drive without either."""
    drives = (FakeDrive(network, Joint.R, R_NODE), FakeDrive(network, Joint.THETA, THETA_NODE))
    _without(drives[0], absent)
    infos = _announce_and_run(make_bring_up(network, replace(FAST, sync_counter_overflow=0)),
                              drives)
    assert [i.limits.sync_counter_overflow for i in infos] == [0, 0]


def test_a_drive_without_0x1019_is_refused_a_sync_counter(network: LoopbackNetwork) -> None:
    drives = (FakeDrive(network, Joint.R, R_NODE), FakeDrive(network, Joint.THETA, THETA_NODE))
    _without(drives[0], 0x1019)
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(make_bring_up(network), drives)
    assert str(raised.value) == (
        "r drive (node 1): no 0x1019 SYNC counter overflow (SDO abort 0x06020000 writing "
        "240): the drive takes SYNC without a counter only; set "
        "drives.sync_counter_overflow: 0")


def test_an_inhibit_time_the_eds_declares_read_only_is_refused_naming_it(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork) -> None:
    """A TPDO2 that may not go out within 100 ms of the last (a status change seen that
    late): the EDS declares it 0 and read-only, so bring-up refuses the drive (it did not
    look at it)."""
    fake_drives[0].node.set_data(0x1801, 3, (1000).to_bytes(2, "little"))
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(make_bring_up(network), fake_drives)
    assert str(raised.value) == (
        "r drive (node 1): 0x1801:3 TPDO2 inhibit time is 1000, dc_servo_drive.eds declares 0 "
        "and read-only: the hot path and the bus-load budget take the EDS's PDOs")


def _add_pdo(drive: FakeDrive, index: int, cob_id: int, access: str = "rw") -> None:
    """A PDO communication parameter beyond the EDS's (0x1401 RPDO2, 0x1802 TPDO3)."""
    kind = "RPDO" if index < 0x1800 else "TPDO"
    record = ODRecord(f"{kind} communication parameter", index)
    for subindex, name, data_type, default, sub_access in (
            (0, "Highest sub-index supported", datatypes.UNSIGNED8, 2, "ro"),
            (1, f"COB-ID used by {kind}", datatypes.UNSIGNED32, cob_id, access),
            (2, "Transmission type", datatypes.UNSIGNED8, 255, "rw")):
        variable = ODVariable(name, index, subindex)
        variable.data_type, variable.access_type, variable.default = (data_type, sub_access,
                                                                      default)
        record.add_member(variable)
    drive.node.object_dictionary.add_object(record)


def _cob_id(drive: FakeDrive, index: int) -> int:
    return int.from_bytes(drive.node.get_data(index, 1), "little")


def test_pdos_beyond_the_eds_s_are_made_not_valid(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork) -> None:
    """A drive with a third TPDO and a second RPDO, valid (many CiA 402 drives ship so): at
    1 kHz the TPDO would break the bus-load budget, and the RPDO would take frames no clamp
    judged. Both are made not valid (bit 31; bit 30 as held), the rest of the drive as
    before, and ``rakectl drives`` names them. They were refused before."""
    _add_pdo(fake_drives[1], 0x1802, NO_RTR | 0x380 + THETA_NODE)
    _add_pdo(fake_drives[1], 0x1401, 0x300 + THETA_NODE)
    _add_pdo(fake_drives[0], 0x1802, 1 << 31 | 0x381)  # already not valid: left alone
    infos = _announce_and_run(make_bring_up(network), fake_drives)
    assert _cob_id(fake_drives[1], 0x1802) == 1 << 31 | NO_RTR | 0x382
    assert _cob_id(fake_drives[1], 0x1401) == 1 << 31 | 0x302
    assert infos[1].extra == (ExtraPdo("RPDO2", 0x1401, 0x302),
                                 ExtraPdo("TPDO3", 0x1802, NO_RTR | 0x382))
    assert infos[0].extra == ()
    assert [p.name for p in infos[1].pdos] == ["RPDO1", "TPDO1", "TPDO2"]
    printed = text(report(infos[1], drive_parameters(Joint.THETA, FAST, MOTORS),
                          "geared_motor_drive.eds", "cia402"))
    assert printed.endswith("  beyond the EDS's and valid, made not valid (not stored: at "
                            "every bring-up):\n    RPDO2  COB-ID 0x302\n"
                            "    TPDO3  COB-ID 0x40000382")


def test_a_tpdo_beyond_the_eds_s_that_stays_valid_is_refused(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork) -> None:
    """A drive whose extra TPDO's COB-ID is read-only: refused, naming the PDO and what to
    do, and nothing started."""
    _add_pdo(fake_drives[1], 0x1802, 0x380 + THETA_NODE, access="ro")
    refused = make_bring_up(network)
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(refused, fake_drives)
    refused.close()
    assert str(raised.value) == (
        "θ drive (node 2): TPDO3 (0x1802:1 COB-ID 0x382) is valid and geared_motor_drive.eds "
        "has no such TPDO: sent beside the EDS's, it would break the bus-load budget "
        "(docs/can-bus.md); the drive keeps it valid (SDO abort 0x06010002 writing "
        "0x80000382: Attempt to write a read only object): make it not valid (bit 31) with "
        "the drive's own tool and store that")
    assert _cob_id(fake_drives[1], 0x1802) == 0x382


def _add_mapping(drive: FakeDrive, index: int, entries: tuple[int, ...]) -> None:
    """A PDO mapping parameter beyond the EDS's (0x1601 for RPDO2)."""
    record = ODRecord("RPDO mapping parameter", index)
    for subindex, data_type, value in ((0, datatypes.UNSIGNED8, len(entries)),
                                       *((k, datatypes.UNSIGNED32, entry)
                                         for k, entry in enumerate(entries, start=1))):
        variable = ODVariable(f"sub {subindex}", index, subindex)
        variable.data_type, variable.access_type, variable.default = data_type, "ro", value
        record.add_member(variable)
    drive.node.object_dictionary.add_object(record)


KEPT = "SDO abort 0x06010002 writing 0x80000302: Attempt to write a read only object"
WHERE = ("θ drive (node 2): RPDO2 (0x1401:1 COB-ID 0x302) is valid and geared_motor_drive.eds "
         f"has no such RPDO; the drive keeps it valid ({KEPT})")


@pytest.mark.parametrize(("mapping", "refused"), [
    ((0x20050120,), ""),  # a user variable of the drive's: nothing it acts on
    ((0x20050120, 0x20000020), f"{WHERE}, and it maps 0x2000:0, which the drive acts on: a "
     "frame on 0x302 would command it past the clamp; make the RPDO not valid (bit 31) with "
     "the drive's own tool and store that"),
    ((0x20030010,), f"{WHERE}, and it maps 0x2003:0, which the drive acts on: a frame on "
     "0x302 would command it past the clamp; make the RPDO not valid (bit 31) with the "
     "drive's own tool and store that"),  # its command watchdog, which bring-up writes
    (None, f"{WHERE}, and its mapping 0x1601 cannot be read: make it not valid (bit 31) "
     "with the drive's own tool and store that")])
def test_an_rpdo_beyond_the_eds_s_that_stays_valid_is_named_or_refused(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork,
        mapping: tuple[int, ...] | None, refused: str) -> None:
    """A drive whose extra RPDO's COB-ID is fixed (read-only): no tool but the drive's own
    changes it. One that maps nothing the drive acts on takes only frames on its COB-ID:
    the drive is brought up and ``rakectl drives`` names the RPDO and its CAN-ID. One that
    maps the voltage or the controlword would let any node command the drive past the
    clamp, and one whose mapping cannot be read cannot be judged: refused."""
    _add_pdo(fake_drives[1], 0x1401, 0x300 + THETA_NODE, access="ro")
    if mapping is not None:
        _add_mapping(fake_drives[1], 0x1601, mapping)
    bring_up = make_bring_up(network)
    if refused:
        with pytest.raises(DriveFault) as raised:
            _announce_and_run(bring_up, fake_drives)
        bring_up.close()
        assert str(raised.value) == refused
        return
    infos = _announce_and_run(bring_up, fake_drives)
    assert infos[1].extra == (ExtraPdo("RPDO2", 0x1401, 0x302, KEPT),)
    printed = text(report(infos[1], drive_parameters(Joint.THETA, FAST, MOTORS),
                          "geared_motor_drive.eds", "cia402"))
    assert printed.endswith(f"    RPDO2  COB-ID 0x302: kept valid by the drive ({KEPT}); it "
                            "takes any frame sent on 0x302")


def test_a_fault_reset_that_does_not_clear_names_the_timeout(
        fake_drives: tuple[FakeDrive, FakeDrive], network: LoopbackNetwork,
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(profiles, "FAULT_RESET_TIMEOUT_S", 0.05)
    fault = cia402.encode_statusword(DriveState.FAULT)
    fake_drives[0].node.add_read_callback(  # type: ignore[no-untyped-call]
        lambda index, subindex, od: fault if index == 0x6041 else None)
    with pytest.raises(DriveFault) as raised:
        _announce_and_run(make_bring_up(network), fake_drives)
    assert str(raised.value) == ("r drive (node 1): in FAULT (0x603F = 0x0000) since before "
                                 "bring-up, and a fault reset does not clear it within 0.05 s")


class SlowRoboteqDrive:
    """A Roboteq-class LocalNode whose fault flags clear only some reads after a release
    shutdown (its own cycle), as a drive's do, not in the SDO answer's moment."""

    def __init__(self, network: canopen.Network, node_id: int, reads_to_clear: int) -> None:
        self.node = canopen.LocalNode(node_id, load_drive_od("roboteq_class_drive.eds",
                                                             node_id))
        self.node.associate_network(network)
        self.network, self.node_id = network, node_id
        self.flags = roboteq.FAULT_COMMUNICATION  # the previous run's heartbeat lost
        self._reads, self.reads_to_clear = reads_to_clear, -1  # -1: no release yet
        self.node.add_read_callback(self._read)  # type: ignore[no-untyped-call]
        self.node.add_write_callback(self._write)  # type: ignore[no-untyped-call]
        network.subscribe(codec.NMT_COB_ID, self._on_nmt)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if decode_nmt(data) == (NmtCommand.RESET_COMMUNICATION, self.node_id):
            self.announce(NmtState.BOOT_UP)

    def announce(self, state: NmtState) -> None:
        self.network.send_message(0x700 + self.node_id, bytes((state,)))

    def _read(self, index: int, subindex: int, od: Any) -> int | None:
        if index == 0x2112:
            if self.reads_to_clear == 0:
                self.flags &= roboteq.FAULT_EMERGENCY_STOP
            self.reads_to_clear -= 1
            return self.flags
        return None

    def _write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x200D:
            self.reads_to_clear = self._reads
        elif index == 0x200C:
            self.flags |= roboteq.FAULT_EMERGENCY_STOP


def test_a_roboteq_class_release_is_awaited_in_the_drives_cycle(
        network: LoopbackNetwork) -> None:
    """Release shutdown 0x200D of a drive whose communication fault flag clears a few
    reads later: its flags are read until clear (they were read once, at once: refused)."""
    drives = replace(FAST, profile=DriveProfile.ROBOTEQ)
    slow = [SlowRoboteqDrive(network, node_id, 3) for node_id in NODES]
    bring_up = BringUp(network, drives, MOTORS, boot_timeout_s=0.05)
    for drive in slow:
        drive.announce(NmtState.PRE_OPERATIONAL)  # a heartbeat: it is there
    infos = bring_up.run(start=False)
    bring_up.close()
    assert [i.cleared_fault for i in infos] == [roboteq.FAULT_COMMUNICATION] * 2
    assert [i.state for i in infos] == [DriveState.SWITCH_ON_DISABLED] * 2
    assert all(drive.flags == roboteq.FAULT_EMERGENCY_STOP for drive in slow)
