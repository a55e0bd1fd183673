"""Generate ``rakedrive.dbc``, the database that decodes bus traces, from the EDS files.

    python -m rakectl.protocol.gen_dbc > rakectl/protocol/rakedrive.dbc

then, for a candump log: ``python -m cantools decode rakectl/protocol/rakedrive.dbc < trace.log``.

The PDO messages come from each drive's EDS: COB-IDs from the communication
objects (0x1400/0x1800 …) at the default node-IDs (r drive 1, θ drive 2),
signals from the mapping objects (0x1600/0x1A00 …), bit lengths and
signedness from the mapped objects' data types. Only the physical scaling is
added here (:data:`SIGNAL_STYLES`, by object index): voltage and current in
V and A, velocity in rad/s, position left in encoder counts (its scale,
0x2004, is configurable). SYNC follows :mod:`rakectl.protocol.codec`, NMT,
heartbeats and EMCY :mod:`rakectl.protocol.nmt`; value tables come from
:mod:`rakectl.protocol.nmt` and :mod:`rakectl.protocol.cia402`. :func:`dbc_text` is
pure; ``tests/protocol/test_eds_dbc.py`` checks that the committed file is its output.
"""

from __future__ import annotations

import enum
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final

import canopen
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable, datatypes

from rakectl.protocol import codec
from rakectl.protocol.cia402 import DriveCommand
from rakectl.protocol.files import EDS_DIR
from rakectl.protocol.nmt import EMCY_SIZE, EmcyCode, NmtCommand, NmtState

DC_SERVO_EDS: Final = EDS_DIR / "dc_servo_drive.eds"
GEARED_MOTOR_EDS: Final = EDS_DIR / "geared_motor_drive.eds"
CONTROLLER: Final = "CONTROLLER"


@dataclass(frozen=True)
class Drive:
    """One drive on the bus: its DBC node name, node-ID and object dictionary."""

    label: str
    node_id: int
    od: ObjectDictionary


@dataclass(frozen=True)
class SignalStyle:
    """How a mapped object appears in the DBC: name with unit, scale, unit."""

    name: str
    factor: float = 1.0
    unit: str = ""
    choices: tuple[tuple[int, str], ...] = ()


@dataclass(frozen=True)
class Signal:
    name: str
    start_bit: int
    length: int
    signed: bool
    receivers: tuple[str, ...]
    factor: float = 1.0
    unit: str = ""
    comment: str = ""
    choices: tuple[tuple[int, str], ...] = ()
    raw_range: tuple[int, int] | None = None  # None: the whole range of the bits

    def raw_limits(self) -> tuple[int, int]:
        if self.raw_range is not None:
            return self.raw_range
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1


@dataclass(frozen=True)
class Message:
    frame_id: int
    name: str
    size: int
    sender: str
    signals: tuple[Signal, ...]
    comment: str


def _choices(values: type[enum.Enum]) -> tuple[tuple[int, str], ...]:
    """(value, name) of each member; aliases are named with their member, "A / B"."""
    names: dict[int, list[str]] = {}
    for name, member in values.__members__.items():
        names.setdefault(int(member.value), []).append(name)
    return tuple((value, " / ".join(aliases)) for value, aliases in names.items())


SIGNAL_STYLES: Final = {
    0x6064: SignalStyle("position_counts", 1.0, "counts"),
    0x606C: SignalStyle("velocity_rad_per_s", codec.RAD_PER_S_PER_RPM, "rad/s"),
    0x2100: SignalStyle("current_a", 0.001, "A"),
    0x6041: SignalStyle("statusword"),
    0x1001: SignalStyle("error_register"),
    0x2000: SignalStyle("voltage_v", 0.001, "V"),
    0x6040: SignalStyle("controlword", choices=_choices(DriveCommand)),
}
"""DBC name, scale and unit of each object a PDO maps (raw × factor = physical)."""


# --------------------------------------------------------------------------- from the EDS


