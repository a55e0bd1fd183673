"""The SDO transfers of the drives' bring-up (rakectl.drive.bringup), one line per
failure.

Each transfer names the drive and the object when it fails: an abort as
``DriveFault("r drive (node 1): SDO abort 0x06090030 writing 0x2003 watchdog timeout =
3 ms: Value range of parameter exceeded")`` (raised ``from`` the canopen error), an
answer shorter than the object's type or an SDO frame too short to decode as a
DriveFault too, ``CommsTimeout`` when no answer comes, ``BusError`` when the bus refuses
a frame. A transfer that meets an answer of another kind is made again, twice at most:
canopen empties its answer queue only before it sends, so the late answer to a request
it had repeated is otherwise taken for the next request's (``Unexpected response
0x60``: a download's answer to a reading of the same object); a segmented upload that
lost a segment is started again. An answer that names another object than the one
asked (an abort, an upload's or a download's first answer: they carry the index) is
not taken as the transfer's (:class:`AnswerGate`): a late abort of an object asked
before, or another SDO client's answer on the drive's channel, would otherwise
refuse a healthy drive naming the wrong object and cause, or acknowledge a write
the drive never took. Left without its own answer, the transfer's ``CommsTimeout``
names what came instead.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TypeVar

import can
import canopen
from canopen.objectdictionary import ObjectDictionaryError, ODVariable, datatypes
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from rakectl.drive.canbus import BusError
from rakectl.drive.joints import Joint, Parameter, od_variable
from rakectl.errors import CommsTimeout, DriveFault

_T = TypeVar("_T")
SDO_RETRIES = 6  # canopen sends an unanswered SDO request this often in all at bring-up
# (on a bus losing 5 % each way, 1 exchange in 10 fails: 6 tries fail 1 transfer in a
# million, 3 failed 1 bring-up of ~160 transfers in 7), and a segmented upload that lost a
# segment is started again this often
SDO_TOGGLE_BIT_ABORT = 0x05030000  # a segment lost or repeated
SDO_NO_OBJECT_ABORTS = (0x06020000, 0x06090011)  # no such object, no such subindex
SDO_LATE_ANSWER_RETRIES = 2  # a transfer that met a late answer is made again this often
_TYPE_NAMES = {code: name for name, code in vars(datatypes).items()
               if name.isupper() and isinstance(code, int)}


class AnswerGate:
    """Between the network and one drive's ``canopen`` SDO client: while a transfer of
    ``expected`` (index, subindex) runs, an answer naming another object is kept from
    the client and described in ``ignored``. Segments carry no index and pass."""

    def __init__(self, client: SdoClient) -> None:
        self._client = client
        self._forward: Callable[[int, bytearray, float], None] = client.on_response
        self.expected: tuple[int, int] | None = None
        self.ignored: list[str] = []

    def install(self) -> None:
        """In place of the client's own subscription to the drive's SDO answers."""
        network, cob_id = self._client.network, self._client.tx_cobid
        network.unsubscribe(cob_id, self._client.on_response)
        network.subscribe(cob_id, self.on_response)

    def remove(self) -> None:
        """The client's own subscription back (canopen removes that one with the node)."""
        network, cob_id = self._client.network, self._client.tx_cobid
        network.unsubscribe(cob_id, self.on_response)
        network.subscribe(cob_id, self._client.on_response)

    def on_response(self, can_id: int, data: bytearray, timestamp: float) -> None:
        expected = self.expected  # the notifier's thread; set by the bring-up's
        if expected is not None and len(data) >= 4 and data[0] & 0xE0 in _INDEXED:
            named = (data[1] | data[2] << 8, data[3])
            if named != expected:
                kind = (f"abort 0x{int.from_bytes(data[4:8], 'little'):08X}"
                        if data[0] & 0xE0 == 0x80 else _INDEXED[data[0] & 0xE0])
                self.ignored.append(f"{kind} for 0x{named[0]:04X}:{named[1]}")
                return
        self._forward(can_id, data, timestamp)


_INDEXED = {0x40: "upload answer", 0x60: "download answer", 0x80: "abort"}  # by their
# server command specifier (CiA 301): the answers that name the object


