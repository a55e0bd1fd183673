"""The two drives as the controller knows them: joints, node-IDs, the frames it listens
to, identities, limits and the parameters written at bring-up (from their EDS files)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import canopen
from canopen.objectdictionary import ObjectDictionary, ODVariable, datatypes

from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.core.motor_model import MotorParams
from rakectl.errors import ConfigError
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.codec import (
    NMT_COB_ID,
    SYNC_COB_ID,
    FunctionCode,
    cob_id,
)
from rakectl.protocol.files import EDS_DIR


class Joint(enum.IntEnum):
    """The two joints, each driven by one drive; the value indexes per-drive lists."""

    R = 0
    THETA = 1


JOINTS = (Joint.R, Joint.THETA)
_LABEL = {Joint.R: "r", Joint.THETA: "θ"}


def node_ids(drives: DrivesSettings) -> tuple[int, int]:
    """(r drive, θ drive) node-IDs."""
    return drives.r_node_id, drives.theta_node_id


def drive_label(joint: Joint, node_id: int) -> str:
    """How messages name a drive: ``r drive (node 1)``."""
    return f"{_LABEL[joint]} drive (node {node_id})"


def receive_ids(drives: DrivesSettings) -> tuple[int, ...]:
    """COB-IDs the controller receives: TPDO1, TPDO2, EMCY, heartbeat and SDO response per
    drive, and its RPDO1, which only another node sends (socketcan does not hand a socket
    its own frames): another master commanding the drive."""
    functions = (FunctionCode.TPDO1, FunctionCode.TPDO2, FunctionCode.EMCY,
                 FunctionCode.HEARTBEAT, FunctionCode.SDO_RESPONSE, FunctionCode.RPDO1)
    return tuple(cob_id(f, node) for node in node_ids(drives) for f in functions)


def own_ids(drives: DrivesSettings) -> tuple[int, ...]:
    """COB-IDs the controller sends (udp_multicast echoes them back)."""
    per_node = [cob_id(f, node) for node in node_ids(drives)
                for f in (FunctionCode.RPDO1, FunctionCode.SDO_REQUEST)]
    controller = cob_id(FunctionCode.HEARTBEAT, drives.controller_node_id)
    return (NMT_COB_ID, SYNC_COB_ID, controller, *per_node)


# =========================================================================== bring-up


@dataclass(frozen=True)
class Identity:
    """Identity object 0x1018 of a drive."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int


@dataclass(frozen=True)
class DriveLimits:
    """The configuration written at bring-up, as read back from the drive."""

    max_voltage_mv: int  # 0x2001
    current_limit_ma: int  # 0x2002
    watchdog_timeout_ms: int  # 0x2003
    encoder_counts_per_rev: int  # 0x2004
    heartbeat_period_ms: int  # 0x1017
    consumer_heartbeat: int  # 0x1016:1, controller node-ID << 16 | timeout ms
    sync_counter_overflow: int  # 0x1019: 0 = SYNC without counter


@dataclass(frozen=True)
class PdoReading:
    """One PDO's communication and mapping parameters as read back from a drive (equal
    to its EDS's: bring-up checks it)."""

    name: str  # "RPDO1", "TPDO2", ...
    cob_id: int  # sub 1 of 0x1400 + n or 0x1800 + n
    transmission_type: int  # sub 2: 1 … 240 synchronous (every n-th SYNC), 254/255 event
    mapped: tuple[int, ...]  # the mapping's entries: index << 16 | subindex << 8 | bits
    # (name, value) of an inhibit time or event timer the drive held otherwise than its
    # EDS (a PDO written back); not compared
    timers: tuple[tuple[str, int], ...] = field(default=(), compare=False)

    def entries(self) -> list[tuple[int, int, int]]:
        """(index, subindex, bits) of each mapped object."""
        return [(m >> 16, (m >> 8) & 0xFF, m & 0xFF) for m in self.mapped]


@dataclass(frozen=True)
class DriveInfo:
    """A drive after bring-up: who it is and the limits it verifiably holds."""

    joint: Joint
    node_id: int
    identity: Identity
    limits: DriveLimits
    statusword: int  # 0x6041 read just before NMT start
    state: DriveState
    cleared_fault: int = 0  # 0x603F of a fault the previous run left, reset at bring-up
    device_name: str = ""  # 0x1008
    pdos: tuple[PdoReading, ...] = ()  # as read back, equal to the EDS's
    rewritten: tuple[PdoReading, ...] = ()  # what the drive held of the PDOs written back
    extra: tuple[ExtraPdo, ...] = ()  # PDOs beyond the EDS's that the drive held valid


@dataclass(frozen=True)
class ExtraPdo:
    """A PDO the drive has beyond its EDS's and held valid: made not valid at bring-up
    (bit 31 of its COB-ID; not stored: again at every bring-up), or, an RPDO whose COB-ID
    the drive keeps, left valid and named."""

    name: str  # "RPDO2", "TPDO3", ...
    index: int  # its communication parameter, 0x1400 + n or 0x1800 + n
    cob_id: int  # as the drive held it
    kept: str = ""  # why the drive kept it valid (its SDO abort); "": made not valid


@dataclass(frozen=True)
class Parameter:
    """One object written at bring-up, with the setting it comes from; ``limit`` is the
    :class:`DriveLimits` field its read-back fills (times ``limit_scale``: the drive's
    unit in the field's)."""

    index: int
    subindex: int
    name: str
    unit: str
    value: int
    setting: str
    limit: str = ""
    limit_scale: int = 1

    def where(self) -> str:
        return f"0x{self.index:04X}" + (f":{self.subindex}" if self.subindex else "")


def motor_of(motors: MotorsSettings, joint: Joint) -> MotorParams:
    return motors.r if joint is Joint.R else motors.theta


def configured_identity(drives: DrivesSettings, joint: Joint) -> tuple[int, int]:
    """(vendor-ID, product code) the drive of ``joint`` must report; -1: its EDS's."""
    if joint is Joint.R:
        return drives.r_vendor_id, drives.r_product_code
    return drives.theta_vendor_id, drives.theta_product_code


def load_drive_od(eds_file: str, node_id: int) -> ObjectDictionary:
    """The object dictionary of a drive type, from its EDS file."""
    return canopen.import_od(str(EDS_DIR / eds_file), node_id)


def od_variable(od: ObjectDictionary, index: int, subindex: int) -> ODVariable:
    var = od.get_variable(index, subindex)
    if var is None:
        raise ConfigError(f"0x{index:04X}:{subindex} is not in the drive's EDS")
    return var


def allowed_range(var: ODVariable) -> tuple[int, int]:
    bits = len(var)
    signed = var.data_type in (datatypes.INTEGER8, datatypes.INTEGER16, datatypes.INTEGER32)
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    return (low if var.min is None else max(low, var.min),
            high if var.max is None else min(high, var.max))