def _variable(od: ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    entry = od[index]
    if isinstance(entry, (ODRecord, ODArray)):
        entry = entry[subindex]
    assert isinstance(entry, ODVariable)
    return entry


def _default(od: ObjectDictionary, index: int, subindex: int) -> int:
    value = _variable(od, index, subindex).default
    if not isinstance(value, int):
        raise ValueError(f"0x{index:04X}:{subindex} has no integer default")
    return value


def pdo_mapping(od: ObjectDictionary, map_index: int) -> list[tuple[int, int, int]]:
    """(index, subindex, bit length) of each object a mapping object maps, in order."""
    count = _default(od, map_index, 0)
    entries = (_default(od, map_index, sub) for sub in range(1, count + 1))
    return [(e >> 16, (e >> 8) & 0xFF, e & 0xFF) for e in entries]


def _pdo_signals(drive: Drive, map_index: int, receivers: tuple[str, ...]) -> tuple[Signal, ...]:
    signals, start = [], 0
    for index, subindex, length in pdo_mapping(drive.od, map_index):
        variable, style = _variable(drive.od, index, subindex), SIGNAL_STYLES[index]
        signed = variable.data_type in datatypes.SIGNED_TYPES
        comment = f"0x{index:04X} {variable.name}"
        signals.append(Signal(style.name, start, length, signed, receivers, style.factor,
                              style.unit, comment, style.choices))
        start += length
    return tuple(signals)


def pdo_messages(drive: Drive) -> list[Message]:
    """Every PDO in the drive's EDS, at its default COB-ID."""
    kinds = (("TPDO", 0x1800, 0x1A00, drive.label, (CONTROLLER,)),
             ("RPDO", 0x1400, 0x1600, CONTROLLER, (drive.label,)))
    messages = []
    for kind, com_base, map_base, sender, receivers in kinds:
        for number in range(512):
            if com_base + number not in drive.od:
                continue
            signals = _pdo_signals(drive, map_base + number, receivers)
            size = sum(s.length for s in signals) // 8
            cob = _default(drive.od, com_base + number, 1) & 0x7FF
            product = drive.od.device_information.product_name
            comment = f"{kind}{number + 1} of node {drive.node_id} ({product})"
            messages.append(Message(cob, f"{drive.label}_{kind}{number + 1}", size, sender,
                                    signals, comment))
    return messages


# --------------------------------------------------------------------------- fixed objects


def _heartbeat(label: str, node_id: int, receivers: tuple[str, ...]) -> Message:
    state = Signal("nmt_state", 0, 8, False, receivers, choices=_choices(NmtState))
    cob = codec.cob_id(codec.FunctionCode.HEARTBEAT, node_id)
    return Message(cob, f"{label}_HEARTBEAT", 1, label, (state,), f"Heartbeat of node {node_id}")


def _emcy(drive: Drive) -> Message:
    to = (CONTROLLER,)
    signals = (
        Signal("error_code", 0, 16, False, to, choices=_choices(EmcyCode)),
        Signal("error_register", 16, 8, False, to),
        Signal("manufacturer_data", 24, 40, False, to),
    )
    cob = codec.cob_id(codec.FunctionCode.EMCY, drive.node_id)
    return Message(cob, f"{drive.label}_EMCY", EMCY_SIZE, drive.label, signals,
                   f"EMCY of node {drive.node_id}")


def fixed_messages(drives: Sequence[Drive]) -> list[Message]:
    """SYNC, NMT, the heartbeats and the drives' EMCYs."""
    to_drives = tuple(d.label for d in drives)
    sync = Signal("sync_counter", 0, 8, False, to_drives, comment="1..240, then 1 again",
                  raw_range=(1, codec.SYNC_COUNTER_MAX))
    nmt = (Signal("command", 0, 8, False, to_drives, choices=_choices(NmtCommand)),
           Signal("node_id", 8, 8, False, to_drives, comment="0 = every node"))
    return [
        Message(codec.NMT_COB_ID, "NMT", 2, CONTROLLER, nmt, "NMT command"),
        Message(codec.SYNC_COB_ID, "SYNC", codec.SYNC_SIZE, CONTROLLER, (sync,), "SYNC"),
        _heartbeat(CONTROLLER, codec.CONTROLLER_NODE_ID, to_drives),
        *(_heartbeat(d.label, d.node_id, (CONTROLLER,)) for d in drives),
        *(_emcy(d) for d in drives),
    ]


# --------------------------------------------------------------------------- DBC text


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _signal_line(s: Signal) -> str:
    raw_low, raw_high = s.raw_limits()
    low, high = _number(raw_low * s.factor), _number(raw_high * s.factor)
    return (f" SG_ {s.name} : {s.start_bit}|{s.length}@1{'-' if s.signed else '+'} "
            f"({_number(s.factor)},0) [{low}|{high}] \"{s.unit}\" {','.join(s.receivers)}")


def _message_block(m: Message) -> str:
    lines = [f"BO_ {m.frame_id} {m.name}: {m.size} {m.sender}"]
    lines += [_signal_line(s) for s in m.signals]
    return "\n".join(lines)


def _comments(messages: Iterable[Message]) -> list[str]:
    lines = []
    for m in messages:
        lines.append(f'CM_ BO_ {m.frame_id} "{m.comment}";')
        lines += [f'CM_ SG_ {m.frame_id} {s.name} "{s.comment}";' for s in m.signals if s.comment]
    return lines


def _value_tables(messages: Iterable[Message]) -> list[str]:
    lines = []
    for m in messages:
        for s in (s for s in m.signals if s.choices):
            pairs = " ".join(f'{value} "{name}"' for value, name in s.choices)
            lines.append(f"VAL_ {m.frame_id} {s.name} {pairs} ;")
    return lines


def dbc_text(drives: Sequence[Drive]) -> str:
    """The DBC for a bus with these drives and the controller."""
    messages = sorted(fixed_messages(drives) + [m for d in drives for m in pdo_messages(d)],
                      key=lambda m: m.frame_id)
    nodes = " ".join((CONTROLLER, *(d.label for d in drives)))
    header = ['VERSION ""', "", "NS_ :", "\tCM_", "\tVAL_", "", "BS_:", "", f"BU_: {nodes}", ""]
    body = [_message_block(m) + "\n" for m in messages]
    return "\n".join([*header, *body, *_comments(messages), "", *_value_tables(messages), ""])


def default_drives() -> list[Drive]:
    """The rake's two drives at their default node-IDs, read from the EDS files."""
    return [
        Drive("R_DRIVE", codec.R_DRIVE_NODE_ID,
              canopen.import_od(str(DC_SERVO_EDS), codec.R_DRIVE_NODE_ID)),
        Drive("THETA_DRIVE", codec.THETA_DRIVE_NODE_ID,
              canopen.import_od(str(GEARED_MOTOR_EDS), codec.THETA_DRIVE_NODE_ID)),
    ]


def main() -> None:
    sys.stdout.write(dbc_text(default_drives()))


if __name__ == "__main__":
    main()
