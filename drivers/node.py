"""One emulated CANopen drive with an open-loop voltage mode: frames in, frames out.

A :class:`DriveNode` is the protocol side of one Roboteq/Faulhaber-class drive
(CiA 301 + CiA 402, the layouts of :mod:`rakectl.protocol.codec`). It does no bus I/O
and reads no clock: :meth:`DriveNode.receive` takes a frame's COB-ID, data and
the time, :meth:`~DriveNode.poll` the time alone, :meth:`~DriveNode.sense` the
physics' latest sample; each returns the frames to send as ``(can_id, data)``.
``data`` is ``bytes``, or for TPDO1/TPDO2 a ``bytearray`` the node packs again
on its next call (send it, or copy it, before then). The physics reads
:attr:`~DriveNode.output_voltage_v` and :attr:`~DriveNode.motor_params`.

NMT (CiA 301). At power-on (:meth:`~DriveNode.boot`) and after NMT reset node
or reset communication the drive sends its boot-up heartbeat (state 0) and is
PRE-OPERATIONAL; then it sends a heartbeat 0x700+id every 0x1017 ms in every
state. START → OPERATIONAL, STOP → STOPPED, ENTER_PRE_OPERATIONAL →
PRE-OPERATIONAL; node-ID 0 addresses every node. Reset node restores every
object to its power-on value and the CiA 402 state to SWITCH_ON_DISABLED
(faults cleared); reset communication restores 0x1000–0x1FFF only. PDOs
(SYNC → TPDO1, RPDO1, TPDO2) work only in OPERATIONAL; SDO and EMCY in
PRE-OPERATIONAL and OPERATIONAL; in STOPPED only NMT and heartbeats. Entering
OPERATIONAL sends TPDO2 once; leaving it drops the latched voltage to 0 V
(the command watchdog then faults an enabled drive).

SDO. canopen's ``LocalNode`` over the drive type's EDS is the SDO server: the
drive passes each 8-byte request to ``Network.notify`` of a never-connected
``canopen.Network`` whose ``send_message`` (the override point canopen
documents) collects the response into the frames returned. LocalNode's own NMT
slave is left out (it would start a heartbeat thread when 0x1017 is written).
Live objects (0x6041, 0x6064 …) are served by a read callback; a write callback
checks the EDS's LowLimit/HighLimit and the drive's own bounds and rejects a
write by raising ``SdoAbortedError`` (canopen answers with that abort code and
stores nothing): 0x2001 ≤ the supply, 0x2002 in 1 … the hardware current
limit and 0x2004 only while not OPERATION_ENABLED (0x08000022), 0x6060 only −1.
Other writable communication objects (COB-IDs, transmission types) are fixed
in this drive: writing their present value succeeds, any other value aborts.
Identity 0x1018: product code from the EDS, serial number from the
configuration.

CiA 402 (:mod:`rakectl.protocol.cia402`). The drive boots to SWITCH_ON_DISABLED. RPDO1
is synchronous: its controlword and voltage take effect at the next SYNC (the
command computed from SYNC k's TPDO1 acts from SYNC k+1); a controlword
written by SDO to 0x6040 acts at once. The command's voltage is applied only
in OPERATION_ENABLED. In every other state the output is 0 V *with the bridge
driven*: the motor terminals are shorted, so the motor brakes dynamically and
the arm sinks slowly under gravity instead of falling freely. A RPDO1 voltage
beyond ±0x2001 is clamped; the first of a run of such commands sends EMCY
INVALID_COMMAND and sets statusword bits 7 (warning) and 11 (internal limit)
and the error register; the next valid command clears them and sends EMCY
NO_ERROR. The clamp is a warning, not a fault. The physics' current limiter
uses 0x2002 (≤ the hardware limit; :attr:`~DriveNode.motor_params`).

On SYNC (1-byte counter 1..240) an OPERATIONAL drive (1) samples position
counts = round(position / joint_resolution), motor rpm and current mA and
sends TPDO1; (2) applies the latest RPDO1 received since the previous SYNC;
(3) sends TPDO2 when statusword or error register changed, and on every
0x2005-th SYNC received. Lost SYNCs are counted from the counter.

Faults: each sends its EMCY, applies 0 V at once and goes through
FAULT_REACTION_ACTIVE to FAULT (0x603F holds the code):
COMMAND_WATCHDOG_TIMEOUT when, in OPERATION_ENABLED, no valid RPDO1 or no
SYNC arrived for 0x2003 ms (a wrong-length RPDO1 does not feed it);
HEARTBEAT_LOST when the controller's heartbeat (0x1016 sub 1: node in bits
16–23, timeout ms in bits 0–15; monitored from its first heartbeat) stops
for that long, in any state; OVER_CURRENT when, enabled, the measured current
stays at ≥ 95 % of the limit longer than the configured time; HARD_STOP_HIT
when, enabled, the joint reaches a workspace limit (an end switch: on reaching
it, not while resting on it). A rising edge of controlword bit 7 in FAULT is a
fault reset: it succeeds (→ SWITCH_ON_DISABLED, EMCY NO_ERROR) unless the
cause persists (controller heartbeat still missing, current still at limit).

Bad input (wrong length, undefined values) is counted in
:attr:`DriveNode.stats` and ignored; it never raises.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import canopen
from canopen import SdoAbortedError

from rakectl.core.motor_model import MotorParams, joint_resolution
from rakectl.errors import FrameError
from rakectl.protocol import cia402
from rakectl.protocol.cia402 import DriveCommand, DriveState, StatusFlag
from rakectl.protocol.codec import (
    EMCY_ERROR_REGISTER,
    INT32_LIMIT,
    NMT_COB_ID,
    RPDO1_SIZE,
    SYNC_COB_ID,
    SYNC_COUNTER_MAX,
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
from rakectl.protocol.files import EDS_DIR

Frame = tuple[int, bytes | bytearray]
NO_FRAMES: Final[tuple[Frame, ...]] = ()
OVERCURRENT_SHARE: Final = 0.95  # |i| ≥ this share of the limit counts as "at the limit"
MAX_COUNTS_PER_REV: Final = 10**9  # MotorParams' bound on encoder_counts_per_rev


class DriveKind(enum.Enum):
    """A drive type and its EDS (object dictionary, product code)."""

    DC_SERVO = "dc_servo_drive.eds"
    GEARED_MOTOR = "geared_motor_drive.eds"

    @property
    def eds_path(self) -> Path:
        return EDS_DIR / self.value


class BadInput(enum.Enum):
    """Kinds of input that are counted and ignored."""

    WRONG_LENGTH = "wrong_length"
    BAD_VALUE = "bad_value"  # a value the protocol does not define
    UNKNOWN_ID = "unknown_id"  # no drive listens to it (counted by the emulator)
    UNSUPPORTED = "unsupported"  # remote, error, extended-ID or FD frame (emulator)


class SdoAbort(enum.IntEnum):
    """SDO abort codes (CiA 301) this drive's own checks use."""

    UNKNOWN_COMMAND = 0x05040001  # command specifier not valid, or out of sequence
    VALUE_RANGE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    DEVICE_STATE = 0x08000022


