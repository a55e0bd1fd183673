"""Tier 2: one emulated drive's PDOs remapped over SDO (drivers.pdo_map), by scripted
exchange with an injected clock (the harness of tests/drivers/test_node.py): what goes out
and what is taken after a remap, a PDO made not valid, and the resets."""

from __future__ import annotations

from drivers.pdo_map import PdoAbort
from drivers.stats import BadInput
from rakectl.protocol import codec
from rakectl.protocol.cia402 import DriveCommand, DriveState, decode_statusword
from rakectl.protocol.nmt import EmcyCode, NmtCommand
from tests.drivers.test_node import (
    EMCY,
    NODE_ID,
    RPDO1,
    SDO_RX,
    TPDO1,
    TPDO2,
    Bench,
    emcys,
    make_node,
    sdo_download,
    sdo_reply,
    sdo_upload,
)

NOT_VALID = 1 << 31


def _write(bench: Bench, index: int, subindex: int, value: int, size: int = 4) -> None:
    reply = sdo_reply(bench.rx(SDO_RX, sdo_download(index, subindex, value, size)))
    assert reply == ("ok", 0), f"0x{index:04X}:{subindex} = 0x{value:X}: {reply}"


def _read(bench: Bench, index: int, subindex: int = 0) -> int:
    kind, value = sdo_reply(bench.rx(SDO_RX, sdo_upload(index, subindex)))
    assert kind == "value"
    return value


def _remap(bench: Bench, comm: int, mapping: int, cob_id: int, entries: list[int]) -> None:
    """CiA 301's order: not valid, sub 0 = 0, the entries, sub 0 = n, valid."""
    _write(bench, comm, 1, cob_id | NOT_VALID)
    _write(bench, mapping, 0, 0, 1)
    for k, entry in enumerate(entries, start=1):
        _write(bench, mapping, k, entry)
    _write(bench, mapping, 0, len(entries), 1)
    _write(bench, comm, 1, cob_id)


def _frames(frames: list[tuple[int, bytes]], can_id: int) -> list[bytes]:
    return [data for i, data in frames if i == can_id]


def test_a_tpdo2_remapped_goes_out_in_its_layout_and_reset_brings_the_eds_back() -> None:
    """TPDO2 remapped in PRE-OPERATIONAL to the statusword alone: entering OPERATIONAL
    sends those 2 bytes; after NMT reset communication (what the controller's bring-up
    does first) the EDS's 3 bytes again, in the EDS's layout."""
    bench = Bench(make_node())
    _remap(bench, 0x1801, 0x1A01, 0x280 + NODE_ID, [0x60410010])
    started = _frames(bench.nmt(NmtCommand.START), TPDO2)
    assert [len(f) for f in started] == [2]
    assert decode_statusword(int.from_bytes(started[0], "little")) is (
        DriveState.SWITCH_ON_DISABLED)
    bench.nmt(NmtCommand.RESET_COMMUNICATION)
    assert _read(bench, 0x1A01) == 2
    started = _frames(bench.nmt(NmtCommand.START), TPDO2)
    assert [len(f) for f in started] == [3]
    assert decode_statusword(codec.decode_tpdo2(started[0])[0]) is DriveState.SWITCH_ON_DISABLED


def test_a_pdo_not_valid_is_not_sent_and_a_reset_makes_it_valid_again() -> None:
    bench = Bench(make_node())
    _write(bench, 0x1800, 1, 0x180 + NODE_ID | NOT_VALID)
    _write(bench, 0x1801, 1, 0x280 + NODE_ID | NOT_VALID)
    assert _frames(bench.nmt(NmtCommand.START), TPDO2) == []
    assert _frames(bench.sync(), TPDO1) == []
    bench.nmt(NmtCommand.RESET_COMMUNICATION)
    assert len(_frames(bench.nmt(NmtCommand.START), TPDO2)) == 1
    assert len(_frames(bench.sync(), TPDO1)) == 1


def test_a_tpdo2_made_valid_again_sends_the_status_it_missed() -> None:
    bench = Bench(make_node())
    bench.nmt(NmtCommand.START)
    _write(bench, 0x1801, 1, 0x280 + NODE_ID | NOT_VALID)
    bench.controlword_by_sdo(DriveCommand.SHUTDOWN.value)  # → READY_TO_SWITCH_ON, unsent
    assert bench.node.state is DriveState.READY_TO_SWITCH_ON
    assert _frames(bench.sync(), TPDO2) == []
    frames = bench.rx(SDO_RX, sdo_download(0x1801, 1, 0x280 + NODE_ID, 4))  # valid again
    assert sdo_reply(frames) == ("ok", 0)
    sent = _frames(frames, TPDO2)  # at once, with the SDO's answer
    assert [decode_statusword(codec.decode_tpdo2(f)[0]) for f in sent] == [
        DriveState.READY_TO_SWITCH_ON]


