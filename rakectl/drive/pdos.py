"""The PDO part of the drives' bring-up (step 6 of rakectl.drive.bringup): every PDO the
EDS declares read back; one a drive holds otherwise (another tool stored it) written back
to the EDS's in CiA 301's order and read again; a drive that refuses it, or keeps its
own, refused with one line naming the object and what the drive held.

It makes its SDO transfers through the bring-up's own (given to :class:`PdoCheck`), so
their retries, timeouts and one-line failures are the bring-up's.
"""

from __future__ import annotations

from collections.abc import Callable

from canopen.objectdictionary import ObjectDictionary

from rakectl.drive.joints import Joint, Parameter, PdoReading, od_variable
from rakectl.errors import ConfigError, DriveFault

PDO_SLOTS = 512  # CiA 301: RPDO and TPDO communication parameters 0x1400/0x1800 + 0 … 511
PDO_NOT_VALID = 1 << 31  # bit 31 of a PDO's COB-ID
MORE_ENTRIES = -1  # a read-back mapping longer than the EDS's ends in this


class PdoCheck:
    """The PDOs of the drives, checked and written back over the bring-up's transfers."""

    def __init__(self, read: Callable[[Joint, int, int, str], int],
                 write: Callable[[Joint, Parameter], None], label: Callable[[Joint], str],
                 od: Callable[[Joint], ObjectDictionary], eds: Callable[[Joint], str]) -> None:
        """``eds``: the name of a drive's EDS file, for the messages."""
        self._read, self._write, self._label, self._od = read, write, label, od
        self._eds = eds

    def check(self, joint: Joint) -> tuple[tuple[PdoReading, ...], tuple[PdoReading, ...]]:
        """Every PDO the EDS declares, read back. One that differs from the EDS (another
        tool stored its own mapping, which reset communication restores) is written back
        to the EDS's in CiA 301's order (:meth:`_remap`) and read again; DriveFault naming
        the first object that still differs."""
        slots = self._pdo_slots(joint)
        declared = [self._declared_pdo(joint, *slot) for slot in slots]
        readings = [self._read_pdo(joint, *slot, eds)
                    for slot, eds in zip(slots, declared, strict=True)]
        if readings == declared:
            return tuple(readings), ()
        for (_, comm, mapping), reading, eds in zip(slots, readings, declared, strict=True):
            if reading != eds:
                self._remap(joint, comm, mapping, reading, eds)
        for (name, comm, mapping), eds in zip(slots, declared, strict=True):
            self._expect(joint, comm, 1, f"{name} COB-ID")
            self._expect(joint, comm, 2, f"{name} transmission type")
            self._expect(joint, mapping, 0, f"{name} number of mapped objects")
            for k in range(1, len(eds.mapped) + 1):
                self._expect(joint, mapping, k, f"{name} mapped object {k}")
        return tuple(declared), tuple(r for r, e in zip(readings, declared, strict=True)
                                      if r != e)

    def _pdo_slots(self, joint: Joint) -> list[tuple[str, int, int]]:
        """(name, communication index, mapping index) of each PDO the EDS declares."""
        od = self._od(joint)
        return [(f"{kind}{n + 1}", comm_base + n, map_base + n)
                for kind, comm_base, map_base in (("RPDO", 0x1400, 0x1600),
                                                  ("TPDO", 0x1800, 0x1A00))
                for n in range(PDO_SLOTS) if comm_base + n in od]

    def _read_pdo(self, joint: Joint, name: str, comm: int, mapping: int,
                  eds: PdoReading) -> PdoReading:
        """A PDO as the drive holds it (the entries past the EDS's count are not read:
        a longer mapping differs anyway, and ends in ``MORE_ENTRIES``)."""
        count = self._read(joint, mapping, 0, f"{name} number of mapped objects")
        entries = tuple(self._read(joint, mapping, k, f"{name} mapped object {k}")
                        for k in range(1, min(count, len(eds.mapped)) + 1))
        return PdoReading(name, self._read(joint, comm, 1, f"{name} COB-ID"),
                          self._read(joint, comm, 2, f"{name} transmission type"),
                          entries if count <= len(eds.mapped) else (*entries, MORE_ENTRIES))

    def _declared_pdo(self, joint: Joint, name: str, comm: int, mapping: int) -> PdoReading:
        od = self._od(joint)

        def eds(index: int, subindex: int) -> int:
            default = od_variable(od, index, subindex).default
            if not isinstance(default, int):
                raise ConfigError(f"{self._eds(joint)}: 0x{index:04X}:{subindex} has no "
                                  "integer default")
            return default

        return PdoReading(name, eds(comm, 1), eds(comm, 2),
                          tuple(eds(mapping, k) for k in range(1, eds(mapping, 0) + 1)))

    def _remap(self, joint: Joint, comm: int, mapping: int, held: PdoReading,
               eds: PdoReading) -> None:
        """The EDS's PDO written in CiA 301's order: the COB-ID the drive holds made not
        valid (bit 31), then the EDS's CAN-ID if it differs (still not valid), the
        transmission type, sub 0 = 0, the entries, sub 0 = n, the COB-ID as declared. A
        step the drive refuses is one DriveFault naming the PDO, what the drive held and
        the step."""
        name, why = eds.name, "the EDS's PDO mapping"
        steps = [(comm, 1, "COB-ID", held.cob_id | PDO_NOT_VALID)]
        if held.cob_id & 0x7FF != eds.cob_id & 0x7FF:
            steps.append((comm, 1, "COB-ID", eds.cob_id | PDO_NOT_VALID))
        steps += [(comm, 2, "transmission type", eds.transmission_type),
                  (mapping, 0, "number of mapped objects", 0),
                  *((mapping, k, f"mapped object {k}", entry)
                    for k, entry in enumerate(eds.mapped, start=1)),
                  (mapping, 0, "number of mapped objects", len(eds.mapped)),
                  (comm, 1, "COB-ID", eds.cob_id)]
        for index, subindex, what, value in steps:
            try:
                self._write(joint, Parameter(index, subindex, f"{name} {what}", "", value, why))
            except DriveFault as error:
                raise DriveFault(f"{error} (writing {self._eds(joint)}'s {name} back over the "
                                 f"drive's: {_describe(held)})") from error

    def _expect(self, joint: Joint, index: int, subindex: int, name: str) -> int:
        """An object read back that must hold its EDS default."""
        value = self._read(joint, index, subindex, name)
        declared = od_variable(self._od(joint), index, subindex).default
        if value != declared:
            raise DriveFault(f"{self._label(joint)}: 0x{index:04X}:{subindex} {name} is "
                             f"0x{value:X}, {self._eds(joint)} declares 0x{declared:X}, and "
                             "the drive kept it when the EDS's mapping was written: the hot "
                             "path decodes the EDS's PDO layout")
        return value


def _describe(pdo: PdoReading) -> str:
    """A PDO's parameters as a drive holds them, in one phrase."""
    mapped = ", ".join(f"0x{m:08X}" if m >= 0 else "..." for m in pdo.mapped)
    return (f"COB-ID 0x{pdo.cob_id:X}, transmission type {pdo.transmission_type}, "
            f"mapped [{mapped}]")