@dataclass(frozen=True)
class DriveSpec:
    """What a drive is: its node-ID, type, hardware and serial number."""

    node_id: int
    kind: DriveKind
    motor: MotorParams  # the hardware: supply and current limit bound 0x2001 and 0x2002
    serial_number: int
    controller_node_id: int
    overcurrent_time_s: float = 0.5


class InputStats:
    """Bad input per kind, and the last such frame of each kind."""

    __slots__ = ("counts", "last", "total")

    def __init__(self) -> None:
        self.counts = dict.fromkeys(BadInput, 0)
        self.last: dict[BadInput, tuple[int, bytes]] = {}
        self.total = 0

    def count(self, kind: BadInput, can_id: int, data: bytes | bytearray) -> None:
        self.counts[kind] += 1
        self.last[kind] = (can_id, bytes(data))
        self.total += 1


class NodeStats:
    """Counters of one drive (summarized off the hot path)."""

    __slots__ = ("bad", "clamped_commands", "emcys", "faults", "lost_syncs", "rpdos",
                 "rpdos_ignored", "sdo_requests", "syncs")

    def __init__(self) -> None:
        self.bad = InputStats()
        self.syncs = self.lost_syncs = self.rpdos = self.rpdos_ignored = 0
        self.sdo_requests = self.clamped_commands = self.emcys = self.faults = 0


_STATUS_FLAGS: Final = StatusFlag.VOLTAGE_ENABLED | StatusFlag.REMOTE  # supply on, CAN control
_STATUSWORD: Final = {s: cia402.encode_statusword(s, _STATUS_FLAGS) for s in DriveState}
_CLAMP_FLAGS: Final = int(StatusFlag.WARNING | StatusFlag.INTERNAL_LIMIT_ACTIVE)
_REGISTER: Final = {code: int(reg) for code, reg in EMCY_ERROR_REGISTER.items()}
_NMT_TARGET: Final = {NmtCommand.START: NmtState.OPERATIONAL, NmtCommand.STOP: NmtState.STOPPED,
                      NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL}
