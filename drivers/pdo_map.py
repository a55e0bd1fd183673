"""An emulated drive's PDO communication and mapping parameters, remappable over SDO in
CiA 301's order (pure: no bus, no clock).

Each PDO of the EDS (RPDO1 0x1400/0x1600, TPDO1 0x1800/0x1A00, TPDO2 0x1801/0x1A01) has a
COB-ID (communication parameter sub 1: bit 31 set = not valid, bit 30 = no RTR, bits 0–10
the CAN-ID) and a mapping (sub 0: the number of entries; sub 1 … n: index << 16 |
subindex << 8 | length in bits). A master remaps it in CiA 301's order:

1. invalidate it: the COB-ID with bit 31 set, the other bits kept;
2. sub 0 = 0: the mapping is emptied;
3. the entries, each checked against the object dictionary;
4. sub 0 = n: the n entries together checked (at most 64 bits);
5. validate it: the COB-ID with bit 31 clear.

Refused, with the abort codes CANopenNode answers (the object keeps its value):

* a COB-ID whose CAN-ID differs from the EDS's, or with any of bits 11–29 set:
  0x06090030 (value range: this drive keeps the pre-defined connection set, so its
  frames are routed by ID; bit 30, no RTR, is kept as written: it answers no RTR);
* a COB-ID made valid over an empty mapping: 0x06090030;
* sub 0 or an entry written while the PDO is valid, or an entry while sub 0 ≠ 0:
  0x06010000 (unsupported access);
* an entry naming an object the EDS does not have: 0x06020000; a subindex it does not
  have: 0x06090011 (dummy entries, index < 0x20, are not taken: 0x06020000);
* an object that is not mappable, not in this direction (a TPDO maps what the drive
  reports, an RPDO what it acts on: 0x2000 and 0x6040, a Roboteq-class drive's
  0x2000:01), or with another length than its type's: 0x06040041;
* sub 0 above the entries the EDS gives the mapping, or more than 64 bits: 0x06040042
  (an entry keeps its value when sub 0 is set to 0, and only a mappable object can be
  written into one, so the first n entries always name objects).

NMT reset communication restores the EDS's values (the drive stores nothing: no 0x1010).
A PDO that is not valid is not sent (a TPDO) or not taken (an RPDO, counted as ignored).
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field
from typing import Any, Final

from canopen import SdoAbortedError
from canopen.objectdictionary import ObjectDictionary, ODVariable

COB_ID_INVALID: Final = 1 << 31
COB_ID_RESERVED: Final = 0x3FFFF800  # bits 11–29: 0 with 11-bit identifiers
CAN_ID_MASK: Final = 0x7FF
MAX_PDO_BITS: Final = 64


class PdoAbort(enum.IntEnum):
    """SDO abort codes (CiA 301) of a refused PDO parameter."""

    UNSUPPORTED_ACCESS = 0x06010000
    NO_OBJECT = 0x06020000
    NOT_MAPPABLE = 0x06040041
    TOO_LONG = 0x06040042
    NO_SUB_INDEX = 0x06090011
    VALUE_RANGE = 0x06090030


class Pdo(enum.Enum):
    """The PDOs of the EDS: (communication index, mapping index, whether it transmits)."""

    RPDO1 = (0x1400, 0x1600, False)
    TPDO1 = (0x1800, 0x1A00, True)
    TPDO2 = (0x1801, 0x1A01, True)

    @property
    def comm_index(self) -> int:
        return int(self.value[0])

    @property
    def map_index(self) -> int:
        return int(self.value[1])


Entry = tuple[int, int, int]  # index, subindex, bits


@dataclass
class _PdoState:
    cob_id: int
    count: int
    raw: list[int]  # sub 1 … capacity, 0 = empty
    defaults: tuple[int, int, tuple[int, ...]] = field(repr=False)

    def restore(self) -> None:
        self.cob_id, self.count, raw = self.defaults
        self.raw = list(raw)


def entry_format(var: Any) -> str:
    """The struct code of a mapped object (little-endian, as CiA 301 lays PDOs out)."""
    code = var.STRUCT_TYPES.get(var.data_type)
    if code is None:
        raise ValueError(f"0x{var.index:04X}:{var.subindex} is not an integer")
    return str(code.format)[-1]


class PdoMaps:
    """The three PDOs' parameters; :meth:`read` and :meth:`write` serve them over SDO."""

    def __init__(self, od: ObjectDictionary, rx_objects: frozenset[tuple[int, int]]) -> None:
        """``rx_objects``: what an RPDO may map (the objects the drive acts on)."""
        self._od, self._rx_objects = od, rx_objects
        self._pdos: dict[Pdo, _PdoState] = {}
        for pdo in Pdo:
            mapping: Any = od[pdo.map_index]
            capacity = max(mapping.subindices)
            raw = tuple(int(mapping[s].default) for s in range(1, capacity + 1))
            comm: Any = od[pdo.comm_index]
            default_cob = int(comm[1].default)
            defaults = (default_cob, int(mapping[0].default), raw)
            self._pdos[pdo] = _PdoState(default_cob, defaults[1], list(raw), defaults)
        self.revision = 0  # counts changes of any layout or validity

    def restore(self) -> None:
        """The EDS's values (NMT reset communication)."""
        for state in self._pdos.values():
            state.restore()
        self.revision += 1

    def valid(self, pdo: Pdo) -> bool:
        return not self._pdos[pdo].cob_id & COB_ID_INVALID

    def layout(self, pdo: Pdo) -> tuple[Entry, ...]:
        """The mapped objects in frame order (empty when sub 0 is 0)."""
        state = self._pdos[pdo]
        return tuple((r >> 16, (r >> 8) & 0xFF, r & 0xFF) for r in state.raw[:state.count])

    def is_default(self, pdo: Pdo) -> bool:
        state = self._pdos[pdo]
        return (state.cob_id, state.count, tuple(state.raw)) == state.defaults

    def owns(self, index: int) -> bool:
        return any(index in (p.comm_index, p.map_index) for p in Pdo)

    # ------------------------------------------------------------------- SDO

    def read(self, index: int, subindex: int) -> int | None:
        """The value of a PDO parameter this class keeps (None: the EDS's default)."""
        for pdo, state in self._pdos.items():
            if index == pdo.comm_index and subindex == 1:
                return state.cob_id
            if index == pdo.map_index:
                if subindex == 0:
                    return state.count
                if subindex <= len(state.raw):
                    return state.raw[subindex - 1]
        return None

    def write(self, index: int, subindex: int, value: int) -> bool:
        """Apply a write, or raise ``SdoAbortedError``; False if this class does not keep the
        object (the caller's rule for fixed objects applies)."""
        for pdo, state in self._pdos.items():
            if index == pdo.comm_index and subindex == 1:
                self._write_cob_id(pdo, state, value)
                return True
            if index == pdo.map_index:
                if subindex == 0:
                    self._write_count(pdo, state, value)
                else:
                    self._write_entry(pdo, state, subindex, value)
                self.revision += 1
                return True
        return False

    def _write_cob_id(self, pdo: Pdo, state: _PdoState, value: int) -> None:
        if value & COB_ID_RESERVED or value & CAN_ID_MASK != state.defaults[0] & CAN_ID_MASK:
            raise SdoAbortedError(PdoAbort.VALUE_RANGE)  # the pre-defined connection set's ID
        if not value & COB_ID_INVALID and not state.count:
            raise SdoAbortedError(PdoAbort.VALUE_RANGE)  # valid over an empty mapping
        state.cob_id = value  # bit 30 (no RTR) kept as written: this drive answers no RTR
        self.revision += 1

    def _write_count(self, pdo: Pdo, state: _PdoState, value: int) -> None:
        if not state.cob_id & COB_ID_INVALID:
            raise SdoAbortedError(PdoAbort.UNSUPPORTED_ACCESS)
        if value > len(state.raw):
            raise SdoAbortedError(PdoAbort.TOO_LONG)
        if sum(raw & 0xFF for raw in state.raw[:value]) > MAX_PDO_BITS:
            raise SdoAbortedError(PdoAbort.TOO_LONG)
        state.count = value

    def _write_entry(self, pdo: Pdo, state: _PdoState, subindex: int, value: int) -> None:
        if not state.cob_id & COB_ID_INVALID or state.count:
            raise SdoAbortedError(PdoAbort.UNSUPPORTED_ACCESS)
        index, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if index not in self._od:
            raise SdoAbortedError(PdoAbort.NO_OBJECT)
        entry: Any = self._od[index]
        var: Any = (entry if sub == 0 else None) if isinstance(entry, ODVariable) else (
            entry.get(sub) if hasattr(entry, "get") else None)
        if var is None:
            raise SdoAbortedError(PdoAbort.NO_SUB_INDEX)
        transmit = bool(pdo.value[2])
        readable = var.access_type in ("ro", "rw", "const")
        allowed = var.pdo_mappable and (readable if transmit else (index, sub) in self._rx_objects)
        coded = var.STRUCT_TYPES.get(var.data_type)
        if not allowed or coded is None or bits != coded.size * 8:
            raise SdoAbortedError(PdoAbort.NOT_MAPPABLE)
        state.raw[subindex - 1] = value


class PdoCodec:
    """One PDO's layout compiled into a ``struct`` and the objects it carries."""

    __slots__ = ("_limits", "entries", "size", "struct")

    def __init__(self, od: ObjectDictionary, entries: tuple[Entry, ...]) -> None:
        self.entries = tuple((index, sub) for index, sub, _ in entries)
        formats, limits = [], []
        for index, sub, _ in entries:
            entry: Any = od[index]
            var: Any = entry if isinstance(entry, ODVariable) else entry[sub]
            code = entry_format(var)
            formats.append(code)
            bits = struct.calcsize(code) * 8
            limits.append((-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code.islower()
                          else (0, (1 << bits) - 1))
        self.struct = struct.Struct("<" + "".join(formats))
        self.size = self.struct.size
        self._limits = tuple(limits)

    def pack_into(self, buffer: bytearray, values: list[int]) -> None:
        """The values, each saturated to its type, into ``buffer`` (``size`` bytes)."""
        self.struct.pack_into(buffer, 0, *(max(low, min(high, int(v))) for v, (low, high)
                                           in zip(values, self._limits, strict=True)))

    def unpack(self, data: bytes | bytearray) -> tuple[int, ...]:
        return tuple(self.struct.unpack(data))
