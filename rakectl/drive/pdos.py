"""The PDO part of the drives' bring-up (step 5 of rakectl.drive.bringup): every PDO the
EDS declares read back (COB-ID, transmission type, inhibit time and event timer where the
EDS has them, mapping); one a drive holds otherwise (another tool stored it) written back
to the EDS's in CiA 301's order and read again; a drive that refuses it, or keeps its
own, refused with one line naming the object and what the drive held.

Bit 30 of a COB-ID (no RTR) is the drive's own: many drives report their TPDOs' COB-IDs
with it set (0x40000181) and refuse a COB-ID that clears it, so it is neither compared
nor ever written otherwise than the drive reports it. A PDO the drive has beyond the
EDS's (0x1400 + n or 0x1800 + n, up to the first it does not have) that is valid is made
not valid (bit 31 written, read again; not stored, as a standard master does): a TPDO
sent beside the EDS's would load the bus beyond the budget of docs/can-bus.md, and an
RPDO would let frames no clamp has judged reach the drive. A drive that keeps such a TPDO
valid is refused, naming it; an RPDO it keeps valid (a fixed COB-ID: nothing but the
drive's own tool changes it) is named by ``rakectl drives`` and the daemon's log.

It makes its SDO transfers through the bring-up's own (given to :class:`PdoCheck`), so
their retries, timeouts and one-line failures are the bring-up's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from canopen import SdoAbortedError
from canopen.objectdictionary import ObjectDictionary, ODVariable, datatypes

from rakectl.drive.joints import ExtraPdo, Joint, Parameter, PdoReading, od_variable
from rakectl.drive.sdo import abort_code
from rakectl.errors import ConfigError, DriveFault

PDO_SLOTS = 512  # CiA 301: RPDO and TPDO communication parameters 0x1400/0x1800 + 0 … 511
PDO_NOT_VALID = 1 << 31  # bit 31 of a PDO's COB-ID
PDO_NO_RTR = 1 << 30  # bit 30: no RTR answered for it; the drive's own
MORE_ENTRIES = -1  # a read-back mapping longer than the EDS's ends in this
TIMERS = ((3, "inhibit time"), (5, "event timer"))  # communication subindices, where declared
RPDO_BASE, TPDO_BASE = 0x1400, 0x1800

Slot = tuple[str, int, int]  # name, communication index, mapping index
Timer = tuple[int, str, int, int]  # subindex, name, as the drive holds it, as the EDS declares


class PdoCheck:
    """The PDOs of the drives, checked and written back over the bring-up's transfers."""

    def __init__(self, read: Callable[[Joint, int, int, str], int],
                 write: Callable[[Joint, Parameter, ODVariable | None], None],
                 read_if_present: Callable[[Joint, int, int, str, ODVariable], int | None],
                 label: Callable[[Joint], str],
                 od: Callable[[Joint], ObjectDictionary], eds: Callable[[Joint], str],
                 configured: Callable[[Joint], frozenset[tuple[int, int]]] = (
                     lambda joint: frozenset())) -> None:
        """``write``: a write encoding as the variable given (None: the EDS's);
        ``read_if_present``: a read that gives None when the drive has no such object,
        decoding as the variable given; ``eds``: the name of a drive's EDS file;
        ``configured``: the objects (index, subindex) bring-up writes or commands the power
        stage through, which no RPDO beyond the EDS's may map."""
        self._read, self._write, self._label, self._od = read, write, label, od
        self._read_if_present, self._eds, self._configured = read_if_present, eds, configured

    def check(self, joint: Joint) -> tuple[tuple[PdoReading, ...], tuple[PdoReading, ...],
                                            tuple[ExtraPdo, ...]]:
        """Every PDO the EDS declares, read back. One that differs from the EDS (another
        tool stored its own, which reset communication restores) is written back to the
        EDS's in CiA 301's order (:meth:`_remap`) and read again; DriveFault naming the
        first object that still differs. Then every PDO beyond the EDS's that is valid is
        made not valid (:meth:`_disable_other_pdos`). Returns the PDOs as they now are (the
        EDS's, with the drive's bit 30), the readings of those written back (with the
        timers the drive held otherwise) and the PDOs made not valid."""
        slots = self._pdo_slots(joint)
        declared = [self._declared_pdo(joint, *slot) for slot in slots]
        readings = [self._read_pdo(joint, *slot, eds)
                    for slot, eds in zip(slots, declared, strict=True)]
        timers = [self._read_timers(joint, *slot) for slot in slots]
        differ = [not _same(reading, eds) or any(held != eds_value
                                                 for _, _, held, eds_value in held_timers)
                  for reading, eds, held_timers in zip(readings, declared, timers, strict=True)]
        if any(differ):
            for slot, reading, eds, held_timers, different in zip(
                    slots, readings, declared, timers, differ, strict=True):
                if different:
                    self._remap(joint, slot, reading, eds, held_timers)
            for slot, eds, held_timers in zip(slots, declared, timers, strict=True):
                self._verify(joint, slot, eds, held_timers)
        extra = self._disable_other_pdos(joint, slots)
        rewritten = tuple(
            replace(reading, timers=tuple((what, held) for _, what, held, eds_value
                                          in held_timers if held != eds_value))
            for reading, held_timers, different in zip(readings, timers, differ, strict=True)
            if different)
        return (tuple(replace(eds, cob_id=eds.cob_id | reading.cob_id & PDO_NO_RTR)
                      for eds, reading in zip(declared, readings, strict=True)),
                rewritten, extra)

    def _pdo_slots(self, joint: Joint) -> list[Slot]:
        """(name, communication index, mapping index) of each PDO the EDS declares."""
        od = self._od(joint)
        return [(f"{kind}{n + 1}", comm_base + n, map_base + n)
                for kind, comm_base, map_base in (("RPDO", 0x1400, 0x1600),
                                                  ("TPDO", TPDO_BASE, 0x1A00))
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

    def _read_timers(self, joint: Joint, name: str, comm: int, mapping: int) -> list[Timer]:
        """The inhibit time and event timer of a PDO whose EDS declares them, as held."""
        od = self._od(joint)
        return [(sub, what, self._read(joint, comm, sub, f"{name} {what}"),
                 self._default(joint, comm, sub))
                for sub, what in TIMERS if od.get_variable(comm, sub) is not None]

    def _default(self, joint: Joint, index: int, subindex: int) -> int:
        default = od_variable(self._od(joint), index, subindex).default
        if not isinstance(default, int):
            raise ConfigError(f"{self._eds(joint)}: 0x{index:04X}:{subindex} has no "
                              "integer default")
        return default

    def _declared_pdo(self, joint: Joint, name: str, comm: int, mapping: int) -> PdoReading:
        def eds(index: int, subindex: int) -> int:
            return self._default(joint, index, subindex)

        return PdoReading(name, eds(comm, 1), eds(comm, 2),
                          tuple(eds(mapping, k) for k in range(1, eds(mapping, 0) + 1)))

    def _remap(self, joint: Joint, slot: Slot, held: PdoReading, eds: PdoReading,
               timers: list[Timer]) -> None:
        """The EDS's PDO written in CiA 301's order: the COB-ID the drive holds made not
        valid (bit 31), then the EDS's CAN-ID if it differs (still not valid), whatever of
        the transmission type, inhibit time and event timer differs, the mapping if it
        differs (sub 0 = 0, the entries, sub 0 = n), the COB-ID as declared; bit 30 always
        as the drive holds it. A step the drive refuses is one DriveFault naming the PDO,
        what the drive held and the step; one the EDS declares read-only is refused
        before anything is written."""
        name, comm, mapping = slot
        no_rtr, why = held.cob_id & PDO_NO_RTR, "the EDS's PDO mapping"
        steps = [(comm, 1, "COB-ID", held.cob_id | PDO_NOT_VALID)]
        if (held.cob_id ^ eds.cob_id) & ~(PDO_NOT_VALID | PDO_NO_RTR):
            steps.append((comm, 1, "COB-ID", eds.cob_id | no_rtr | PDO_NOT_VALID))
        for sub, what, held_value, eds_value in [
                (2, "transmission type", held.transmission_type, eds.transmission_type),
                *timers]:
            if held_value != eds_value:
                self._require_writable(joint, comm, sub, f"{name} {what}", held_value)
                steps.append((comm, sub, what, eds_value))
        if held.mapped != eds.mapped:
            steps += [(mapping, 0, "number of mapped objects", 0),
                      *((mapping, k, f"mapped object {k}", entry)
                        for k, entry in enumerate(eds.mapped, start=1)),
                      (mapping, 0, "number of mapped objects", len(eds.mapped))]
        steps.append((comm, 1, "COB-ID", eds.cob_id | no_rtr))
        for index, subindex, what, value in steps:
            try:
                self._write(joint, Parameter(index, subindex, f"{name} {what}", "", value, why),
                            None)
            except DriveFault as error:
                raise DriveFault(f"{error} (writing {self._eds(joint)}'s {name} back over the "
                                 f"drive's: {_describe(held, timers)})") from error

    def _require_writable(self, joint: Joint, index: int, subindex: int, name: str,
                          held: int) -> None:
        if not od_variable(self._od(joint), index, subindex).writable:
            raise DriveFault(f"{self._label(joint)}: 0x{index:04X}:{subindex} {name} is "
                             f"{held}, {self._eds(joint)} declares "
                             f"{self._default(joint, index, subindex)} and read-only: the "
                             "hot path and the bus-load budget take the EDS's PDOs")

    def check_kept(self, joint: Joint, extra: tuple[ExtraPdo, ...], when: str,
                   cause: str) -> None:
        """Every PDO the EDS declares still the EDS's, and those made not valid still not
        valid; DriveFault naming ``when`` (before or after NMT start), the first object
        that is not and ``cause``."""
        od = self._od(joint)
        for slot in self._pdo_slots(joint):
            comm = slot[1]
            timers = [(sub, what, 0, 0) for sub, what in TIMERS
                      if od.get_variable(comm, sub) is not None]
            self._verify(joint, slot, self._declared_pdo(joint, *slot), timers,
                         f"{when}, ", cause)
        cob_id = od_variable(od, TPDO_BASE, 1)
        for pdo in extra:
            if pdo.kept:
                continue
            now = self._read_if_present(joint, pdo.index, 1, f"{pdo.name} COB-ID", cob_id)
            if now is None or not now & PDO_NOT_VALID:
                held = "no such object" if now is None else f"0x{now:X}, valid again"
                raise DriveFault(f"{self._label(joint)}: {when}, 0x{pdo.index:04X}:1 "
                                 f"{pdo.name} COB-ID is {held}: {cause}")

    def _verify(self, joint: Joint, slot: Slot, eds: PdoReading, timers: list[Timer],
                when: str = "", cause: str = "") -> None:
        """A PDO read again after the write-back (or, with ``cause``, around NMT start,
        ``when`` naming which side): every object its EDS's."""
        name, comm, mapping = slot
        checks = [(comm, 1, "COB-ID", PDO_NO_RTR), (comm, 2, "transmission type", 0),
                  *((comm, sub, what, 0) for sub, what, _, _ in timers),
                  (mapping, 0, "number of mapped objects", 0),
                  *((mapping, k, f"mapped object {k}", 0) for k in range(1, len(eds.mapped)
                                                                         + 1))]
        for index, subindex, what, ignored in checks:
            self._expect(joint, index, subindex, f"{name} {what}", ignored, when, cause)

    def _expect(self, joint: Joint, index: int, subindex: int, name: str,
                ignored: int = 0, when: str = "", cause: str = "") -> int:
        """An object read back that must hold its EDS default (but the ``ignored`` bits);
        ``cause``: why it would not, around NMT start."""
        value = self._read(joint, index, subindex, name)
        declared = self._default(joint, index, subindex)
        if (value ^ declared) & ~ignored:
            held = (f"0x{index:04X}:{subindex} {name} is 0x{value:X}, {self._eds(joint)} "
                    f"declares 0x{declared:X}")
            if cause:
                raise DriveFault(f"{self._label(joint)}: {when}{held}: {cause}")
            raise DriveFault(f"{self._label(joint)}: {held}, and the drive kept it when the "
                             "EDS's mapping was written: the hot path decodes the EDS's PDO "
                             "layout")
        return value

    def _disable_other_pdos(self, joint: Joint, slots: list[Slot]) -> tuple[ExtraPdo, ...]:
        """Every RPDO and TPDO the drive has beyond the EDS's (up to the first of each it
        does not have) that is valid made not valid: bit 31 of its COB-ID written, the
        other bits as held, and read again. A TPDO the drive keeps valid is a DriveFault
        naming it (the bus-load budget counts the EDS's frames only); an RPDO it keeps valid
        (a fixed COB-ID) is returned as kept, for ``rakectl drives`` and the daemon's log
        to name. Returns them all, as held."""
        declared = {comm for _, comm, _ in slots}
        cob_id = od_variable(self._od(joint), TPDO_BASE, 1)  # UNSIGNED32, as every COB-ID
        extra: list[ExtraPdo] = []
        for kind, base in (("RPDO", RPDO_BASE), ("TPDO", TPDO_BASE)):
            for n in range(PDO_SLOTS):
                comm, name = base + n, f"{kind}{n + 1}"
                if comm in declared:
                    continue
                what = f"{name} COB-ID"
                held = self._read_if_present(joint, comm, 1, what, cob_id)
                if held is None:
                    break
                if held & PDO_NOT_VALID:
                    continue
                kept = self._make_not_valid(joint, comm, what, held, cob_id)
                if kept and kind == "RPDO":
                    self._refuse_commanding(joint, name, comm, held, kept, slots)
                if kept and kind == "TPDO":
                    raise DriveFault(
                        f"{self._label(joint)}: {name} (0x{comm:04X}:1 COB-ID 0x{held:X}) is "
                        f"valid and {self._eds(joint)} has no such TPDO: sent beside the "
                        f"EDS's, it would break the bus-load budget (docs/can-bus.md); the "
                        f"drive keeps it valid ({kept}): make it not valid (bit 31) with the "
                        "drive's own tool and store that")
                extra.append(ExtraPdo(name, comm, held, kept))
        return tuple(extra)

    def _refuse_commanding(self, joint: Joint, name: str, comm: int, held: int, kept: str,
                           slots: list[Slot]) -> None:
        """An RPDO the drive keeps valid must map nothing the drive acts on: what the
        EDS's RPDOs map (its voltage, its controlword), what bring-up writes (its limits,
        watchdog, heartbeats) and what switches its power stage. DriveFault naming the
        first it maps, or that its mapping cannot be read."""
        acted_on = {entry >> 8 for slot in slots if slot[0].startswith("RPDO")
                    for entry in self._declared_pdo(joint, *slot).mapped}
        acted_on |= {index << 8 | subindex for index, subindex in self._configured(joint)}
        mapping = comm + 0x200
        count = self._read_if_present(joint, mapping, 0, f"{name} number of mapped objects",
                                      _variable(mapping, 0, datatypes.UNSIGNED8))
        entries = [self._read_if_present(joint, mapping, k, f"{name} mapped object {k}",
                                         _variable(mapping, k, datatypes.UNSIGNED32))
                   for k in range(1, (count or 0) + 1)]
        where = (f"{self._label(joint)}: {name} (0x{comm:04X}:1 COB-ID 0x{held:X}) is valid "
                 f"and {self._eds(joint)} has no such RPDO; the drive keeps it valid ({kept})")
        if count is None or None in entries:
            raise DriveFault(f"{where}, and its mapping 0x{mapping:04X} cannot be read: make "
                             "it not valid (bit 31) with the drive's own tool and store that")
        for entry in entries:
            if entry is not None and entry >> 8 in acted_on:
                raise DriveFault(
                    f"{where}, and it maps 0x{entry >> 16:04X}:{entry >> 8 & 0xFF}, which the "
                    f"drive acts on: a frame on 0x{held & 0x7FF:03X} would command it past "
                    "the clamp; make the RPDO not valid (bit 31) with the drive's own tool "
                    "and store that")

    def _make_not_valid(self, joint: Joint, comm: int, what: str, held: int,
                        cob_id: ODVariable) -> str:
        """Bit 31 of a COB-ID written and read again: "" if it took, else why not."""
        try:
            self._write(joint, Parameter(comm, 1, what, "", held | PDO_NOT_VALID,
                                         "a PDO beyond the EDS's"), cob_id)
        except DriveFault as error:
            code = abort_code(error)
            if not code:
                raise
            return (f"SDO abort 0x{code:08X} writing 0x{held | PDO_NOT_VALID:X}: "
                    f"{SdoAbortedError.CODES.get(code, 'unknown abort code')}")
        now = self._read_if_present(joint, comm, 1, what, cob_id)
        if now is None or not now & PDO_NOT_VALID:
            return "it reads " + ("no such object" if now is None else f"0x{now:X}") + \
                " once written not valid"
        return ""


def _same(held: PdoReading, eds: PdoReading) -> bool:
    """Whether a PDO the drive holds is the EDS's, bit 30 of its COB-ID aside."""
    return held == replace(eds, cob_id=eds.cob_id | held.cob_id & PDO_NO_RTR)


def _describe(pdo: PdoReading, timers: list[Timer]) -> str:
    """A PDO's parameters as a drive holds them (its timers where not the EDS's), in one
    phrase."""
    mapped = ", ".join(f"0x{m:08X}" if m >= 0 else "..." for m in pdo.mapped)
    held = "".join(f", {what} {value}" for _, what, value, eds in timers if value != eds)
    return (f"COB-ID 0x{pdo.cob_id:X}, transmission type {pdo.transmission_type}{held}, "
            f"mapped [{mapped}]")


def _variable(index: int, subindex: int, data_type: int) -> ODVariable:
    """An object the EDS does not have, to read as ``data_type``."""
    variable = ODVariable(f"0x{index:04X}:{subindex}", index, subindex)
    variable.data_type = data_type
    return variable