_SDO_STATES: Final = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})
_COMM_RANGE: Final = range(0x1000, 0x2000)
_SDO_ABORT: Final = struct.Struct("<BHBL")  # command 0x80, index, subindex, abort code


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


class DriveNode:
    """One drive's CiA 301/402 behaviour; see the module docstring."""

    nmt: NmtState
    state: DriveState
    fault: EmcyCode | None  # the last fault, until a fault reset (0x603F)
    output_voltage_v: float  # what the bridge applies now
    motor_params: MotorParams  # the hardware with the current limit of 0x2002
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
    _overcurrent_s: float
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

    def __init__(self, spec: DriveSpec) -> None:
        self.spec, self.node_id = spec, spec.node_id
        self.stats = NodeStats()
        self.notes: list[tuple[str, enum.Enum]] = []  # events for the log, drained by the caller
        self._network = _Outbox()
        self._od = _SdoServerNode(spec.node_id, str(spec.kind.eds_path))
        self._network.add_node(self._od)
        self._od.add_read_callback(self._od_read)  # type: ignore[no-untyped-call]
        self._od.add_write_callback(self._od_write)
        self._tpdo1, self._tpdo2 = bytearray(8), bytearray(3)
        self._ids = {f: cob_id(f, spec.node_id) for f in FunctionCode}
        self._handlers: dict[int, Callable[[int, bytes | bytearray, float], Sequence[Frame]]] = {
            0x700 + n: self._on_heartbeat for n in range(1, 128) if n != spec.node_id}
        self._handlers |= {SYNC_COB_ID: self._on_sync, NMT_COB_ID: self._on_nmt,
                           self._ids[FunctionCode.RPDO1]: self._on_rpdo,
                           self._ids[FunctionCode.SDO_REQUEST]: self._on_sdo}
        self._power_on = self._power_on_values()
        self._readers, self._writers = self._object_handlers()
        self._now_s: float = 0.0  # context of the SDO write callbacks
        self._out: list[Frame] = []
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

    def _on_sync(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        if len(data) != 1:
            return self._bad(BadInput.WRONG_LENGTH, can_id, data)
        counter = data[0]
        if not 1 <= counter <= SYNC_COUNTER_MAX:
            return self._bad(BadInput.BAD_VALUE, can_id, data)
        if self.nmt is not NmtState.OPERATIONAL:
            return NO_FRAMES
        stats = self.stats
        stats.syncs += 1
        if self._last_counter:
            stats.lost_syncs += lost_syncs(self._last_counter, counter)
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
        self._now_s, self._out = now_s, out  # context of the write callback
        try:
            self._network.notify(can_id, bytearray(data), now_s)
        except Exception:  # canopen's server raises on a segment with no transfer open
            self._network.frames.clear()
            self.stats.bad.count(BadInput.BAD_VALUE, can_id, data)
            abort = _SDO_ABORT.pack(0x80, 0, 0, SdoAbort.UNKNOWN_COMMAND)
            self._network.frames.append((self._ids[FunctionCode.SDO_RESPONSE], abort))
        out += self._network.frames
        self._network.frames.clear()
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

    def _eds_default(self, index: int, subindex: int = 0) -> int:
        entry: Any = self._od.object_dictionary[index]
        return int((entry[subindex] if subindex else entry).default)

    def _power_on_values(self) -> dict[int, int]:
        """Power-on values of the objects the drive acts on, bounded by its hardware."""
        motor, default = self.spec.motor, self._eds_default
        return {
            0x1016: default(0x1016, 1) & 0xFFFF | self.spec.controller_node_id << 16,
            0x1017: default(0x1017),
            0x2001: min(default(0x2001), round(motor.supply_voltage_v * 1000)),
            0x2002: min(default(0x2002), self._hardware_limit_ma()),
            0x2003: default(0x2003), 0x2004: motor.encoder_counts_per_rev,
            0x2005: default(0x2005),
        }

    def _hardware_limit_ma(self) -> int:
        return round(self.spec.motor.current_limit_a * 1000)

    def _power_on_application(self) -> None:
        values = self._power_on
        self._od.data_store.clear()
        self._max_voltage_mv, self._watchdog_ms = values[0x2001], values[0x2003]
        self._tpdo2_refresh = values[0x2005]
        self._set_current_limit_ma(values[0x2002])
        self._set_counts_per_rev(values[0x2004])
        self.state = cia402.settle(DriveState.NOT_READY_TO_SWITCH_ON)
        self.fault = None
        self._clamping, self._controlword, self._latched_mv = False, 0, 0
        self._rx_voltage_mv = self._rx_controlword = 0
        self._fresh_voltage = self._fresh_controlword = False
        self._last_rpdo_s = self._last_sync_s = self._overcurrent_s = 0.0
        self._statusword = self._error_register = -1
        self._update_output()

    def _power_on_communication(self, now_s: float) -> None:
        for index in [i for i in self._od.data_store if i in _COMM_RANGE]:
            del self._od.data_store[index]
        self._heartbeat_ms, self._consumer = self._power_on[0x1017], self._power_on[0x1016]
        self._next_heartbeat_s = now_s + self._heartbeat_ms * 0.001
        self._heartbeat_seen_s = None
        self._heartbeat_lost, self._last_counter = False, 0

    def _set_current_limit_ma(self, limit_ma: int) -> None:
        self._current_limit_ma = limit_ma
        limit_a = min(limit_ma, self._hardware_limit_ma()) * 0.001
        self.motor_params = dataclasses.replace(self.spec.motor, current_limit_a=limit_a)

    def _set_counts_per_rev(self, counts: int) -> None:
        self._counts_per_rev = counts
        motor = dataclasses.replace(self.spec.motor, encoder_counts_per_rev=counts)
        self._resolution = joint_resolution(motor)

    # ------------------------------------------------------------------- object dictionary

    def _object_handlers(self) -> tuple[dict[tuple[int, int], Callable[[], int]],
                                        dict[tuple[int, int], Callable[[int], None]]]:
        readers: dict[tuple[int, int], Callable[[], int]] = {
            (0x1001, 0): lambda: self._error_register,
            (0x1016, 1): lambda: self._consumer,
            (0x1017, 0): lambda: self._heartbeat_ms,
            (0x1018, 4): lambda: self.spec.serial_number,
            (0x2000, 0): lambda: self._latched_mv,
            (0x2001, 0): lambda: self._max_voltage_mv,
            (0x2002, 0): lambda: self._current_limit_ma,
            (0x2003, 0): lambda: self._watchdog_ms,
            (0x2004, 0): lambda: self._counts_per_rev,
            (0x2005, 0): lambda: self._tpdo2_refresh,
            (0x2100, 0): lambda: current_a_to_ma(self._current_a),
            (0x603F, 0): lambda: int(self.fault or 0),
            (0x6040, 0): lambda: self._controlword,
            (0x6041, 0): lambda: self._statusword,
            (0x6064, 0): lambda: round(self._position / self._resolution),
            (0x606C, 0): lambda: rad_per_s_to_rpm(self._motor_vel),
        }
        writers: dict[tuple[int, int], Callable[[int], None]] = {
            (0x1006, 0): lambda value: None,  # communication cycle period: informative
            (0x6060, 0): lambda value: None,  # the EDS limits it to −1
            (0x1016, 1): self._write_consumer,
            (0x1017, 0): self._write_heartbeat_period,
            (0x2000, 0): self._write_voltage,
            (0x2001, 0): self._write_max_voltage,
            (0x2002, 0): self._write_current_limit,
            (0x2003, 0): self._write_watchdog,
            (0x2004, 0): self._write_counts_per_rev,
            (0x2005, 0): self._write_tpdo2_refresh,
            (0x6040, 0): self._write_controlword,
        }
        return readers, writers

    def _od_read(self, index: int, subindex: int, od: Any, **_: Any) -> int | None:
        reader = self._readers.get((index, subindex))
        return reader() if reader is not None else None

    def _od_write(self, index: int, subindex: int, od: Any, data: bytes, **_: Any) -> None:
        value = od.decode_raw(data)
        if not isinstance(value, int):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)
        if od.min is not None and value < od.min:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        writer = self._writers.get((index, subindex))
        if writer is not None:
            writer(value)
        elif value != od.decode_raw(self._od.get_data(index, subindex)):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)  # fixed in this drive

    def _require_not_enabled(self) -> None:
        if self.state is DriveState.OPERATION_ENABLED:
            raise SdoAbortedError(SdoAbort.DEVICE_STATE)

    def _write_consumer(self, value: int) -> None:
        self._consumer, self._heartbeat_seen_s, self._heartbeat_lost = value, None, False

    def _write_heartbeat_period(self, value: int) -> None:
        self._heartbeat_ms, self._next_heartbeat_s = value, self._now_s + value * 0.001

    def _write_voltage(self, value: int) -> None:
        self._rx_voltage_mv, self._fresh_voltage = value, True  # latched at the next SYNC

    def _write_max_voltage(self, value: int) -> None:
        if value > round(self.spec.motor.supply_voltage_v * 1000):
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        self._max_voltage_mv = value
        self._latched_mv = max(-value, min(value, self._latched_mv))
        self._update_output()

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

    def _write_controlword(self, value: int) -> None:
        self._apply_controlword(value, self._now_s, self._out)
