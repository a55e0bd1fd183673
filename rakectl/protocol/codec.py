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
command watchdog time (0x2003, 20 ms by default) the drive applies 0 V and
faults with :attr:`EmcyCode.COMMAND_WATCHDOG_TIMEOUT`.

On events::

    drive      → TPDO2      0x280+node  3 B  statusword u16 0x6041, error register u8 0x1001
    drive      → EMCY       0x080+node  8 B  error code u16, error register u8, 5 B manufacturer
    any node   → heartbeat  0x700+node  1 B  NMT state
    controller → NMT        0x000       2 B  command specifier u8, node-ID u8 (0 = all)

TPDO2 has transmission type 255: the drive sends it whenever the statusword or
the error register changes (inhibit time 0) and, as a refresh, on every 100th
SYNC it receives (manufacturer object 0x2005, counted by the drive, 0 = off).
Drives send a heartbeat every 100 ms (0x1017). The controller sends one every
100 ms; each drive consumes it with a 250 ms timeout (0x1016 sub 1 =
0x000A00FA: node 10, 250 ms) and faults with :attr:`EmcyCode.HEARTBEAT_LOST`.

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
from collections.abc import Mapping
from types import MappingProxyType
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


def next_sync_counter(counter: int) -> int:
    """The counter after ``counter``: 240 is followed by 1 (CiA 301)."""
    return counter % SYNC_COUNTER_MAX + 1


def lost_syncs(previous: int, current: int, overflow: int = SYNC_COUNTER_MAX) -> int:
    """SYNCs missed between two received counters (0 when consecutive; counting 1 … overflow)."""
    return (current - previous - 1) % overflow


# --------------------------------------------------------------------------- NMT and heartbeat


class NmtState(enum.IntEnum):
    """NMT state in a heartbeat (CiA 301)."""

    BOOT_UP = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


class NmtCommand(enum.IntEnum):
    """NMT command specifier (CiA 301)."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


_NMT: Final = struct.Struct("<BB")
_NMT_STATES: Final = frozenset(NmtState)
_NMT_COMMANDS: Final = frozenset(NmtCommand)


def encode_heartbeat(state: NmtState) -> bytes:
    """Heartbeat data: the producer's NMT state."""
    if state not in _NMT_STATES:
        raise FrameError(f"heartbeat: {state!r} is no NMT state")
    return bytes((state,))


def decode_heartbeat(data: Data) -> NmtState:
    """The NMT state of a heartbeat frame."""
    if len(data) != 1:
        raise _length_error("heartbeat", 1, data)
    try:
        return NmtState(data[0])
    except ValueError:
        raise FrameError(f"heartbeat: 0x{data[0]:02X} is no NMT state") from None


def encode_nmt(command: NmtCommand, node_id: int) -> bytes:
    """NMT command data for ``node_id`` (0 = every node)."""
    if command not in _NMT_COMMANDS or not 0 <= node_id <= 127:
        raise FrameError(f"NMT: need a command and a node-ID 0..127, got {command!r}, {node_id!r}")
    return _NMT.pack(command, node_id)


def decode_nmt(data: Data) -> tuple[NmtCommand, int]:
    """(command, node-ID) of an NMT command frame."""
    try:
        command, node_id = _NMT.unpack(data)
    except struct.error:
        raise _length_error("NMT", _NMT.size, data) from None
    try:
        return NmtCommand(command), node_id
    except ValueError:
        raise FrameError(f"NMT: 0x{command:02X} is no NMT command") from None


# --------------------------------------------------------------------------- EMCY


class ErrorRegister(enum.IntFlag):
    """Error register 0x1001 (CiA 301); GENERIC is set whenever any error is."""

    GENERIC = 0x01
    CURRENT = 0x02
    VOLTAGE = 0x04
    TEMPERATURE = 0x08
    COMMUNICATION = 0x10
    DEVICE_PROFILE = 0x20
    MANUFACTURER = 0x80


