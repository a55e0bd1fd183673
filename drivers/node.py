"""One emulated CANopen drive with an open-loop voltage mode: frames in, frames out.

A :class:`DriveNode` is the protocol side of one Roboteq/Faulhaber-class drive
(CiA 301 + CiA 402, the layouts of :mod:`rakectl.protocol.codec`, remappable in
CiA 301's order: :mod:`drivers.pdo_map`). It does no bus I/O
and reads no clock: :meth:`DriveNode.receive` takes a frame's COB-ID, data and
the time, :meth:`~DriveNode.poll` the time alone, :meth:`~DriveNode.sense` the
physics' latest sample; each returns the frames to send as ``(can_id, data)``.
``data`` is ``bytes``, or for TPDO1/TPDO2 a ``bytearray`` the node packs again
on its next call (send it, or copy it, before then). The physics reads
:attr:`~DriveNode.output_voltage_v` and :attr:`~DriveNode.motor_params`.

This module is the CiA 301 communication (NMT, SYNC, PDOs, heartbeats, SDO
requests); its base :class:`~drivers.power_stage.PowerStage` the CiA 402 state
machine, output and faults, whose base :class:`~drivers.dictionary.DriveObjects`
holds the parameters and the SDO server. The behaviour, as a drive's manual
would state it, is in docs/can-bus.md, "The emulated drives".

Bad input (wrong length, undefined values) is counted in
:attr:`DriveNode.stats` and ignored; it never raises.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

from drivers.drive_spec import DriveSpec, Frame
from drivers.pdo_map import Entry, Pdo, PdoCodec
from drivers.power_stage import EMCY_STATES, NO_FRAMES, REGISTER, PowerStage
from drivers.stats import BadInput
from rakectl.errors import FrameError
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.codec import (
    INT32_LIMIT,
    NMT_COB_ID,
    RPDO1_SIZE,
    SYNC_COB_ID,
    TPDO1_SIZE,
    TPDO2_SIZE,
    FunctionCode,
    current_a_to_ma,
    decode_rpdo,
    lost_syncs,
    pack_tpdo1_into,
    rad_per_s_to_rpm,
)
from rakectl.protocol.nmt import (
    EmcyCode,
    NmtCommand,
    NmtState,
    decode_heartbeat,
    decode_nmt,
    encode_emcy,
)

_NMT_TARGET: Final = {NmtCommand.START: NmtState.OPERATIONAL, NmtCommand.STOP: NmtState.STOPPED,
                      NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL}


class DriveNode(PowerStage):
    """One drive's CiA 301 communication over its power stage; see the module docstring."""

    FAST_PATH = True  # the EDS's PDO layouts packed by rakectl.protocol.codec's structs

    _rx_voltage_mv: int  # latest RPDO1, applied at the next SYNC if fresh
    _rx_controlword: int
    _fresh_voltage: bool
    _fresh_controlword: bool
    _last_counter: int
    _sync_length_error: bool  # in a run of SYNCs of the wrong length (one EMCY a run)

    def __init__(self, spec: DriveSpec) -> None:
        super().__init__(spec)
        self._tpdo1 = bytearray(8)
        self._handlers: dict[int, Callable[[int, bytes | bytearray, float], Sequence[Frame]]] = {
            0x700 + n: self._on_heartbeat for n in range(1, 128) if n != spec.node_id}
        self._handlers |= {SYNC_COB_ID: self._on_sync, NMT_COB_ID: self._on_nmt,
                           self._ids[FunctionCode.RPDO1]: self._on_rpdo,
                           self._ids[FunctionCode.SDO_REQUEST]: self._on_sdo}
        self._writers[(0x2000, 0)] = self._write_voltage
        self.nmt = NmtState.BOOT_UP
        self._pdo_layouts: dict[Pdo, tuple[bool, tuple[Entry, ...]]] = {}
        self._pdo_revision = -1
        self._power_on_application()
        self._power_on_communication(0.0)

    # ------------------------------------------------------------------- public

    @property
    def listens_to(self) -> frozenset[int]:
        """COB-IDs this drive handles (SYNC, NMT, its RPDO1 and SDO, heartbeats)."""
        return frozenset(self._handlers)

    def boot(self, now_s: float) -> Sequence[Frame]:
        """Power on: boot-up heartbeat, then PRE-OPERATIONAL."""
        out: list[Frame] = []
        self._reset(True, now_s, out)
        return out

    def receive(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        """Handle one received frame; frames for other nodes are ignored."""
        handler = self._handlers.get(can_id)
        if handler is None or self.nmt is NmtState.BOOT_UP:
            return NO_FRAMES
        return handler(can_id, data, now_s)

    def poll(self, now_s: float) -> Sequence[Frame]:
        """Timers: heartbeat production, heartbeat consumer, command watchdog, a fault reset
        due, TPDO2's event timer."""
        if self.nmt is NmtState.BOOT_UP:
            return NO_FRAMES
        out = list(self.heartbeat(now_s))
        seen_s, timeout_s = self._heartbeat_seen_s, (self._consumer & 0xFFFF) * 0.001
        if seen_s is not None and timeout_s and now_s - seen_s >= timeout_s:
            self._heartbeat_seen_s, self._heartbeat_lost = None, True
            self._fault(EmcyCode.HEARTBEAT_LOST, out)
        self._check_watchdog(now_s, out)
        self._complete_fault_reset(now_s, out)
        timed = self._tpdo2_timed() and now_s >= self._next_tpdo2_s
        if not self._emit_status(out) and timed:
            out.append(self._tpdo2_frame())  # its event timer: the status, changed or not
        if timed:
            self._next_tpdo2_s = now_s + self._tpdo2_event_ms * 0.001
        return out

    def heartbeat(self, now_s: float) -> Sequence[Frame]:
        """The heartbeat producer alone, if due (the checks of what was received are
        :meth:`poll`'s, once the frames that arrived have been read)."""
        if self.nmt is NmtState.BOOT_UP or not self._heartbeat_ms or now_s < self._next_heartbeat_s:
            return NO_FRAMES
        period_s = self._heartbeat_ms * 0.001
        self._next_heartbeat_s += period_s
        if self._next_heartbeat_s <= now_s:  # polled late: keep the period from now
            self._next_heartbeat_s = now_s + period_s
        return ((self._ids[FunctionCode.HEARTBEAT], bytes((self.nmt,))),)

    def next_deadline_s(self) -> float:
        """When :meth:`poll` next has work to do (inf if never)."""
        deadline = self._next_heartbeat_s if self._heartbeat_ms else math.inf
        if self._heartbeat_seen_s is not None and self._consumer & 0xFFFF:
            deadline = min(deadline, self._heartbeat_seen_s + (self._consumer & 0xFFFF) * 0.001)
        if self._watchdog_running():
            oldest_s = min(self._last_rpdo_s, self._last_sync_s)
            deadline = min(deadline, oldest_s + self._watchdog_ms * 0.001)
        if self._fault_reset_due_s is not None:
            deadline = min(deadline, self._fault_reset_due_s)
        if self._tpdo2_timed():
            deadline = min(deadline, self._next_tpdo2_s)
        return deadline

    def _watchdog_running(self) -> bool:
        """Whether the command watchdog counts now (the CiA 402 drive: while enabled)."""
        return self.state is DriveState.OPERATION_ENABLED

    def _tpdo2_timed(self) -> bool:
        """Whether TPDO2's event timer (0x1801:5) sends it now: set, TPDO2 valid, OPERATIONAL."""
        return bool(self._tpdo2_event_ms) and self._tpdo2_on and self.nmt is NmtState.OPERATIONAL

    # ------------------------------------------------------------------- frames in

    def _bad(self, kind: BadInput, can_id: int, data: bytes | bytearray) -> Sequence[Frame]:
        self.stats.bad.count(kind, can_id, data)
        return NO_FRAMES

    def takes_sync(self, data: bytes | bytearray) -> bool:
        """Whether this drive acts on a SYNC with these data (0x1019 sets its length)."""
        overflow = self._sync_overflow
        if overflow:
            return len(data) == 1 and 1 <= data[0] <= overflow
        return not data

    def _on_sync(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        overflow = self._sync_overflow
        if len(data) != (1 if overflow else 0):
            return self._sync_length_mismatch(can_id, data)
        self._sync_length_error = False
        counter = data[0] if overflow else 0
        if overflow and not 1 <= counter <= overflow:
            return self._bad(BadInput.BAD_VALUE, can_id, data)
        if self.nmt is not NmtState.OPERATIONAL:
            return NO_FRAMES
        stats = self.stats
        stats.syncs += 1
        if self._last_counter and counter:
            stats.lost_syncs += lost_syncs(self._last_counter, counter, overflow)
        self._last_counter = counter
        out = [self._sample()] if self._tpdo1_on else []
        self._complete_fault_reset(now_s, out, cycle=True)  # taken at an earlier cycle
        self._check_watchdog(now_s, out)
        self._last_sync_s = now_s
        if self._fresh_controlword:
            self._fresh_controlword = False
            self._apply_controlword(self._rx_controlword, now_s, out)
        if self._fresh_voltage:
            self._fresh_voltage = False
            self._latch(self._rx_voltage_mv, out)
        if not self._emit_status(out) and self._tpdo2_on and self._tpdo2_refresh and (
                stats.syncs % self._tpdo2_refresh == 0):
            out.append(self._tpdo2_frame())
        return out

    def _sync_length_mismatch(self, can_id: int, data: bytes | bytearray) -> Sequence[Frame]:
        """Ignored and counted; the first of a run sends EMCY 0x8240 (as CANopenNode does)."""
        self.stats.bad.count(BadInput.WRONG_LENGTH, can_id, data)
        if self._sync_length_error or self.nmt not in EMCY_STATES:
            return NO_FRAMES
        self._sync_length_error = True
        code = EmcyCode.SYNC_DATA_LENGTH
        self.record_error(code)
        self.stats.emcys += 1
        return [(self._ids[FunctionCode.EMCY],
                 encode_emcy(code, self._register() | REGISTER[code]))]

    def _on_rpdo(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        if self.nmt is not NmtState.OPERATIONAL or not self._rpdo1_on:
            self.stats.rpdos_ignored += 1  # (not valid: as if not received)
            return NO_FRAMES
        codec = self._rpdo1_codec
        if len(data) != (RPDO1_SIZE if codec is None else codec.size):
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        if codec is None:  # the EDS's layout
            self._rx_voltage_mv, self._rx_controlword = decode_rpdo(data)
            self._fresh_voltage = self._fresh_controlword = True
        else:
            for (index, subindex), value in zip(codec.entries, codec.unpack(data), strict=True):
                self._take_rpdo(index, subindex, value)
        self._last_rpdo_s = now_s
        self.stats.rpdos += 1
        return NO_FRAMES

    def _take_rpdo(self, index: int, subindex: int, value: int) -> None:
        """One object of a remapped RPDO1 (its mapping admits only what the drive acts on)."""
        if index == 0x2000:
            self._rx_voltage_mv, self._fresh_voltage = value, True
        elif index == 0x6040:
            self._rx_controlword, self._fresh_controlword = value, True

    def _on_nmt(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        if len(data) != 2:
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        try:
            command, target = decode_nmt(data)
        except FrameError:
            return self._bad(BadInput.BAD_VALUE, can_id, data)
        if target not in (0, self.node_id):
            return NO_FRAMES
        out: list[Frame] = []
        if command in _NMT_TARGET:
            before = self.nmt
            self._set_nmt(_NMT_TARGET[command])
            if self.nmt is not before and self._heartbeat_ms:  # as CANopenNode: at once,
                out.append((self._ids[FunctionCode.HEARTBEAT], bytes((self.nmt,))))  # and
                self._next_heartbeat_s = now_s + self._heartbeat_ms * 0.001  # the period anew
        else:
            self._reset(command is NmtCommand.RESET_NODE, now_s, out)
        self._emit_status(out)
        return out

    def _on_heartbeat(self, can_id: int, data: bytes | bytearray, now_s: float
                      ) -> Sequence[Frame]:
        if can_id - 0x700 != (self._consumer >> 16) & 0x7F:
            return NO_FRAMES  # a producer this drive does not monitor
        if len(data) != 1:
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        try:
            decode_heartbeat(data)
        except FrameError:
            return self._bad(BadInput.BAD_VALUE, can_id, data)
        self._heartbeat_seen_s, self._heartbeat_lost = now_s, False
        return NO_FRAMES

    def _on_sdo(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        if len(data) != 8:
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        if self.nmt not in EMCY_STATES:
            return NO_FRAMES
        self.stats.sdo_requests += 1
        out: list[Frame] = []
        if not self._serve_sdo(can_id, data, now_s, out):
            self.stats.bad.count(BadInput.BAD_VALUE, can_id, data)
        if self._pdo_revision != self.pdos.revision:
            self._sync_pdos()
        self._emit_status(out)
        return out

    # ------------------------------------------------------------------- behaviour

    def _sample(self) -> Frame:
        codec = self._tpdo1_codec
        if codec is None:  # the EDS's layout
            counts = round(self._position / self._resolution)
            counts = max(-INT32_LIMIT, min(INT32_LIMIT, counts))
            pack_tpdo1_into(self._tpdo1, counts, rad_per_s_to_rpm(self._motor_vel),
                            current_a_to_ma(self._current_a))
        else:
            codec.pack_into(self._tpdo1, [self._value(*entry) for entry in codec.entries])
        return self._ids[FunctionCode.TPDO1], self._tpdo1

    def _tpdo2_frame(self) -> Frame:
        codec = self._tpdo2_codec
        if codec is None:  # the EDS's layout
            return super()._tpdo2_frame()
        codec.pack_into(self._tpdo2, [self._value(*entry) for entry in codec.entries])
        return self._ids[FunctionCode.TPDO2], self._tpdo2

    def _value(self, index: int, subindex: int) -> int:
        reader = self._readers.get((index, subindex))
        return reader() if reader is not None else self._eds_default(index, subindex)

    def _sync_pdos(self) -> None:
        """The PDOs' layouts and validity compiled again, after an SDO write changed them or
        a reset restored them (:mod:`drivers.pdo_map`); the EDS's layouts keep the codec
        module's. A TPDO2 changed goes out at its next chance (as CANopenNode sends a TPDO
        that became valid); an RPDO1 changed drops the voltage it carried to 0 V (nothing
        in the new layout has set one)."""
        pdos, od = self.pdos, self._od.object_dictionary
        self._pdo_revision = pdos.revision
        layouts = {pdo: (pdos.valid(pdo), pdos.layout(pdo)) for pdo in Pdo}
        old, self._pdo_layouts = self._pdo_layouts, layouts
        if layouts == old:
            return
        if old and layouts[Pdo.TPDO2] != old[Pdo.TPDO2]:
            self._statusword = -1
        if old and layouts[Pdo.RPDO1] != old[Pdo.RPDO1]:
            self._rx_voltage_mv, self._fresh_voltage = 0, False
            if self._latched_mv:
                self._latched_mv = 0
                self._update_output()
        fast = self.FAST_PATH
        codecs = {pdo: None if (fast and pdos.is_default(pdo)) or not pdos.layout(pdo)
                  else PdoCodec(od, pdos.layout(pdo)) for pdo in Pdo}
        self._tpdo1_codec, self._tpdo2_codec = codecs[Pdo.TPDO1], codecs[Pdo.TPDO2]
        self._rpdo1_codec = codecs[Pdo.RPDO1]
        for codec, attribute in ((codecs[Pdo.TPDO1], "_tpdo1"), (codecs[Pdo.TPDO2], "_tpdo2")):
            if codec is not None:
                setattr(self, attribute, bytearray(codec.size))
            elif attribute == "_tpdo1":
                self._tpdo1 = bytearray(TPDO1_SIZE)
            else:
                self._tpdo2 = bytearray(TPDO2_SIZE)
        on = {pdo: valid and bool(layout) for pdo, (valid, layout) in layouts.items()}
        self._tpdo1_on, self._tpdo2_on, self._rpdo1_on = on[Pdo.TPDO1], on[Pdo.TPDO2], on[Pdo.RPDO1]

    def _set_nmt(self, state: NmtState) -> None:
        if state is self.nmt:
            return
        if self.nmt is NmtState.OPERATIONAL:
            self._latched_mv, self._fresh_voltage, self._fresh_controlword = 0, False, False
            self._update_output()
        if state is NmtState.OPERATIONAL:
            self._statusword = -1  # TPDO2 goes out on entering OPERATIONAL
        self.nmt = state
        self.notes.append(("nmt_state", state))

    def _reset(self, application: bool, now_s: float, out: list[Frame]) -> None:
        if application:
            self._power_on_application()
        self._power_on_communication(now_s)
        out.append((self._ids[FunctionCode.HEARTBEAT], bytes((NmtState.BOOT_UP,))))
        self._set_nmt(NmtState.PRE_OPERATIONAL)

    # ------------------------------------------------------------------- power-on values

    def _power_on_application(self) -> None:
        self._power_on_stage()
        self._rx_voltage_mv = self._rx_controlword = 0
        self._fresh_voltage = self._fresh_controlword = False

    def _power_on_communication(self, now_s: float) -> None:
        self._restore_communication(now_s)
        self._last_counter, self._sync_length_error = 0, False
        self._sync_pdos()

    def _write_voltage(self, value: int) -> None:
        self._rx_voltage_mv, self._fresh_voltage = value, True  # latched at the next SYNC