class DriveSdo:
    """Reads and writes of the drives' objects over their ``canopen.RemoteNode``s."""

    def __init__(self, nodes: dict[Joint, canopen.RemoteNode], label: Callable[[Joint], str],
                 timeout_s: float) -> None:
        """``nodes``: on their network already (an :class:`AnswerGate` each is installed
        here, and removed by :meth:`close`); ``label``: a drive's name in messages;
        ``timeout_s``: the SDO answer timeout, for the message."""
        self._nodes, self._label, self._timeout_s = nodes, label, timeout_s
        self._gates = {joint: AnswerGate(node.sdo) for joint, node in nodes.items()}
        for gate in self._gates.values():
            gate.install()

    def close(self) -> None:
        """Each drive's SDO answers to its client again, ungated."""
        for gate in self._gates.values():
            gate.remove()

    def read_text(self, joint: Joint, index: int, subindex: int, name: str) -> str:
        """A segmented upload, started again when a segment was lost (``_repeatable``)."""
        node = self._nodes[joint]
        what = f"reading 0x{index:04X}:{subindex} {name}"
        data = self._transfer(joint, (index, subindex), what,
                              lambda: node.sdo.upload(index, subindex), segmented=True)
        return bytes(data).decode("ascii", errors="replace").rstrip("\0")

    def read(self, joint: Joint, index: int, subindex: int, name: str,
             variable: ODVariable | None = None) -> int:
        """An integer object, decoded as the EDS declares it (or as ``variable``, for an
        object the EDS does not have)."""
        node = self._nodes[joint]
        what = f"reading 0x{index:04X}:{subindex} {name}"
        data = self._transfer(joint, (index, subindex), what,
                              lambda: node.sdo.upload(index, subindex))
        var = od_variable(node.object_dictionary, index, subindex) if variable is None \
            else variable
        try:
            value = var.decode_raw(data)
        except ObjectDictionaryError as error:  # an answer shorter than the type
            type_name = _TYPE_NAMES.get(var.data_type or 0, "data type")
            raise DriveFault(f"{self._label(joint)}: {what}: the drive answered {len(data)} "
                             f"byte(s), the EDS's {type_name} takes {len(var) // 8}") from error
        if not isinstance(value, int):
            raise DriveFault(f"{self._label(joint)}: {what}: not an integer: {value!r}")
        return value

    def read_if_present(self, joint: Joint, index: int, subindex: int, name: str,
                        variable: ODVariable | None = None) -> int | None:
        """:meth:`read` of an object a drive may lack: None if it answers that it has no
        such object or subindex."""
        try:
            return self.read(joint, index, subindex, name, variable)
        except DriveFault as error:
            if no_such_object(error):
                return None
            raise

    def write(self, joint: Joint, p: Parameter, variable: ODVariable | None = None) -> None:
        """``p`` written, encoded as the EDS declares it (or as ``variable``, for an object
        the EDS does not have)."""
        node = self._nodes[joint]
        var = od_variable(node.object_dictionary, p.index, p.subindex) if variable is None \
            else variable
        data = var.encode_raw(p.value)
        what = f"writing {p.where()} {p.name} = {p.value}{' ' + p.unit if p.unit else ''}"
        self._transfer(joint, (p.index, p.subindex), what,
                       lambda: node.sdo.download(p.index, p.subindex, data))

    def _transfer(self, joint: Joint, obj: tuple[int, int], what: str,
                  transfer: Callable[[], _T], segmented: bool = False) -> _T:
        """One transfer of ``obj`` (an upload, or a download of a value: either may be made
        again), gated to its answers, made again while its failure is ``_repeatable``, up
        to ``SDO_RETRIES`` more times for a segmented one, ``SDO_LATE_ANSWER_RETRIES``
        otherwise; its failure as one line naming the drive and the object."""
        gate = self._gates[joint]
        gate.expected, gate.ignored = obj, []
        try:
            return self._attempts(joint, what, transfer, segmented, gate)
        finally:
            gate.expected = None

    def _attempts(self, joint: Joint, what: str, transfer: Callable[[], _T], segmented: bool,
                  gate: AnswerGate) -> _T:
        label = self._label(joint)
        retries = SDO_RETRIES if segmented else SDO_LATE_ANSWER_RETRIES
        for attempt in range(retries + 1):
            try:
                return transfer()
            except SdoAbortedError as error:
                if attempt < retries and _repeatable(error, segmented):
                    continue
                text = SdoAbortedError.CODES.get(error.code, "unknown abort code")
                raise DriveFault(f"{label}: SDO abort 0x{error.code:08X} {what}: "
                                 f"{text}") from error
            except SdoCommunicationError as error:
                if attempt < retries and _repeatable(error, segmented):
                    continue
                if "No SDO response" in str(error):
                    came = (f" (ignored, naming other objects: {', '.join(gate.ignored[:3])}"
                            f"{', …' if len(gate.ignored) > 3 else ''})" if gate.ignored
                            else "")
                    raise CommsTimeout(f"{label}: no SDO response {what} within "
                                       f"{self._timeout_s:g} s{came}") from error
                raise DriveFault(f"{label}: SDO error {what}: {error}") from error
            except can.CanError as error:
                raise BusError(f"{label}: bus error {what}: {error}") from error
            except struct.error as error:  # canopen unpacks a frame shorter than 8 bytes
                raise DriveFault(f"{label}: SDO answer {what} shorter than CiA 301's 8 bytes: "
                                 f"{error}") from error
        raise AssertionError("unreachable: the last attempt returns or raises")


def abort_code(error: DriveFault) -> int:
    """The SDO abort code ``error`` was raised from; 0 if none."""
    cause = error.__cause__
    return cause.code if isinstance(cause, SdoAbortedError) else 0


def no_such_object(error: DriveFault) -> bool:
    """Whether ``error`` is an SDO abort saying the drive has no such object or subindex."""
    return abort_code(error) in SDO_NO_OBJECT_ABORTS


def _repeatable(error: SdoAbortedError | SdoCommunicationError, segmented: bool) -> bool:
    """Whether a failed transfer is worth making again: any transfer that met an answer of
    another kind (canopen empties its answer queue only before it sends, so the late answer
    to a request it had repeated is taken for the next request's); a segmented upload whose
    segment was lost (a toggle-bit abort, no answer, a toggle mismatch). An answer of another
    kind reads ``Unexpected response 0x60`` (a download's answer) or ``Node returned a value
    for 0x1018:01 instead`` (an upload's answer for the object asked before)."""
    if isinstance(error, SdoAbortedError):
        return segmented and error.code == SDO_TOGGLE_BIT_ABORT
    return segmented or str(error).startswith(("Unexpected response", "Node returned a value"))