class EmcyCode(enum.IntEnum):
    """EMCY error codes the emulated drives send: CiA 301/402 codes where one fits, else 0xFFxx.

    Each is a fault but INVALID_COMMAND and SYNC_DATA_LENGTH (warnings): the drive
    applies 0 V and goes through FAULT_REACTION_ACTIVE to FAULT (CiA 402
    transitions 13, 14), stores the code in 0x603F and sends the EMCY. After a
    fault reset it sends NO_ERROR with error register 0.
    """

    NO_ERROR = 0x0000  # error reset (CiA 301)
    OVER_CURRENT = 0x2310  # continuous over-current (CiA 402)
    SUPPLY_OVER_VOLTAGE = 0x3210  # DC link over-voltage (CiA 402)
    SUPPLY_UNDER_VOLTAGE = 0x3220  # DC link under-voltage (CiA 402)
    ENCODER_FAULT = 0x7305  # incremental sensor 1 fault (CiA 402)
    HEARTBEAT_LOST = 0x8130  # controller heartbeat missed for 0x1016 (CiA 301)
    SYNC_DATA_LENGTH = 0x8240  # a SYNC whose length does not follow 0x1019 (CiA 301; a warning)
    COMMAND_WATCHDOG_TIMEOUT = 0x8250  # no RPDO1 for 0x2003 ms: RPDO timeout (CiA 301)
    HARD_STOP_HIT = 0xFF01  # manufacturer-specific: the joint hit its mechanical stop
    INVALID_COMMAND = 0xFF02  # manufacturer-specific: |voltage| > 0x2001, or a bad mode


EMCY_ERROR_REGISTER: Final[Mapping[EmcyCode, ErrorRegister]] = MappingProxyType({
    EmcyCode.NO_ERROR: ErrorRegister(0),
    EmcyCode.OVER_CURRENT: ErrorRegister.GENERIC | ErrorRegister.CURRENT,
    EmcyCode.SUPPLY_OVER_VOLTAGE: ErrorRegister.GENERIC | ErrorRegister.VOLTAGE,
    EmcyCode.SUPPLY_UNDER_VOLTAGE: ErrorRegister.GENERIC | ErrorRegister.VOLTAGE,
    EmcyCode.ENCODER_FAULT: ErrorRegister.GENERIC | ErrorRegister.DEVICE_PROFILE,
    EmcyCode.HEARTBEAT_LOST: ErrorRegister.GENERIC | ErrorRegister.COMMUNICATION,
    EmcyCode.SYNC_DATA_LENGTH: ErrorRegister.GENERIC | ErrorRegister.COMMUNICATION,
    EmcyCode.COMMAND_WATCHDOG_TIMEOUT: ErrorRegister.GENERIC | ErrorRegister.COMMUNICATION,
    EmcyCode.HARD_STOP_HIT: ErrorRegister.GENERIC | ErrorRegister.MANUFACTURER,
    EmcyCode.INVALID_COMMAND: ErrorRegister.GENERIC | ErrorRegister.MANUFACTURER,
})
"""The error register a drive reports with each code."""

_EMCY: Final = struct.Struct("<HB5s")
EMCY_SIZE: Final = _EMCY.size
_EMCY_BY_CODE: Final = {c.value: c for c in EmcyCode}


class Emcy(NamedTuple):
    """A decoded EMCY; ``code`` may be one of another device (see :func:`emcy_code`)."""

    code: int
    error_register: int
    manufacturer_data: bytes


def encode_emcy(code: int, error_register: int, manufacturer_data: bytes = bytes(5)) -> bytes:
    """EMCY data: error code uint16, error register uint8, 5 manufacturer bytes."""
    if len(manufacturer_data) != 5:
        raise FrameError(f"EMCY: manufacturer data must be 5 bytes, got {len(manufacturer_data)}")
    try:
        return _EMCY.pack(code, error_register, manufacturer_data)
    except struct.error:
        raise FrameError(
            f"EMCY: code={code!r} must be an int in 0..65535 and "
            f"error_register={error_register!r} one in 0..255"
        ) from None


def decode_emcy(data: Data) -> Emcy:
    """The fields of an EMCY frame."""
    try:
        return Emcy(*_EMCY.unpack(data))
    except struct.error:
        raise _length_error("EMCY", EMCY_SIZE, data) from None


def emcy_code(code: int) -> EmcyCode | None:
    """The :class:`EmcyCode` of a received code, or None if ours has no such code."""
    return _EMCY_BY_CODE.get(code)


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
