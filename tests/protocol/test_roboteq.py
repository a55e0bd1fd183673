"""The Roboteq-class drive's pure codecs (rakectl.protocol.roboteq) against hand-made
frames and against the EDS they must agree with (roboteq_class_drive.eds)."""

from __future__ import annotations

import struct

import canopen
import pytest

from rakectl.errors import FrameError, NonFiniteError
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.files import EDS_DIR


def test_the_eds_maps_the_layouts_the_codecs_pack() -> None:
    od = canopen.import_od(str(EDS_DIR / "roboteq_class_drive.eds"), 1)

    def mapping(index: int) -> list[tuple[int, int, int]]:
        record = od[index]
        return [((record[k].default >> 16) & 0xFFFF, (record[k].default >> 8) & 0xFF,
                 record[k].default & 0xFF) for k in range(1, record[0].default + 1)]

    assert mapping(0x1600) == [(0x2000, 1, 32)]
    assert mapping(0x1A00) == [(0x2104, 1, 32), (0x2103, 1, 16), (0x2100, 1, 16)]
    assert mapping(0x1A01) == [(0x2112, 0, 16), (0x2111, 0, 16)]
    assert od[0x2000][1].min == -roboteq.PER_MILLE and od[0x2000][1].max == roboteq.PER_MILLE
    assert sum(bits for *_, bits in mapping(0x1A01)) == 8 * roboteq.TPDO2_SIZE
    # TPDO1 has the project's own drive's layout (i32, i16, i16): one decoder for both
    assert struct.calcsize("<ihh") == sum(bits for *_, bits in mapping(0x1A00)) // 8


def test_the_power_requests_are_expedited_one_byte_downloads() -> None:
    assert bytes([0x2F, 0x0C, 0x20, 0x00, 0x01, 0, 0, 0]) == roboteq.EMERGENCY_SHUTDOWN
    assert bytes([0x2F, 0x0D, 0x20, 0x00, 0x01, 0, 0, 0]) == roboteq.RELEASE_SHUTDOWN


@pytest.mark.parametrize(("faults", "status", "state"), [
    (0, 0x0001, DriveState.OPERATION_ENABLED),
    (roboteq.FAULT_EMERGENCY_STOP, 0x0009, DriveState.SWITCH_ON_DISABLED),
    (roboteq.FAULT_SHORT_CIRCUIT, 0x0009, DriveState.FAULT),
    (roboteq.FAULT_SENSOR | roboteq.FAULT_EMERGENCY_STOP, 0x0009, DriveState.FAULT),
    (0, 0x0001 | roboteq.STATUS_WATCHDOG_EXPIRED, DriveState.FAULT),
    (0, 0x0001 | roboteq.STATUS_AMPS_LIMIT, DriveState.OPERATION_ENABLED),
])
def test_flags_read_as_the_cia402_state_that_behaves_the_same(
        faults: int, status: int, state: DriveState) -> None:
    data = struct.pack("<HH", faults, status)
    assert roboteq.state_of(roboteq.flags_image(*roboteq.decode_flags(data))) is state


def test_bad_frames_and_numbers_raise_one_clear_error() -> None:
    with pytest.raises(FrameError, match="TPDO2 must be 4 bytes, got 3"):
        roboteq.decode_flags(b"\x00\x00\x00")
    with pytest.raises(FrameError, match="RPDO1 must be 4 bytes, got 2"):
        roboteq.decode_command(b"\x00\x00")
    with pytest.raises(NonFiniteError):
        roboteq.volts_to_per_mille(float("inf"), 24.0)
    assert roboteq.volts_to_per_mille(1e307, 24.0) == 1000  # saturated before rounding
    assert roboteq.volts_to_per_mille(-1e307, 24.0) == -1000


def test_a_command_round_trips_through_its_frame() -> None:
    buffer = bytearray(4)
    roboteq.pack_command_into(buffer, -737)
    assert roboteq.decode_command(buffer) == -737
    assert roboteq.per_mille_to_mv(-737, 24000) == -17688
