"""The drives' CAN protocol as pure, precompiled ``struct`` codecs (the 1 kHz hot path).

Both the controller and the drive emulator use this module; it imports no
``can``, ``canopen`` or ``cantools``. The object dictionary and the PDO
mapping are defined once, in ``rakectl/protocol/eds/*.eds``; ``tests/protocol/test_eds_dbc.py``
checks that the ``*_FIELDS`` tables below, the EDS files and
``rakectl/protocol/rakedrive.dbc`` agree.

Bus: CAN 2.0A (11-bit identifiers), 1 Mbit/s; every multi-byte field is
little-endian (CiA 301). Node-IDs: r drive (DC-servo drive) 1, θ drive
(geared-motor drive) 2, controller 10. The controller only produces
heartbeats and SYNC; it has no SDO server, so its node-ID only has to be free.

Every control cycle (1 kHz)::

    controller → SYNC    0x080       1 B  SYNC counter u8: 1, 2 … 240, 1 …  (0x1019 = 240)
    drive      → TPDO1   0x180+node  8 B  position actual value i32 [counts]  0x6064
                                           velocity actual value i16 [rpm]     0x606C
                                           current actual value  i16 [mA]      0x2100
    controller → RPDO1   0x200+node  4 B  voltage command i16 [mV]            0x2000
                                           controlword u16                     0x6040

On SYNC a drive samples position (encoder counts), motor velocity and current
and sends TPDO1 (transmission type 1). RPDO1 is synchronous too (type 1): the
drive applies the latest RPDO1 at the next SYNC, so the command computed from
the TPDO1 of SYNC k acts from SYNC k+1 (one cycle of delay). The counter lets
either side count lost SYNCs (:func:`lost_syncs`). If no RPDO1 arrives for the
command watchdog time (0x2003: 20 ms at power-on, ``drives.watchdog_timeout_ms`` from
bring-up on, 3 ms on the robot) the drive applies 0 V and
faults with :attr:`~rakectl.protocol.nmt.EmcyCode.COMMAND_WATCHDOG_TIMEOUT`.

On events::

    drive      → TPDO2      0x280+node  3 B  statusword u16 0x6041, error register u8 0x1001

TPDO2 has transmission type 255: the drive sends it whenever the statusword or
the error register changes (inhibit time 0) and, as a refresh, on every 100th
SYNC it receives (manufacturer object 0x2005, counted by the drive, 0 = off).
The frames of state and faults (NMT, heartbeat, EMCY) are in
:mod:`rakectl.protocol.nmt`.

Encoders take ints the caller has already clamped and raise
:class:`~rakectl.errors.FrameError` for one outside its wire type; decoders
raise it for a frame of the wrong length or an undefined value. The
``pack_*_into`` variants write into a preallocated buffer (the ``bytearray``
``data`` of a reused ``can.Message``, of exactly the frame's size). The unit
conversions at the end are separate: those into a wire unit (mV, mA, rpm,
counts) round and saturate, only as a numeric guard.
"""

from __future__ import annotations

import enum
import math
import struct
from typing import Final, NamedTuple

from rakectl.errors import FrameError, NonFiniteError

Data = bytes | bytearray | memoryview

# --------------------------------------------------------------------------- identifiers

R_DRIVE_NODE_ID: Final = 1
THETA_DRIVE_NODE_ID: Final = 2
CONTROLLER_NODE_ID: Final = 10
NMT_COB_ID: Final = 0x000
SYNC_COB_ID: Final = 0x080
CONTROLLER_HEARTBEAT_TIMEOUT_MS: Final = 250  # drives' 0x1016 sub 1 for node 10
DRIVE_HEARTBEAT_PERIOD_MS: Final = 100  # drives' 0x1017
TPDO2_REFRESH_SYNCS: Final = 100  # drives' 0x2005


class FunctionCode(enum.IntEnum):
    """COB-ID = function code + node-ID (CiA 301 predefined connection set)."""

    EMCY = 0x080
    TPDO1 = 0x180
    RPDO1 = 0x200
    TPDO2 = 0x280
    SDO_RESPONSE = 0x580  # server (drive) → client
    SDO_REQUEST = 0x600  # client → server (drive)
    HEARTBEAT = 0x700


_FUNCTION_BY_CODE: Final = {f.value: f for f in FunctionCode}


def cob_id(function: FunctionCode, node_id: int) -> int:
    """The COB-ID of ``function`` for node ``node_id`` (1..127)."""
    if not 1 <= node_id <= 127:
        raise FrameError(f"node-ID must be 1..127, got {node_id!r}")
    return int(function) + node_id


def split_cob_id(can_id: int) -> tuple[FunctionCode, int]:
    """(function code, node-ID) of a node's COB-ID; NMT and SYNC have no node."""
    function, node_id = _FUNCTION_BY_CODE.get(can_id & 0x780), can_id & 0x7F
    if function is None or node_id == 0 or not 0 <= can_id <= 0x7FF:
        raise FrameError(f"COB-ID 0x{can_id:03X} is no node's object in this protocol")
    return function, node_id


