"""NMT, heartbeat and EMCY frames (CiA 301): the bus's network state and faults.

Pure codecs like :mod:`rakectl.protocol.codec`, with its length errors and
:class:`~rakectl.errors.FrameError`, for the frames outside the 1 kHz
exchange, sent on events::

    drive      → EMCY       0x080+node  8 B  error code u16, error register u8, 5 B manufacturer
    any node   → heartbeat  0x700+node  1 B  NMT state
    controller → NMT        0x000       2 B  command specifier u8, node-ID u8 (0 = all)

Drives send a heartbeat every 100 ms (0x1017). The controller sends one every
100 ms; each drive consumes it with a 250 ms timeout (0x1016 sub 1 =
0x000A00FA: node 10, 250 ms) and faults with :attr:`EmcyCode.HEARTBEAT_LOST`.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Mapping
from types import MappingProxyType
from typing import Final, NamedTuple

from rakectl.errors import FrameError
from rakectl.protocol.codec import Data, _length_error

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
