"""The Roboteq-class drive's protocol (``drives.profile: roboteq``) as pure codecs.

Both the controller and the drive emulator use this module; like
:mod:`rakectl.protocol.codec` it imports no ``can`` or ``canopen``. The object
dictionary and PDO mapping are those of ``rakectl/protocol/eds/roboteq_class_drive.eds``::

    controller → RPDO1   0x200+node  4 B  motor command i32 [‰ of the supply]  0x2000:01
    drive      → TPDO1   0x180+node  8 B  encoder counter i32 [counts]          0x2104:01
                                           encoder motor speed i16 [rpm]         0x2103:01
                                           motor amps i16 [0.1 A]               0x2100:01
    drive      → TPDO2   0x280+node  4 B  fault flags u16                       0x2112
                                           status flags u16                      0x2111

TPDO1 has the layout of the project's own drive (i32, i16, i16): only the current's
unit differs. There is no CiA 402 state machine: the power stage is switched off by
*emergency shutdown* (0x200C) and on again by *release shutdown* (0x200D), each an
expedited SDO download of one byte (:data:`EMERGENCY_SHUTDOWN`, :data:`RELEASE_SHUTDOWN`).
The controller reads the flags as the CiA 402 state that behaves the same
(:func:`state_of`), so its state machine and supervision stay those of CiA 402.
"""

from __future__ import annotations

import math
import struct
from typing import Final

from rakectl.errors import FrameError, NonFiniteError
from rakectl.protocol.cia402 import DriveState

PER_MILLE: Final = 1000  # the motor command's full scale
CURRENT_A_PER_UNIT: Final = 0.1  # 0x2100's unit
TPDO2_SIZE: Final = 4

FAULT_SHORT_CIRCUIT: Final = 1 << 3  # over current (EMCY 0x2310)
FAULT_EMERGENCY_STOP: Final = 1 << 4  # 0x200C written: the power stage off until 0x200D
FAULT_SENSOR: Final = 1 << 5  # the joint's hard stop hit (EMCY 0xFF01)
FAULT_COMMUNICATION: Final = 1 << 8  # the controller's heartbeat lost (0x1016, EMCY 0x8130)
FAULT_OTHER: Final = 1 << 15  # any other fault (its EMCY names it)
STATUS_SERIAL_MODE: Final = 1 << 0  # commands come from the bus
STATUS_POWER_STAGE_OFF: Final = 1 << 3
STATUS_WATCHDOG_EXPIRED: Final = 1 << 5  # no command for 0x3001 ms: 0 V until the next
STATUS_AMPS_LIMIT: Final = 1 << 6

_COMMAND: Final = struct.Struct("<i")
_FLAGS: Final = struct.Struct("<HH")


def _sdo_download_u8(index: int, value: int) -> bytes:
    """An expedited SDO download of one byte to ``index``:00 (CiA 301: 0x2F)."""
    return struct.pack("<BHBB3x", 0x2F, index, 0, value)


EMERGENCY_SHUTDOWN: Final = _sdo_download_u8(0x200C, 1)  # power stage off, latched
RELEASE_SHUTDOWN: Final = _sdo_download_u8(0x200D, 1)  # and clears the fault flags


def volts_to_per_mille(voltage_v: float, supply_v: float) -> int:
    """A voltage as the motor command: ‰ of ``supply_v``, saturated at ±1000, rounded to
    the nearest ‰ (half of it is 12 mV at 24 V, as the CiA 402 path rounds to the mV:
    docs/installation.md states what it is worth in force). Scaled by the supply the
    configuration states, which bring-up checks the drive's own reading against."""
    if not math.isfinite(voltage_v):
        raise NonFiniteError(f"voltage_v must be finite, got {voltage_v}")
    share = voltage_v * PER_MILLE / supply_v
    if share >= PER_MILLE:
        return PER_MILLE
    if share <= -PER_MILLE:
        return -PER_MILLE
    return round(share)


def per_mille_to_mv(command: int, supply_mv: int) -> int:
    """A motor command (‰ of the supply) in mV, rounded half away from zero."""
    mv = (abs(command) * supply_mv + PER_MILLE // 2) // PER_MILLE
    return mv if command >= 0 else -mv


def pack_command_into(buffer: bytearray, per_mille: int) -> None:
    """RPDO1 data (4 bytes) into ``buffer``, allocating nothing."""
    _COMMAND.pack_into(buffer, 0, per_mille)


def decode_command(data: bytes | bytearray | memoryview) -> int:
    try:
        (per_mille,) = _COMMAND.unpack(data)
    except struct.error:
        raise FrameError(f"RPDO1 must be 4 bytes, got {len(data)}") from None
    return int(per_mille)


def decode_flags(data: bytes | bytearray | memoryview) -> tuple[int, int]:
    """(fault flags, status flags) of TPDO2 data."""
    try:
        fault_flags, status_flags = _FLAGS.unpack(data)
    except struct.error:
        raise FrameError(f"TPDO2 must be {TPDO2_SIZE} bytes, got {len(data)}") from None
    return fault_flags, status_flags


def flags_image(fault_flags: int, status_flags: int) -> int:
    """Both flags in one int (fault flags high): what the controller keeps as the
    drive's status word."""
    return fault_flags << 16 | status_flags


def state_of(image: int) -> DriveState:
    """The CiA 402 state that behaves as a drive with these flags does (:func:`flags_image`):
    FAULT for any fault flag but the emergency stop, and for an expired command watchdog
    (the drive stopped driving by itself, as a CiA 402 drive's watchdog faults it);
    SWITCH_ON_DISABLED for an emergency stop (the power stage off by 0x200C);
    OPERATION_ENABLED otherwise (it applies the commands it receives). An emergency stop
    the controller did not ask for is its client's fault (rakectl.drive.power)."""
    fault_flags, status_flags = image >> 16, image & 0xFFFF
    if fault_flags & ~FAULT_EMERGENCY_STOP or status_flags & STATUS_WATCHDOG_EXPIRED:
        return DriveState.FAULT
    if fault_flags & FAULT_EMERGENCY_STOP:
        return DriveState.SWITCH_ON_DISABLED
    return DriveState.OPERATION_ENABLED
