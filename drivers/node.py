"""One emulated CANopen drive with an open-loop voltage mode: frames in, frames out.

A :class:`DriveNode` is the protocol side of one Roboteq/Faulhaber-class drive
(CiA 301 + CiA 402, the layouts of :mod:`rakectl.protocol.codec`). It does no bus I/O
and reads no clock: :meth:`DriveNode.receive` takes a frame's COB-ID, data and
the time, :meth:`~DriveNode.poll` the time alone, :meth:`~DriveNode.sense` the
physics' latest sample; each returns the frames to send as ``(can_id, data)``.
``data`` is ``bytes``, or for TPDO1/TPDO2 a ``bytearray`` the node packs again
on its next call (send it, or copy it, before then). The physics reads
:attr:`~DriveNode.output_voltage_v` and :attr:`~DriveNode.motor_params`.

Its behaviour, as a drive's manual would state it (NMT, CiA 402, SYNC,
faults), is in docs/can-bus.md, "The emulated drives"; its parameters and
SDO server are :mod:`drivers.dictionary` (this class's base).

Bad input (wrong length, undefined values) is counted in
:attr:`DriveNode.stats` and ignored; it never raises.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from typing import Final

from canopen import SdoAbortedError

from drivers.dictionary import DriveObjects, DriveSpec, Frame, SdoAbort
from drivers.stats import BadInput, NodeStats
from rakectl.errors import FrameError
from rakectl.protocol import cia402
from rakectl.protocol.cia402 import DriveCommand, DriveState, StatusFlag
from rakectl.protocol.codec import (
    EMCY_ERROR_REGISTER,
    INT32_LIMIT,
    NMT_COB_ID,
    RPDO1_SIZE,
    SYNC_COB_ID,
    EmcyCode,
    FunctionCode,
    NmtCommand,
    NmtState,
    cob_id,
    current_a_to_ma,
    decode_heartbeat,
    decode_nmt,
    decode_rpdo,
    encode_emcy,
    lost_syncs,
    pack_tpdo1_into,
    pack_tpdo2_into,
    rad_per_s_to_rpm,
)

NO_FRAMES: Final[tuple[Frame, ...]] = ()
OVERCURRENT_SHARE: Final = 0.95  # |i| ≥ this share of the limit counts as "at the limit"


_STATUS_FLAGS: Final = StatusFlag.VOLTAGE_ENABLED | StatusFlag.REMOTE  # supply on, CAN control
_STATUSWORD: Final = {s: cia402.encode_statusword(s, _STATUS_FLAGS) for s in DriveState}
_CLAMP_FLAGS: Final = int(StatusFlag.WARNING | StatusFlag.INTERNAL_LIMIT_ACTIVE)
_REGISTER: Final = {code: int(reg) for code, reg in EMCY_ERROR_REGISTER.items()}
_NMT_TARGET: Final = {NmtCommand.START: NmtState.OPERATIONAL, NmtCommand.STOP: NmtState.STOPPED,
                      NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL}
_SDO_STATES: Final = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})


class DriveNode(DriveObjects):
    """One drive's CiA 301/402 behaviour; see the module docstring."""

    nmt: NmtState
    fault: EmcyCode | None  # the last fault, until a fault reset (0x603F)
    output_voltage_v: float  # what the bridge applies now
    _statusword: int
    _error_register: int
    _clamping: bool  # the last commands were beyond ±0x2001 (invalid-command episode)
    _controlword: int  # the last one applied
    _latched_mv: int
    _rx_voltage_mv: int  # latest RPDO1, applied at the next SYNC if fresh
    _rx_controlword: int
    _fresh_voltage: bool
    _fresh_controlword: bool
    _last_rpdo_s: float
    _last_sync_s: float
    _last_counter: int
    _sync_length_error: bool  # in a run of SYNCs of the wrong length (one EMCY a run)
    _overcurrent_s: float

    def __init__(self, spec: DriveSpec) -> None:
        super().__init__(spec)
        self.stats = NodeStats()
        self.notes: list[tuple[str, enum.Enum]] = []  # events for the log, drained by the caller
        self._tpdo1, self._tpdo2 = bytearray(8), bytearray(3)
        self._ids = {f: cob_id(f, spec.node_id) for f in FunctionCode}
        self._handlers: dict[int, Callable[[int, bytes | bytearray, float], Sequence[Frame]]] = {
            0x700 + n: self._on_heartbeat for n in range(1, 128) if n != spec.node_id}
        self._handlers |= {SYNC_COB_ID: self._on_sync, NMT_COB_ID: self._on_nmt,
                           self._ids[FunctionCode.RPDO1]: self._on_rpdo,
                           self._ids[FunctionCode.SDO_REQUEST]: self._on_sdo}
        self._readers |= self._live_objects()
        self._writers |= {(0x2000, 0): self._write_voltage,
                          (0x2001, 0): self._write_max_voltage,
                          (0x6040, 0): self._write_controlword}
        self.nmt = NmtState.BOOT_UP
        self._power_on_application()
        self._power_on_communication(0.0)
        self._position, self._motor_vel, self._current_a, self._at_stop = 0.0, 0.0, 0.0, False

    # ------------------------------------------------------------------- public

    @property
    def listens_to(self) -> frozenset[int]:
        """COB-IDs this drive handles (SYNC, NMT, its RPDO1 and SDO, heartbeats)."""
        return frozenset(self._handlers)

    @property
    def statusword(self) -> int:
        return self._statusword

    @property
    def error_register(self) -> int:
        return self._error_register

    @property
    def max_voltage_mv(self) -> int:
        return self._max_voltage_mv

    @property
    def watchdog_timeout_s(self) -> float:
        return self._watchdog_ms * 0.001

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
        """Timers: heartbeat production, heartbeat consumer, command watchdog."""
        if self.nmt is NmtState.BOOT_UP:
            return NO_FRAMES
        out: list[Frame] = []
        if self._heartbeat_ms and now_s >= self._next_heartbeat_s:
            out.append((self._ids[FunctionCode.HEARTBEAT], bytes((self.nmt,))))
            period_s = self._heartbeat_ms * 0.001
            self._next_heartbeat_s += period_s
            if self._next_heartbeat_s <= now_s:  # polled late: keep the period from now
                self._next_heartbeat_s = now_s + period_s
        seen_s, timeout_s = self._heartbeat_seen_s, (self._consumer & 0xFFFF) * 0.001
        if seen_s is not None and timeout_s and now_s - seen_s >= timeout_s:
            self._heartbeat_seen_s, self._heartbeat_lost = None, True
            self._fault(EmcyCode.HEARTBEAT_LOST, out)
        self._check_watchdog(now_s, out)
        self._emit_status(out)
        return out

    def next_deadline_s(self) -> float:
        """When :meth:`poll` next has work to do (inf if never)."""
        deadline = self._next_heartbeat_s if self._heartbeat_ms else math.inf
        if self._heartbeat_seen_s is not None and self._consumer & 0xFFFF:
            deadline = min(deadline, self._heartbeat_seen_s + (self._consumer & 0xFFFF) * 0.001)
        if self.state is DriveState.OPERATION_ENABLED:
            oldest_s = min(self._last_rpdo_s, self._last_sync_s)
            deadline = min(deadline, oldest_s + self._watchdog_ms * 0.001)
        return deadline

    def sense(self, position: float, motor_velocity_rad_per_s: float, current_a: float,
              at_hard_stop: bool, dt_s: float) -> Sequence[Frame]:
        """The physics' sample after a step of dt_s: joint position (m or rad), motor
        velocity, measured current, and whether the joint is at a workspace limit."""
        self._position, self._motor_vel = position, motor_velocity_rad_per_s
        self._current_a = current_a
        hit, self._at_stop = at_hard_stop and not self._at_stop, at_hard_stop
        if self.state is not DriveState.OPERATION_ENABLED:
            self._overcurrent_s = 0.0
            return NO_FRAMES
        at_limit = abs(current_a) >= OVERCURRENT_SHARE * self.motor_params.current_limit_a
        self._overcurrent_s = self._overcurrent_s + dt_s if at_limit else 0.0
        if not hit and self._overcurrent_s <= self.spec.overcurrent_time_s:
            return NO_FRAMES
        out: list[Frame] = []
        self._fault(EmcyCode.HARD_STOP_HIT if hit else EmcyCode.OVER_CURRENT, out)
        self._emit_status(out)
        return out

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
        out = [self._sample()]
        self._check_watchdog(now_s, out)
        self._last_sync_s = now_s
        if self._fresh_controlword:
            self._fresh_controlword = False
            self._apply_controlword(self._rx_controlword, now_s, out)
        if self._fresh_voltage:
            self._fresh_voltage = False
            self._latch(self._rx_voltage_mv, out)
        if not self._emit_status(out) and self._tpdo2_refresh and (
                stats.syncs % self._tpdo2_refresh == 0):
            out.append(self._tpdo2_frame())
        return out

    def _sync_length_mismatch(self, can_id: int, data: bytes | bytearray) -> Sequence[Frame]:
        """Ignored and counted; the first of a run sends EMCY 0x8240 (as CANopenNode does)."""
        self.stats.bad.count(BadInput.WRONG_LENGTH, can_id, data)
        if self._sync_length_error or self.nmt not in _SDO_STATES:
            return NO_FRAMES
        self._sync_length_error = True
        code = EmcyCode.SYNC_DATA_LENGTH
        self.stats.emcys += 1
        return [(self._ids[FunctionCode.EMCY],
                 encode_emcy(code, self._register() | _REGISTER[code]))]

    def _on_rpdo(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        if len(data) != RPDO1_SIZE:
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        if self.nmt is not NmtState.OPERATIONAL:
            self.stats.rpdos_ignored += 1
            return NO_FRAMES
        self._rx_voltage_mv, self._rx_controlword = decode_rpdo(data)
        self._fresh_voltage = self._fresh_controlword = True
        self._last_rpdo_s = now_s
        self.stats.rpdos += 1
        return NO_FRAMES

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
            self._set_nmt(_NMT_TARGET[command])
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
        if self.nmt not in _SDO_STATES:
            return NO_FRAMES
        self.stats.sdo_requests += 1
        out: list[Frame] = []
        if not self._serve_sdo(can_id, data, now_s, out):
            self.stats.bad.count(BadInput.BAD_VALUE, can_id, data)
        self._emit_status(out)
        return out

    # ------------------------------------------------------------------- behaviour

    def _sample(self) -> Frame:
        counts = round(self._position / self._resolution)
        counts = max(-INT32_LIMIT, min(INT32_LIMIT, counts))
        pack_tpdo1_into(self._tpdo1, counts, rad_per_s_to_rpm(self._motor_vel),
                        current_a_to_ma(self._current_a))
        return self._ids[FunctionCode.TPDO1], self._tpdo1

    def _tpdo2_frame(self) -> Frame:
        pack_tpdo2_into(self._tpdo2, self._statusword, self._error_register)
        return self._ids[FunctionCode.TPDO2], self._tpdo2

    def _emit_status(self, out: list[Frame]) -> bool:
        """Update statusword and error register; TPDO2 if they changed (and OPERATIONAL)."""
        statusword = _STATUSWORD[self.state] | (_CLAMP_FLAGS if self._clamping else 0)
        register = self._register()
        if statusword == self._statusword and register == self._error_register:
            return False
        self._statusword, self._error_register = statusword, register
        if self.nmt is not NmtState.OPERATIONAL:
            return False
        out.append(self._tpdo2_frame())
        return True

    def _register(self) -> int:
        register = _REGISTER[self.fault] if self.fault is not None else 0
        return register | (_REGISTER[EmcyCode.INVALID_COMMAND] if self._clamping else 0)

    def _emcy(self, code: EmcyCode, out: list[Frame]) -> None:
        if self.nmt in _SDO_STATES:
            out.append((self._ids[FunctionCode.EMCY], encode_emcy(code, self._register())))
            self.stats.emcys += 1

    def _check_watchdog(self, now_s: float, out: list[Frame]) -> None:
        if self.state is DriveState.OPERATION_ENABLED:
            oldest_s = min(self._last_rpdo_s, self._last_sync_s)
            if now_s - oldest_s >= self._watchdog_ms * 0.001:
                self._fault(EmcyCode.COMMAND_WATCHDOG_TIMEOUT, out)

    def _apply_controlword(self, controlword: int, now_s: float, out: list[Frame]) -> None:
        command = cia402.decode_controlword(controlword, self._controlword)
        self._controlword = controlword
        if command is DriveCommand.FAULT_RESET:
            self._fault_reset(out)
            return
        state = cia402.next_state(self.state, command)
        if state is not self.state:
            self.state = state
            if state is DriveState.OPERATION_ENABLED:  # arm the watchdog from now
                self._last_rpdo_s = self._last_sync_s = now_s
            self._update_output()

    def _latch(self, voltage_mv: int, out: list[Frame]) -> None:
        limit = self._max_voltage_mv
        if -limit <= voltage_mv <= limit:
            if self._clamping:
                self._clamping = False
                if self.fault is None:
                    self._emcy(EmcyCode.NO_ERROR, out)
        else:
            self.stats.clamped_commands += 1
            voltage_mv = limit if voltage_mv > 0 else -limit
            if not self._clamping:
                self._clamping = True
                self._emcy(EmcyCode.INVALID_COMMAND, out)
        self._latched_mv = voltage_mv
        self._update_output()

    def _update_output(self) -> None:
        enabled = self.state is DriveState.OPERATION_ENABLED
        self.output_voltage_v = self._latched_mv * 0.001 if enabled else 0.0

    def _fault(self, code: EmcyCode, out: list[Frame]) -> None:
        """0 V, FAULT_REACTION_ACTIVE → FAULT, EMCY; a later different fault only sends EMCY."""
        if code is self.fault:
            return
        self.fault = code
        self.state = cia402.settle(cia402.on_fault(self.state))
        self._latched_mv, self._overcurrent_s = 0, 0.0
        self._update_output()
        self.stats.faults += 1
        self._emcy(code, out)
        self.notes.append(("drive_fault", code))

    def _fault_reset(self, out: list[Frame]) -> None:
        if self.state is not DriveState.FAULT:
            return
        at_limit = abs(self._current_a) >= OVERCURRENT_SHARE * self.motor_params.current_limit_a
        if self._heartbeat_lost or (self.fault is EmcyCode.OVER_CURRENT and at_limit):
            self.notes.append(("fault_reset_refused", self.fault or EmcyCode.NO_ERROR))
            return
        self.notes.append(("fault_reset", self.fault or EmcyCode.NO_ERROR))
        self.fault = None
        self.state = cia402.next_state(self.state, DriveCommand.FAULT_RESET)
        self._emcy(EmcyCode.NO_ERROR, out)

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
        self._restore_parameters()
        self.state = cia402.settle(DriveState.NOT_READY_TO_SWITCH_ON)
        self.fault = None
        self._clamping, self._controlword, self._latched_mv = False, 0, 0
        self._rx_voltage_mv = self._rx_controlword = 0
        self._fresh_voltage = self._fresh_controlword = False
        self._last_rpdo_s = self._last_sync_s = self._overcurrent_s = 0.0
        self._statusword = self._error_register = -1
        self._update_output()

    def _power_on_communication(self, now_s: float) -> None:
        self._restore_communication(now_s)
        self._last_counter, self._sync_length_error = 0, False

    # ------------------------------------------------------------------- live objects

    def _live_objects(self) -> dict[tuple[int, int], Callable[[], int]]:
        return {
            (0x1001, 0): lambda: self._error_register,
            (0x2000, 0): lambda: self._latched_mv,
            (0x2100, 0): lambda: current_a_to_ma(self._current_a),
            (0x603F, 0): lambda: int(self.fault or 0),
            (0x6040, 0): lambda: self._controlword,
            (0x6041, 0): lambda: self._statusword,
            (0x6064, 0): lambda: round(self._position / self._resolution),
            (0x606C, 0): lambda: rad_per_s_to_rpm(self._motor_vel),
        }

    def _write_voltage(self, value: int) -> None:
        self._rx_voltage_mv, self._fresh_voltage = value, True  # latched at the next SYNC

    def _write_max_voltage(self, value: int) -> None:
        if value > round(self.spec.motor.supply_voltage_v * 1000):
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        self._max_voltage_mv = value
        self._latched_mv = max(-value, min(value, self._latched_mv))
        self._update_output()

    def _write_controlword(self, value: int) -> None:
        self._apply_controlword(value, self._now_s, self._out)