# --------------------------------------------------------------------------- PDO layouts


class Field(NamedTuple):
    """One mapped object of a PDO: its name here, its OD index and its struct code."""

    name: str
    od_index: int
    od_subindex: int
    code: str  # struct format character: b/B 8 bit, h/H 16, i/I 32; lower case = signed


TPDO1_FIELDS: Final = (
    Field("position_counts", 0x6064, 0, "i"),
    Field("velocity_rpm", 0x606C, 0, "h"),
    Field("current_ma", 0x2100, 0, "h"),
)
TPDO2_FIELDS: Final = (Field("statusword", 0x6041, 0, "H"), Field("error_register", 0x1001, 0, "B"))
RPDO1_FIELDS: Final = (Field("voltage_mv", 0x2000, 0, "h"), Field("controlword", 0x6040, 0, "H"))


def _layout(fields: tuple[Field, ...]) -> struct.Struct:
    return struct.Struct("<" + "".join(f.code for f in fields))


_TPDO1: Final = _layout(TPDO1_FIELDS)
_TPDO2: Final = _layout(TPDO2_FIELDS)
_RPDO1: Final = _layout(RPDO1_FIELDS)
TPDO1_SIZE: Final = _TPDO1.size
TPDO2_SIZE: Final = _TPDO2.size
RPDO1_SIZE: Final = _RPDO1.size


def field_range(code: str) -> tuple[int, int]:
    """Smallest and largest int a struct code holds."""
    bits = 8 * struct.calcsize(code)
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code.islower() else (0, (1 << bits) - 1)


def _fields_error(frame: str, fields: tuple[Field, ...], values: tuple[object, ...]) -> FrameError:
    problems = []
    for f, value in zip(fields, values, strict=True):
        low, high = field_range(f.code)
        if not (isinstance(value, int) and low <= value <= high):
            problems.append(f"{f.name}={value!r} is not an int in {low}..{high}")
    return FrameError(f"{frame}: " + ("; ".join(problems) or f"cannot pack {values!r}"))


def _length_error(frame: str, size: int, data: Data) -> FrameError:
    got = bytes(data).hex(" ") or "nothing"
    return FrameError(f"{frame} must be {size} bytes, got {len(data)}: {got}")


def _buffer_error(frame: str, size: int, buffer: bytearray) -> FrameError | None:
    if len(buffer) < size:
        return FrameError(f"{frame} needs a buffer of {size} bytes, got {len(buffer)}")
    return None


# --------------------------------------------------------------------------- RPDO1


def encode_rpdo(voltage_mv: int, controlword: int) -> bytes:
    """RPDO1 data: voltage command int16 [mV], controlword uint16."""
    try:
        return _RPDO1.pack(voltage_mv, controlword)
    except struct.error:
        raise _fields_error("RPDO1", RPDO1_FIELDS, (voltage_mv, controlword)) from None


def pack_rpdo_into(buffer: bytearray, voltage_mv: int, controlword: int) -> None:
    """:func:`encode_rpdo` into ``buffer`` (RPDO1_SIZE bytes), allocating nothing."""
    try:
        _RPDO1.pack_into(buffer, 0, voltage_mv, controlword)
    except struct.error:
        error = _buffer_error("RPDO1", RPDO1_SIZE, buffer)
        raise error or _fields_error("RPDO1", RPDO1_FIELDS, (voltage_mv, controlword)) from None


def decode_rpdo(data: Data) -> tuple[int, int]:
    """(voltage_mv, controlword) of RPDO1 data."""
    try:
        voltage_mv, controlword = _RPDO1.unpack(data)
    except struct.error:
        raise _length_error("RPDO1", RPDO1_SIZE, data) from None
    return voltage_mv, controlword


# --------------------------------------------------------------------------- TPDO1


def encode_tpdo1(position_counts: int, velocity_rpm: int, current_ma: int) -> bytes:
    """TPDO1 data: position int32 [counts], velocity int16 [rpm], current int16 [mA]."""
    try:
        return _TPDO1.pack(position_counts, velocity_rpm, current_ma)
    except struct.error:
        values = (position_counts, velocity_rpm, current_ma)
        raise _fields_error("TPDO1", TPDO1_FIELDS, values) from None


def pack_tpdo1_into(
    buffer: bytearray, position_counts: int, velocity_rpm: int, current_ma: int
) -> None:
    """:func:`encode_tpdo1` into ``buffer`` (TPDO1_SIZE bytes), allocating nothing."""
    try:
        _TPDO1.pack_into(buffer, 0, position_counts, velocity_rpm, current_ma)
    except struct.error:
        values = (position_counts, velocity_rpm, current_ma)
        error = _buffer_error("TPDO1", TPDO1_SIZE, buffer)
        raise error or _fields_error("TPDO1", TPDO1_FIELDS, values) from None


def decode_tpdo1(data: Data) -> tuple[int, int, int]:
    """(position_counts, velocity_rpm, current_ma) of TPDO1 data."""
    try:
        position_counts, velocity_rpm, current_ma = _TPDO1.unpack(data)
    except struct.error:
        raise _length_error("TPDO1", TPDO1_SIZE, data) from None
    return position_counts, velocity_rpm, current_ma


