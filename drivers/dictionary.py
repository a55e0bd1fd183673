"""An emulated drive's object dictionary: its identity, its parameters and the SDO server.

:class:`DriveObjects` holds the parameters a drive acts on (heartbeat producer
0x1017 and consumer 0x1016, SYNC counter overflow 0x1019, maximum voltage
0x2001, current limit 0x2002, command watchdog 0x2003, encoder resolution
0x2004, TPDO2 refresh 0x2005), their power-on values bounded by the
hardware, and serves them over SDO. The protocol behaviour (NMT, SYNC, PDOs,
CiA 402, faults) is its subclass :class:`drivers.node.DriveNode`, which adds
the live objects (0x6041, 0x6064 …).

SDO. canopen's ``LocalNode`` over the drive type's EDS is the SDO server: the
drive passes each 8-byte request to ``Network.notify`` of a never-connected
``canopen.Network`` whose ``send_message`` (the override point canopen
documents) collects the response into the frames returned. LocalNode's own NMT
slave is left out (it would start a heartbeat thread when 0x1017 is written).
Live objects are served by a read callback; a write callback checks the EDS's
LowLimit/HighLimit and the drive's own bounds and rejects a write by raising
``SdoAbortedError`` (canopen answers with that abort code and stores
nothing): 0x2001 ≤ the supply, 0x2002 in 1 … the hardware current limit and
0x2004 only while not OPERATION_ENABLED (0x08000022), 0x6060 only −1,
0x1019 (SYNC counter overflow: 0 = no counter, 2 … 240) only outside
OPERATIONAL and only while the communication cycle period 0x1006 is 0
(0x08000022, as CiA 301 and CANopenNode have it; 1 or above 240: 0x06090030).
0x1003, the pre-defined error field, holds the last 8 EMCY error codes, newest at
sub 1; an entry beyond sub 0's count answers 0x08000024, and writing 0 to sub 0
clears it (any other value: 0x06090030); reset communication clears it too. The
PDOs' event timers (sub 5) take any value (TPDO2's sends it every that many ms;
TPDO1 is synchronous and, as CiA 301 has it, ignores it); the transmission types
and inhibit times are read-only in the EDS. A writable object the drive does not
act on (0x1005, the COB-ID of SYNC) is fixed: writing its present value succeeds,
any other value aborts. The PDOs' COB-IDs and mappings are remappable in CiA 301's
order (:mod:`drivers.pdo_map`); a drive whose TPDOs answer no RTR
(``DriveSpec.tpdo_rtr`` False) reports their COB-IDs with bit 30 set and refuses a
COB-ID that clears it (0x06090030). Identity 0x1018: product code from the EDS,
serial number from the configuration.

Reset communication restores 0x1000–0x1FFF to the EDS's values, or to those
``DriveSpec.stored`` gives (what another tool stored in the drive: a producer
heartbeat 0x1017 of 0, CiA 301's default, or an event timer).
"""

from __future__ import annotations

import dataclasses
import struct
from collections.abc import Callable
from typing import Any, Final

import canopen
from canopen import SdoAbortedError

from drivers.drive_spec import DriveSpec, Frame, SdoAbort
from drivers.pdo_map import Pdo, PdoMaps
from rakectl.core.motor_model import MotorParams, joint_resolution
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.codec import SYNC_COUNTER_MAX, FunctionCode, cob_id
from rakectl.protocol.nmt import NmtState

Reader = Callable[[], int]
Writer = Callable[[int], None]
ERROR_HISTORY: Final = 8  # entries of 0x1003 (its EDS has sub 1 … 8)
MAX_COUNTS_PER_REV: Final = 10**9  # MotorParams' bound on encoder_counts_per_rev
_COMM_RANGE: Final = range(0x1000, 0x2000)
_SDO_ABORT: Final = struct.Struct("<BHBL")  # command 0x80, index, subindex, abort code
_SEGMENT_OF: Final = {0x60: "upload", 0x00: "download"}  # segment requests' ccs (CiA 301)


def _segmented_after(ccs: int, request: int, answer: int) -> str | None:
    """The segmented transfer open after a request (its client command specifier ``ccs``,
    its first byte) and the server's answer (first byte): an initiation not expedited
    opens one, a segment keeps it open until the last one (bit 0), an abort either way
    ends it."""
    if answer & 0xE0 == 0x80 or ccs == 0x80:
        return None
    if ccs in (0x40, 0xA0):  # initiate upload (a block upload is answered as one): segmented
        # unless the answer is expedited (bit 1)
        return None if answer & 0x02 else "upload"
    if ccs == 0x20:  # initiate download: segmented unless the request is expedited
        return None if request & 0x02 else "download"
    if ccs == 0x60:  # upload segment: the answer's bit 0 says it was the last
        return None if answer & 0x01 else "upload"
    if ccs == 0x00:
        return None if request & 0x01 else "download"
    return None