def test_an_rpdo1_not_valid_is_not_taken_and_the_watchdog_stops_the_drive() -> None:
    bench = Bench(make_node())
    bench.enable()
    bench.cycle(3000)
    bench.sync()
    assert bench.node.output_voltage_v == 3.0
    _write(bench, 0x1400, 1, 0x200 + NODE_ID | NOT_VALID)
    ignored = bench.node.stats.rpdos_ignored
    faults: list[int] = []
    for _ in range(25):  # past the power-on watchdog (20 ms)
        faults += emcys(bench.cycle(3000))
    assert bench.node.stats.rpdos_ignored == ignored + 25
    assert EmcyCode.COMMAND_WATCHDOG_TIMEOUT in faults
    assert bench.node.output_voltage_v == 0.0 and bench.node.state is DriveState.FAULT


def test_an_rpdo1_remapped_drops_the_voltage_it_carried() -> None:
    """SWITCHED_ON with 5 V latched from the EDS's RPDO1, then RPDO1 remapped to the
    controlword alone: the enabling frame carries no voltage, so none is applied."""
    bench = Bench(make_node())
    bench.nmt(NmtCommand.START)
    for command in (DriveCommand.SHUTDOWN, DriveCommand.SWITCH_ON):
        bench.cycle(5000, command)
    bench.sync()
    assert bench.node.state is DriveState.SWITCHED_ON
    _remap(bench, 0x1400, 0x1600, 0x200 + NODE_ID, [0x60400010])
    bench.rx(RPDO1, DriveCommand.ENABLE_OPERATION.value.to_bytes(2, "little"))
    bench.sync()
    assert bench.node.state is DriveState.OPERATION_ENABLED
    assert bench.node.output_voltage_v == 0.0
    bench.rx(RPDO1, codec.encode_rpdo(1000, DriveCommand.ENABLE_OPERATION.value))
    assert bench.node.stats.bad.counts[BadInput.WRONG_LENGTH] == 1  # 4 bytes for 2: bad input


def test_refused_remaps_change_nothing() -> None:
    bench = Bench(make_node())
    mapping = [_read(bench, 0x1A00, k) for k in range(4)]

    def refused(index: int, subindex: int, value: int, size: int = 4) -> int:
        kind, code = sdo_reply(bench.rx(SDO_RX, sdo_download(index, subindex, value, size)))
        assert kind == "abort"
        return code

    assert refused(0x1A00, 0, 0, 1) == PdoAbort.UNSUPPORTED_ACCESS  # still valid
    assert refused(0x1800, 1, 0x182 | NOT_VALID) == PdoAbort.VALUE_RANGE  # another CAN-ID
    assert refused(0x1800, 1, 0x181 | 1 << 20) == PdoAbort.VALUE_RANGE  # a reserved bit
    assert [_read(bench, 0x1A00, k) for k in range(4)] == mapping
    _write(bench, 0x1800, 1, 0x181 | NOT_VALID | 1 << 30)  # bit 30 (no RTR) is kept
    assert _read(bench, 0x1800, 1) == 0x181 | NOT_VALID | 1 << 30
    _write(bench, 0x1A00, 0, 0, 1)
    assert refused(0x1800, 1, 0x181) == PdoAbort.VALUE_RANGE  # valid over an empty mapping
    assert refused(0x1A00, 1, 0x60410110) == PdoAbort.NO_SUB_INDEX
    assert refused(0x1A00, 1, 0x70000010) == PdoAbort.NO_OBJECT
    assert refused(0x1A00, 1, 0x10080000) == PdoAbort.NOT_MAPPABLE  # the device name
    assert refused(0x1A00, 1, 0x60640010) == PdoAbort.NOT_MAPPABLE  # 32 bits as 16
    assert [_read(bench, 0x1A00, k) for k in range(1, 4)] == mapping[1:]
    for k in (1, 2, 3):
        _write(bench, 0x1A00, k, 0x60640020)
    assert refused(0x1A00, 0, 3, 1) == PdoAbort.TOO_LONG  # 96 bits
    assert _read(bench, 0x1A00) == 0
    bench.nmt(NmtCommand.RESET_NODE)
    assert [_read(bench, 0x1A00, k) for k in range(4)] == mapping
    assert _read(bench, 0x1800, 1) == 0x181
    assert EMCY == 0x80 + NODE_ID