# --------------------------------------------------------------------------- TPDO2


def encode_tpdo2(statusword: int, error_register: int) -> bytes:
    """TPDO2 data: statusword uint16, error register uint8."""
    try:
        return _TPDO2.pack(statusword, error_register)
    except struct.error:
        raise _fields_error("TPDO2", TPDO2_FIELDS, (statusword, error_register)) from None


def pack_tpdo2_into(buffer: bytearray, statusword: int, error_register: int) -> None:
    """:func:`encode_tpdo2` into ``buffer`` (TPDO2_SIZE bytes), allocating nothing."""
    try:
        _TPDO2.pack_into(buffer, 0, statusword, error_register)
    except struct.error:
        error = _buffer_error("TPDO2", TPDO2_SIZE, buffer)
        raise error or _fields_error("TPDO2", TPDO2_FIELDS, (statusword, error_register)) from None


def decode_tpdo2(data: Data) -> tuple[int, int]:
    """(statusword, error_register) of TPDO2 data."""
    try:
        statusword, error_register = _TPDO2.unpack(data)
    except struct.error:
        raise _length_error("TPDO2", TPDO2_SIZE, data) from None
    return statusword, error_register


# --------------------------------------------------------------------------- SYNC

SYNC_COUNTER_MAX: Final = 240  # 0x1019 synchronous counter overflow value
SYNC_SIZE: Final = 1


def _check_sync_counter(counter: int) -> None:
    if not (isinstance(counter, int) and 1 <= counter <= SYNC_COUNTER_MAX):
        raise FrameError(f"SYNC counter must be an int in 1..{SYNC_COUNTER_MAX}, got {counter!r}")


def encode_sync(counter: int) -> bytes:
    """SYNC data: the counter, 1..240."""
    _check_sync_counter(counter)
    return bytes((counter,))


def pack_sync_into(buffer: bytearray, counter: int) -> None:
    """:func:`encode_sync` into ``buffer`` (1 byte), allocating nothing."""
    _check_sync_counter(counter)
    buffer[0] = counter


def decode_sync(data: Data) -> int:
    """The counter of a SYNC frame."""
    if len(data) != SYNC_SIZE:
        raise _length_error("SYNC", SYNC_SIZE, data)
    _check_sync_counter(data[0])
    return data[0]


def next_sync_counter(counter: int, overflow: int = SYNC_COUNTER_MAX) -> int:
    """The counter after ``counter``: ``overflow`` (0x1019, 240 by default) is followed
    by 1 (CiA 301)."""
    return counter % overflow + 1


def lost_syncs(previous: int, current: int, overflow: int = SYNC_COUNTER_MAX) -> int:
    """SYNCs missed between two received counters (0 when consecutive; counting 1 … overflow)."""
    return (current - previous - 1) % overflow


# --------------------------------------------------------------------------- units

INT16_LIMIT: Final = 32767  # conversions into int16 saturate at ±this
INT32_LIMIT: Final = 2147483647
RAD_PER_S_PER_RPM: Final = math.pi / 30.0


def _round_saturate(value: float, limit: int, name: str) -> int:
    if not math.isfinite(value):
        raise NonFiniteError(f"{name} must be finite, got {value}")
    return min(max(round(value), -limit), limit)


def voltage_v_to_mv(voltage_v: float) -> int:
    """Volts → the RPDO1's int16 millivolts, rounded, saturated at ±32.767 V."""
    return _round_saturate(voltage_v * 1000.0, INT16_LIMIT, "voltage_v")


def voltage_mv_to_v(voltage_mv: int) -> float:
    return voltage_mv / 1000.0


def current_a_to_ma(current_a: float) -> int:
    """Amperes → the TPDO1's int16 milliamperes, rounded, saturated at ±32.767 A."""
    return _round_saturate(current_a * 1000.0, INT16_LIMIT, "current_a")


def current_ma_to_a(current_ma: int) -> float:
    return current_ma / 1000.0


def rad_per_s_to_rpm(velocity_rad_per_s: float) -> int:
    """Motor rad/s → the TPDO1's int16 rpm, rounded, saturated at ±32767 rpm."""
    return _round_saturate(velocity_rad_per_s / RAD_PER_S_PER_RPM, INT16_LIMIT, "velocity")


def rpm_to_rad_per_s(velocity_rpm: float) -> float:
    return velocity_rpm * RAD_PER_S_PER_RPM


def motor_rad_to_counts(angle_rad: float, counts_per_rev: int) -> int:
    """Motor-shaft angle → int32 encoder counts (0x2004 counts per turn), rounded, saturated."""
    return _round_saturate(angle_rad * counts_per_rev / math.tau, INT32_LIMIT, "angle_rad")


def counts_to_motor_rad(position_counts: int, counts_per_rev: int) -> float:
    """Encoder counts → motor-shaft angle [rad] (0x2004 counts per turn)."""
    return position_counts * math.tau / counts_per_rev