COB_ID_NO_RTR: Final = 1 << 30  # bit 30 of a PDO's COB-ID: no RTR answered
_TPDO_COB_IDS: Final = frozenset((p.comm_index, 1) for p in Pdo if p.value[2])


class _Outbox(canopen.Network):
    """A canopen Network that is never connected: what its nodes send is collected."""

    def __init__(self) -> None:
        super().__init__()
        self.frames: list[Frame] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.frames.append((can_id, bytes(data)))


class _SdoServerNode(canopen.LocalNode):
    """LocalNode without its NMT slave's 0x1017 callback (that one starts a thread)."""

    def add_write_callback(self, callback: Callable[..., None]) -> None:
        if callback != self.nmt.on_write:
            super().add_write_callback(callback)  # type: ignore[no-untyped-call]


class DriveObjects:
    """A drive's parameters and its SDO server; see the module docstring."""

    state: DriveState  # CiA 402, owned by the subclass (some writes need it disabled)
    nmt: NmtState  # owned by the subclass (0x1019 is written in PRE-OPERATIONAL)
    motor_params: MotorParams  # the hardware with the current limit of 0x2002
    _heartbeat_ms: int
    _next_heartbeat_s: float
    _consumer: int  # 0x1016 sub 1
    _heartbeat_seen_s: float | None  # last controller heartbeat; None = not monitoring
    _heartbeat_lost: bool
    _max_voltage_mv: int
    _current_limit_ma: int
    _watchdog_ms: int
    _counts_per_rev: int
    _resolution: float
    _tpdo2_refresh: int
    _sync_overflow: int  # 0x1019: 0 = SYNC without counter, else the counter's top
    _cycle_period_us: int  # 0x1006: 0x1019 changes only while it is 0
    _tpdo2_event_ms: int  # 0x1801:5, TPDO2's event timer: 0 = none
    _next_tpdo2_s: float  # when the event timer next sends TPDO2
    _errors: list[int]  # 0x1003 pre-defined error field: newest first, at most 8

    def __init__(self, spec: DriveSpec) -> None:
        self.spec, self.node_id = spec, spec.node_id
        self._segmented: str | None = None  # the segmented transfer open: upload, download
        self._network = _Outbox()
        self._od = _SdoServerNode(spec.node_id, str(spec.kind.eds_path))
        self._network.add_node(self._od)
        self.pdos = PdoMaps(self._od.object_dictionary, spec.kind.parameters.rx)
        self._od.add_read_callback(self._od_read)  # type: ignore[no-untyped-call]
        self._od.add_write_callback(self._od_write)
        self._sdo_response_id = cob_id(FunctionCode.SDO_RESPONSE, spec.node_id)
        self._power_on = self._power_on_values()
        self._readers, self._writers = self._parameter_objects()
        self._now_s: float = 0.0  # context of the SDO write callbacks
        self._out: list[Frame] = []

    def _serve_sdo(self, can_id: int, data: bytes | bytearray, now_s: float,
                   out: list[Frame]) -> bool:
        """Answer one SDO request into ``out``; False if it is a segment of no segmented
        transfer open (canopen's server would take it for one, or log a traceback and
        answer an abort naming the object of an earlier transfer): an abort 0x05040001
        is answered instead, naming no object."""
        self._now_s, self._out = now_s, out  # context of the write callbacks
        network, ccs = self._network, data[0] & 0xE0
        if ccs in _SEGMENT_OF and self._segmented != _SEGMENT_OF[ccs]:
            abort = _SDO_ABORT.pack(0x80, 0, 0, SdoAbort.UNKNOWN_COMMAND)
            out.append((self._sdo_response_id, abort))
            return False
        served = True
        try:
            network.notify(can_id, bytearray(data), now_s)
        except Exception:  # canopen's server raises aborting a request it cannot name
            network.frames.clear()  # (no transfer before it: its index is None)
            network.frames.append((self._sdo_response_id, _SDO_ABORT.pack(
                0x80, 0, 0, SdoAbort.UNKNOWN_COMMAND)))
            served = False
        answer = network.frames[-1][1] if network.frames else b"\x80"
        self._segmented = _segmented_after(ccs, data[0], answer[0])
        out += network.frames
        network.frames.clear()
        return served

    # ------------------------------------------------------------------- power-on values

    def _eds_default(self, index: int, subindex: int = 0) -> int:
        entry: Any = self._od.object_dictionary[index]
        return int((entry[subindex] if subindex else entry).default)

    def _power_on_values(self) -> dict[str, int]:
        """Power-on values of the objects the drive acts on, bounded by its hardware (the
        current limit in mA, whatever the drive type's unit)."""
        motor, default, at = self.spec.motor, self._eds_default, self.spec.kind.parameters
        supply_mv = round(motor.supply_voltage_v * 1000)
        return {
            "consumer": default(0x1016, 1) & 0xFFFF | self.spec.controller_node_id << 16,
            "heartbeat_ms": default(0x1017), "sync_overflow": default(0x1019),
            "cycle_period_us": default(0x1006), "tpdo2_event_ms": default(0x1801, 5),
            "max_voltage_mv": supply_mv if at.max_voltage is None
            else min(default(*at.max_voltage), supply_mv),
            "current_limit_ma": min(default(*at.current_limit) * at.current_unit_ma,
                                    self._hardware_limit_ma()),
            "watchdog_ms": default(*at.watchdog), "counts_per_rev": motor.encoder_counts_per_rev,
            "tpdo2_refresh": default(*at.tpdo2_refresh),
        }

    def _hardware_limit_ma(self) -> int:
        return round(self.spec.motor.current_limit_a * 1000)

    def _restore_parameters(self) -> None:
        """Every object to its power-on value (NMT reset node)."""
        values = self._power_on
        self._od.data_store.clear()
        self._max_voltage_mv, self._watchdog_ms = values["max_voltage_mv"], values["watchdog_ms"]
        self._tpdo2_refresh = values["tpdo2_refresh"]
        self._set_current_limit_ma(values["current_limit_ma"])
        self._set_counts_per_rev(values["counts_per_rev"])

    def _restore_communication(self, now_s: float) -> None:
        """0x1000–0x1FFF to their power-on values (NMT reset communication)."""
        for index in [i for i in self._od.data_store if i in _COMM_RANGE]:
            del self._od.data_store[index]
        power_on = self._power_on
        self._heartbeat_ms, self._consumer = power_on["heartbeat_ms"], power_on["consumer"]
        self._sync_overflow = power_on["sync_overflow"]
        self._cycle_period_us, self._tpdo2_event_ms = (power_on["cycle_period_us"],
                                                      power_on["tpdo2_event_ms"])
        self._errors = []
        self.pdos.restore()
        for index, subindex, value in self.spec.stored:  # through the SDO server's checks
            variable: Any = self._od.object_dictionary.get_variable(index, subindex)
            self._od.set_data(index, subindex, variable.encode_raw(value))
        self._next_heartbeat_s = now_s + self._heartbeat_ms * 0.001
        self._next_tpdo2_s = now_s + self._tpdo2_event_ms * 0.001
        self._heartbeat_seen_s = None
        self._heartbeat_lost = False

    def _set_current_limit_ma(self, limit_ma: int) -> None:
        self._current_limit_ma = limit_ma
        limit_a = min(limit_ma, self._hardware_limit_ma()) * 0.001
        self.motor_params = dataclasses.replace(self.spec.motor, current_limit_a=limit_a)

    def _set_counts_per_rev(self, counts: int) -> None:
        self._counts_per_rev = counts
        motor = dataclasses.replace(self.spec.motor, encoder_counts_per_rev=counts)
        self._resolution = joint_resolution(motor)

    # ------------------------------------------------------------------- SDO callbacks

    def _parameter_objects(self) -> tuple[dict[tuple[int, int], Reader],
                                          dict[tuple[int, int], Writer]]:
        at = self.spec.kind.parameters
        readers: dict[tuple[int, int], Reader] = {
            (0x1016, 1): lambda: self._consumer,
            (0x1017, 0): lambda: self._heartbeat_ms,
            (0x1019, 0): lambda: self._sync_overflow,
            (0x1006, 0): lambda: self._cycle_period_us,
            (0x1801, 5): lambda: self._tpdo2_event_ms,
            (0x1003, 0): lambda: len(self._errors),
            **{(0x1003, k): self._error_entry(k) for k in range(1, ERROR_HISTORY + 1)},
            (0x1018, 4): lambda: self.spec.serial_number,
            at.current_limit: lambda: self._current_limit_ma // at.current_unit_ma,
            at.watchdog: lambda: self._watchdog_ms,
            at.counts_per_rev: lambda: self._counts_per_rev,
            at.tpdo2_refresh: lambda: self._tpdo2_refresh,
        }
        if at.max_voltage is not None:
            readers[at.max_voltage] = lambda: self._max_voltage_mv
        writers: dict[tuple[int, int], Writer] = {
            (0x1006, 0): self._write_cycle_period,
            (0x1800, 5): lambda value: None,  # TPDO1's event timer: synchronous, unused
            (0x1801, 5): self._write_tpdo2_event_timer,
            (0x6060, 0): lambda value: None,  # the EDS limits it to −1
            (0x1016, 1): self._write_consumer,
            (0x1017, 0): self._write_heartbeat_period,
            (0x1019, 0): self._write_sync_overflow,
            (0x1003, 0): self._clear_errors,
            at.current_limit: lambda value: self._write_current_limit(value * at.current_unit_ma),
            at.watchdog: self._write_watchdog,
            at.counts_per_rev: self._write_counts_per_rev,
            at.tpdo2_refresh: self._write_tpdo2_refresh,
        }
        return readers, writers

    def _od_read(self, index: int, subindex: int, od: Any, **_: Any) -> int | None:
        reader = self._readers.get((index, subindex))
        if reader is not None:
            return reader()
        value = self.pdos.read(index, subindex) if self.pdos.owns(index) else None
        if value is not None and not self.spec.tpdo_rtr and (index, subindex) in _TPDO_COB_IDS:
            return value | COB_ID_NO_RTR
        return value

    def _od_write(self, index: int, subindex: int, od: Any, data: bytes, **_: Any) -> None:
        value = od.decode_raw(data)
        if not isinstance(value, int):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)
        if od.min is not None and value < od.min:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        writer = self._writers.get((index, subindex))
        if not self.spec.tpdo_rtr and (index, subindex) in _TPDO_COB_IDS and (
                not value & COB_ID_NO_RTR):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)  # it answers no RTR: bit 30 stays set
        if writer is not None:
            writer(value)
        elif self.pdos.owns(index) and self.pdos.write(index, subindex, value):
            return
        elif value != od.decode_raw(self._od.get_data(index, subindex)):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)  # fixed in this drive

    def record_error(self, code: int) -> None:
        """An EMCY error code into the history 0x1003 (newest at sub 1)."""
        self._errors.insert(0, code & 0xFFFF)
        del self._errors[ERROR_HISTORY:]

    def _error_entry(self, subindex: int) -> Reader:
        def read() -> int:
            if subindex > len(self._errors):
                raise SdoAbortedError(SdoAbort.NO_DATA)
            return self._errors[subindex - 1]
        return read

    def _clear_errors(self, value: int) -> None:
        if value != 0:  # CiA 301: only 0 may be written, and it clears the history
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)
        self._errors.clear()

    def _require_not_enabled(self) -> None:
        if self.state is DriveState.OPERATION_ENABLED:
            raise SdoAbortedError(SdoAbort.DEVICE_STATE)

    def _write_consumer(self, value: int) -> None:
        self._consumer, self._heartbeat_seen_s, self._heartbeat_lost = value, None, False

    def _write_heartbeat_period(self, value: int) -> None:
        self._heartbeat_ms, self._next_heartbeat_s = value, self._now_s + value * 0.001

    def _write_sync_overflow(self, value: int) -> None:
        if self.nmt is NmtState.OPERATIONAL:  # CiA 301: not while SYNCs are consumed
            raise SdoAbortedError(SdoAbort.DEVICE_STATE)
        if value == 1 or value > SYNC_COUNTER_MAX:
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)
        if self._cycle_period_us:  # CiA 301 (CANopenNode's OD_write_1019): only while 0x1006 = 0
            raise SdoAbortedError(SdoAbort.DEVICE_STATE)
        self._sync_overflow = value

    def _write_current_limit(self, value: int) -> None:
        self._require_not_enabled()
        if value > self._hardware_limit_ma():
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        if value < 1:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_LOW)
        self._set_current_limit_ma(value)

    def _write_watchdog(self, value: int) -> None:
        self._watchdog_ms = value

    def _write_counts_per_rev(self, value: int) -> None:
        self._require_not_enabled()
        if value > MAX_COUNTS_PER_REV:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        self._set_counts_per_rev(value)

    def _write_tpdo2_refresh(self, value: int) -> None:
        self._tpdo2_refresh = value

    def _write_cycle_period(self, value: int) -> None:
        self._cycle_period_us = value  # informative otherwise: the SYNCs are not timed

    def _write_tpdo2_event_timer(self, value: int) -> None:
        self._tpdo2_event_ms, self._next_tpdo2_s = value, self._now_s + value * 0.001
