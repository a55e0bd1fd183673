"""The frame codec: round-trips over the full ranges, length and range errors, units."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rakectl.errors import FrameError, NonFiniteError, RakeError
from rakectl.protocol import codec, nmt
from rakectl.protocol.codec import FunctionCode
from rakectl.protocol.nmt import EmcyCode, ErrorRegister, NmtCommand, NmtState

INT8 = st.integers(-(2**7), 2**7 - 1)
UINT8 = st.integers(0, 2**8 - 1)
INT16 = st.integers(-(2**15), 2**15 - 1)
UINT16 = st.integers(0, 2**16 - 1)
INT32 = st.integers(-(2**31), 2**31 - 1)
SYNC_COUNTER = st.integers(1, codec.SYNC_COUNTER_MAX)

DECODERS = [
    ("RPDO1", codec.decode_rpdo, codec.RPDO1_SIZE),
    ("TPDO1", codec.decode_tpdo1, codec.TPDO1_SIZE),
    ("TPDO2", codec.decode_tpdo2, codec.TPDO2_SIZE),
    ("SYNC", codec.decode_sync, codec.SYNC_SIZE),
    ("heartbeat", nmt.decode_heartbeat, 1),
    ("NMT", nmt.decode_nmt, 2),
    ("EMCY", nmt.decode_emcy, nmt.EMCY_SIZE),
]


# --------------------------------------------------------------------------- purity


def test_hot_path_modules_import_only_pure_pieces() -> None:
    allowed = {"__future__", "enum", "math", "struct", "types", "typing", "collections.abc",
               "rakectl.errors", "rakectl.protocol.cia402"}
    for name in ("codec.py", "cia402.py", "roboteq.py"):
        tree = ast.parse((Path(codec.__file__).parent / name).read_text())
        imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                    for alias in node.names}
        imported |= {node.module or "" for node in ast.walk(tree)
                     if isinstance(node, ast.ImportFrom)}
        assert imported <= allowed, f"{name} imports {imported - allowed}"


def test_frame_error_is_a_rake_error_and_a_value_error() -> None:
    assert issubclass(FrameError, RakeError)
    assert issubclass(FrameError, ValueError)


# --------------------------------------------------------------------------- layouts


def test_frame_sizes_are_the_protocols() -> None:
    assert (codec.TPDO1_SIZE, codec.TPDO2_SIZE, codec.RPDO1_SIZE) == (8, 3, 4)
    assert (codec.SYNC_SIZE, nmt.EMCY_SIZE) == (1, 8)


def test_field_layout_is_little_endian_in_mapping_order() -> None:
    frame = codec.encode_tpdo1(0x01020304, 0x0506, 0x0708)
    assert frame == bytes([4, 3, 2, 1, 6, 5, 8, 7])
    assert codec.encode_rpdo(-2, 0x000F) == bytes([0xFE, 0xFF, 0x0F, 0x00])
    assert codec.encode_tpdo2(0x0237, 0x81) == bytes([0x37, 0x02, 0x81])


# --------------------------------------------------------------------------- round trips


@given(INT16, UINT16)
def test_rpdo_round_trip(voltage_mv: int, controlword: int) -> None:
    frame = codec.encode_rpdo(voltage_mv, controlword)
    assert codec.decode_rpdo(frame) == (voltage_mv, controlword)
    buffer = bytearray(codec.RPDO1_SIZE)
    codec.pack_rpdo_into(buffer, voltage_mv, controlword)
    assert buffer == frame


@given(INT32, INT16, INT16)
def test_tpdo1_round_trip(position_counts: int, velocity_rpm: int, current_ma: int) -> None:
    frame = codec.encode_tpdo1(position_counts, velocity_rpm, current_ma)
    assert codec.decode_tpdo1(frame) == (position_counts, velocity_rpm, current_ma)
    assert codec.decode_tpdo1(bytearray(frame)) == (position_counts, velocity_rpm, current_ma)
    buffer = bytearray(codec.TPDO1_SIZE)
    codec.pack_tpdo1_into(buffer, position_counts, velocity_rpm, current_ma)
    assert buffer == frame


@given(UINT16, UINT8)
def test_tpdo2_round_trip(statusword: int, error_register: int) -> None:
    frame = codec.encode_tpdo2(statusword, error_register)
    assert codec.decode_tpdo2(frame) == (statusword, error_register)
    buffer = bytearray(codec.TPDO2_SIZE)
    codec.pack_tpdo2_into(buffer, statusword, error_register)
    assert buffer == frame


@given(SYNC_COUNTER)
def test_sync_round_trip(counter: int) -> None:
    frame = codec.encode_sync(counter)
    assert codec.decode_sync(frame) == counter
    buffer = bytearray(1)
    codec.pack_sync_into(buffer, counter)
    assert buffer == frame


@pytest.mark.parametrize("state", list(NmtState))
def test_heartbeat_round_trip(state: NmtState) -> None:
    assert nmt.decode_heartbeat(nmt.encode_heartbeat(state)) is state


@given(st.sampled_from(NmtCommand), st.integers(0, 127))
def test_nmt_round_trip(command: NmtCommand, node_id: int) -> None:
    assert nmt.decode_nmt(nmt.encode_nmt(command, node_id)) == (command, node_id)


@given(UINT16, UINT8, st.binary(min_size=5, max_size=5))
def test_emcy_round_trip(code: int, error_register: int, manufacturer_data: bytes) -> None:
    emcy = nmt.decode_emcy(nmt.encode_emcy(code, error_register, manufacturer_data))
    assert emcy == (code, error_register, manufacturer_data)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(("frame", "decode", "size"), DECODERS, ids=[d[0] for d in DECODERS])
def test_wrong_length_raises_frame_error_naming_frame_and_sizes(
    frame: str, decode: object, size: int
) -> None:
    assert callable(decode)
    for length in (0, size - 1, size + 1, 9):
        if length == size:
            continue
        with pytest.raises(FrameError, match=rf"^{frame} must be {size} bytes, got {length}"):
            decode(bytes(range(length)))


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: codec.encode_rpdo(32768, 0), "voltage_mv=32768"),
        (lambda: codec.encode_rpdo(-32769, 0), "voltage_mv=-32769"),
        (lambda: codec.encode_rpdo(0, -1), "controlword=-1"),
        (lambda: codec.encode_rpdo(0, 0x10000), "controlword=65536"),
        (lambda: codec.encode_rpdo(1.5, 0), "voltage_mv=1.5"),  # type: ignore[arg-type]
        (lambda: codec.encode_tpdo1(2**31, 0, 0), "position_counts=2147483648"),
        (lambda: codec.encode_tpdo1(0, -(2**15) - 1, 0), "velocity_rpm=-32769"),
        (lambda: codec.encode_tpdo1(0, 0, 2**15), "current_ma=32768"),
        (lambda: codec.encode_tpdo2(-1, 0), "statusword=-1"),
        (lambda: codec.encode_tpdo2(0, 256), "error_register=256"),
        (lambda: codec.pack_rpdo_into(bytearray(4), 0, 70000), "controlword=70000"),
        (lambda: codec.pack_tpdo1_into(bytearray(8), 0, 40000, 0), "velocity_rpm=40000"),
        (lambda: codec.pack_tpdo2_into(bytearray(3), 0, 300), "error_register=300"),
    ],
)
def test_out_of_range_values_raise_frame_error_naming_the_field(call: object, field: str) -> None:
    assert callable(call)
    with pytest.raises(FrameError, match=field):
        call()


def test_short_buffer_is_named() -> None:
    with pytest.raises(FrameError, match="RPDO1 needs a buffer of 4 bytes, got 2"):
        codec.pack_rpdo_into(bytearray(2), 0, 0)
    with pytest.raises(FrameError, match="TPDO1 needs a buffer of 8 bytes"):
        codec.pack_tpdo1_into(bytearray(7), 0, 0, 0)


@pytest.mark.parametrize("counter", [0, 241, 255, -1])
def test_sync_counter_outside_1_to_240_is_rejected(counter: int) -> None:
    with pytest.raises(FrameError, match="SYNC counter"):
        codec.encode_sync(counter)
    if 0 <= counter <= 255:
        with pytest.raises(FrameError, match="SYNC counter"):
            codec.decode_sync(bytes([counter]))


def test_undefined_heartbeat_and_nmt_values_are_rejected() -> None:
    with pytest.raises(FrameError, match="0x01 is no NMT state"):
        nmt.decode_heartbeat(b"\x01")
    with pytest.raises(FrameError, match="is no NMT state"):
        nmt.encode_heartbeat(3)  # type: ignore[arg-type]
    with pytest.raises(FrameError, match="0x03 is no NMT command"):
        nmt.decode_nmt(b"\x03\x01")
    with pytest.raises(FrameError, match=r"node-ID 0\.\.127"):
        nmt.encode_nmt(NmtCommand.START, 128)


def test_emcy_fields_are_checked() -> None:
    with pytest.raises(FrameError, match="5 bytes, got 4"):
        nmt.encode_emcy(EmcyCode.OVER_CURRENT, 3, bytes(4))
    with pytest.raises(FrameError, match="code=65536"):
        nmt.encode_emcy(0x10000, 0)


# --------------------------------------------------------------------------- SYNC counter


def test_sync_counter_runs_1_to_240_and_wraps_to_1() -> None:
    counter, seen = 1, []
    for _ in range(2 * codec.SYNC_COUNTER_MAX):
        seen.append(counter)
        counter = codec.next_sync_counter(counter)
    assert seen == list(range(1, 241)) * 2
    assert codec.next_sync_counter(240) == 1


@given(SYNC_COUNTER, st.integers(0, codec.SYNC_COUNTER_MAX - 1))
def test_lost_syncs_counts_the_gap_across_the_wrap(previous: int, lost: int) -> None:
    current = previous
    for _ in range(lost + 1):
        current = codec.next_sync_counter(current)
    assert codec.lost_syncs(previous, current) == lost


# --------------------------------------------------------------------------- COB-IDs


@given(st.sampled_from(FunctionCode), st.integers(1, 127))
def test_cob_id_round_trip(function: FunctionCode, node_id: int) -> None:
    assert codec.split_cob_id(codec.cob_id(function, node_id)) == (function, node_id)


def test_predefined_connection_set() -> None:
    node = codec.R_DRIVE_NODE_ID
    assert codec.cob_id(FunctionCode.TPDO1, node) == 0x181
    assert codec.cob_id(FunctionCode.TPDO2, node) == 0x281
    assert codec.cob_id(FunctionCode.RPDO1, node) == 0x201
    assert codec.cob_id(FunctionCode.EMCY, node) == 0x081
    assert codec.cob_id(FunctionCode.HEARTBEAT, codec.CONTROLLER_NODE_ID) == 0x70A
    assert (codec.NMT_COB_ID, codec.SYNC_COB_ID) == (0x000, 0x080)


@pytest.mark.parametrize("can_id", [0x000, 0x080, 0x100, 0x300, 0x800, -1])
def test_split_rejects_ids_of_no_node(can_id: int) -> None:
    with pytest.raises(FrameError, match="no node's object"):
        codec.split_cob_id(can_id)


@pytest.mark.parametrize("node_id", [0, 128])
def test_cob_id_rejects_bad_node_ids(node_id: int) -> None:
    with pytest.raises(FrameError, match=r"node-ID must be 1\.\.127"):
        codec.cob_id(FunctionCode.TPDO1, node_id)


# --------------------------------------------------------------------------- EMCY codes


def test_every_emcy_code_has_its_error_register() -> None:
    assert set(nmt.EMCY_ERROR_REGISTER) == set(EmcyCode)
    for code, register in nmt.EMCY_ERROR_REGISTER.items():
        assert bool(register & ErrorRegister.GENERIC) == (code is not EmcyCode.NO_ERROR)


def test_emcy_codes_are_standard_or_manufacturer_specific() -> None:
    standard = {0x0000, 0x2310, 0x3210, 0x3220, 0x7305, 0x8130, 0x8240, 0x8250}
    for code in EmcyCode:
        assert code in standard or 0xFF00 <= code <= 0xFFFF, hex(code)
    assert nmt.emcy_code(0x8250) is EmcyCode.COMMAND_WATCHDOG_TIMEOUT
    assert nmt.emcy_code(0x1000) is None


# --------------------------------------------------------------------------- units


@pytest.mark.parametrize(
    ("voltage_v", "voltage_mv"),
    [(0.0, 0), (12.0, 12000), (-0.0014, -1), (0.0016, 2), (40.0, 32767), (-40.0, -32767),
     (1e300, 32767)],
)
def test_voltage_v_to_mv_rounds_and_saturates(voltage_v: float, voltage_mv: int) -> None:
    assert codec.voltage_v_to_mv(voltage_v) == voltage_mv


@pytest.mark.parametrize(
    "convert",
    [codec.voltage_v_to_mv, codec.current_a_to_ma, codec.rad_per_s_to_rpm,
     lambda x: codec.motor_rad_to_counts(x, 2000)],
)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_conversions_to_wire_units_reject_non_finite(convert: object, value: float) -> None:
    assert callable(convert)
    with pytest.raises(NonFiniteError):
        convert(value)


@given(INT16)
def test_wire_units_survive_a_round_trip(raw: int) -> None:
    raw = max(raw, -codec.INT16_LIMIT)
    assert codec.voltage_v_to_mv(codec.voltage_mv_to_v(raw)) == raw
    assert codec.current_a_to_ma(codec.current_ma_to_a(raw)) == raw
    assert codec.rad_per_s_to_rpm(codec.rpm_to_rad_per_s(raw)) == raw


@given(INT32, st.integers(1, 1 << 20))
def test_counts_survive_a_round_trip(counts: int, counts_per_rev: int) -> None:
    counts = max(counts, -codec.INT32_LIMIT)
    angle_rad = codec.counts_to_motor_rad(counts, counts_per_rev)
    assert codec.motor_rad_to_counts(angle_rad, counts_per_rev) == counts


def test_unit_scales() -> None:
    assert codec.counts_to_motor_rad(500, 2000) == pytest.approx(math.pi / 2)
    assert codec.rpm_to_rad_per_s(60) == pytest.approx(2 * math.pi)
    assert codec.rad_per_s_to_rpm(2 * math.pi) == 60
    assert codec.current_ma_to_a(-2500) == -2.5
    assert codec.motor_rad_to_counts(1e12, 2000) == codec.INT32_LIMIT
