"""What an emulated drive is: its node-ID, its type and EDS, the objects its parameters live
in, its hardware and what another tool stored in it (:class:`DriveSpec`); the SDO abort
codes its own checks answer with. The dictionary built from them is
:mod:`drivers.dictionary`."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from rakectl.core.motor_model import MotorParams
from rakectl.protocol.files import EDS_DIR

Frame = tuple[int, bytes | bytearray]
Object = tuple[int, int]  # index, subindex


@dataclass(frozen=True)
class ParameterObjects:
    """Where a drive type keeps the parameters the emulated drive acts on, and their units.

    ``max_voltage`` None: the drive has no voltage limit of its own (it commands a share of
    its supply). ``current_unit_ma``: the current limit's unit (1 mA, or 100 mA = 0.1 A).
    ``rx``: the objects an RPDO may map (what the drive acts on)."""

    max_voltage: Object | None
    current_limit: Object
    current_unit_ma: int
    watchdog: Object
    counts_per_rev: Object
    tpdo2_refresh: Object
    rx: frozenset[Object]


OWN_PROFILE: Final = ParameterObjects(
    max_voltage=(0x2001, 0), current_limit=(0x2002, 0), current_unit_ma=1,
    watchdog=(0x2003, 0), counts_per_rev=(0x2004, 0), tpdo2_refresh=(0x2005, 0),
    rx=frozenset({(0x2000, 0), (0x6040, 0)}))
ROBOTEQ_CLASS: Final = ParameterObjects(
    max_voltage=None, current_limit=(0x3002, 0), current_unit_ma=100,
    watchdog=(0x3001, 0), counts_per_rev=(0x3003, 0), tpdo2_refresh=(0x3004, 0),
    rx=frozenset({(0x2000, 1)}))


class DriveKind(enum.Enum):
    """A drive type and its EDS (object dictionary, product code)."""

    DC_SERVO = "dc_servo_drive.eds"
    GEARED_MOTOR = "geared_motor_drive.eds"
    ROBOTEQ_CLASS = "roboteq_class_drive.eds"  # a manufacturer profile, no CiA 402

    @property
    def eds_path(self) -> Path:
        return EDS_DIR / self.value

    @property
    def parameters(self) -> ParameterObjects:
        return ROBOTEQ_CLASS if self is DriveKind.ROBOTEQ_CLASS else OWN_PROFILE


class SdoAbort(enum.IntEnum):
    """SDO abort codes (CiA 301) this drive's own checks use."""

    UNKNOWN_COMMAND = 0x05040001  # command specifier not valid, or out of sequence
    VALUE_RANGE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    DEVICE_STATE = 0x08000022
    NO_DATA = 0x08000024  # e.g. an error history entry beyond the number of errors


@dataclass(frozen=True)
class DriveSpec:
    """What a drive is: its node-ID, type, hardware and serial number."""

    node_id: int
    kind: DriveKind
    motor: MotorParams  # the hardware: supply and current limit bound 0x2001 and 0x2002
    serial_number: int
    controller_node_id: int
    overcurrent_time_s: float = 0.5
    stored: tuple[tuple[int, int, int], ...] = ()  # (index, subindex, value) of 0x1000–0x1FFF
    # as another tool stored them: reset communication restores these, not the EDS's
    tpdo_rtr: bool = True  # False: its TPDOs answer no RTR (COB-ID bit 30 set, kept)
