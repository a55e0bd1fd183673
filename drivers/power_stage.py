"""An emulated drive's power stage: the CiA 402 state machine, the output voltage and
the faults, with the statusword, error register and EMCY they produce.

A fault reset (a rising edge of controlword bit 7 in FAULT, by RPDO1 or by SDO) takes
effect at the drive's next cycle, as a real drive's state machine runs in a cyclic task:
at the next SYNC, or ``FAULT_RESET_DELAY_S`` later, whichever comes first (the
subclass's timers call :meth:`PowerStage._complete_fault_reset`). Until then the
statusword still reads FAULT.

The base of :class:`drivers.node.DriveNode`, which adds the CiA 301 communication
(NMT, SYNC, PDOs, heartbeats, SDO requests); its parameters and SDO server are
:class:`drivers.dictionary.DriveObjects`. The behaviour as a drive's manual
states it is in docs/can-bus.md, "The emulated drives".
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from typing import Final

from canopen import SdoAbortedError

from drivers.dictionary import DriveObjects
from drivers.drive_spec import DriveSpec, Frame, SdoAbort
from drivers.stats import NodeStats
from rakectl.protocol import cia402
from rakectl.protocol.cia402 import DriveCommand, DriveState, StatusFlag
from rakectl.protocol.codec import (
    FunctionCode,
    cob_id,
    current_a_to_ma,
    pack_tpdo2_into,
    rad_per_s_to_rpm,
)
from rakectl.protocol.nmt import EMCY_ERROR_REGISTER, EmcyCode, NmtState, encode_emcy

NO_FRAMES: Final[tuple[Frame, ...]] = ()
OVERCURRENT_SHARE: Final = 0.95  # |i| ≥ this share of the limit counts as "at the limit"
EMCY_STATES: Final = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})  # and SDO
REGISTER: Final = {code: int(reg) for code, reg in EMCY_ERROR_REGISTER.items()}
_STATUS_FLAGS: Final = StatusFlag.VOLTAGE_ENABLED | StatusFlag.REMOTE  # supply on, CAN control
_STATUSWORD: Final = {s: cia402.encode_statusword(s, _STATUS_FLAGS) for s in DriveState}
_CLAMP_FLAGS: Final = int(StatusFlag.WARNING | StatusFlag.INTERNAL_LIMIT_ACTIVE)
FAULT_RESET_DELAY_S: Final = 0.002  # a fault reset acts at the drive's next cycle, this late


class PowerStage(DriveObjects):
    """One drive's CiA 402 behaviour and output; see the module docstring."""

    fault: EmcyCode | None  # the last fault, until a fault reset (0x603F)
    output_voltage_v: float  # what the bridge applies now
    _statusword: int
    _error_register: int
    _clamping: bool  # the last commands were beyond ±0x2001 (invalid-command episode)
    _controlword: int  # the last one applied
    _latched_mv: int
    _last_rpdo_s: float
    _last_sync_s: float
    _overcurrent_s: float
    _fault_reset_due_s: float | None  # a fault reset taken, acting at the next cycle

    def __init__(self, spec: DriveSpec) -> None:
        super().__init__(spec)
        self.stats = NodeStats()
        self.notes: list[tuple[str, enum.Enum]] = []  # events for the log, drained by the caller
        self._tpdo2 = bytearray(3)
        self._tpdo2_on = True  # TPDO2 valid and mapped (drivers.pdo_map)
        self._ids = {f: cob_id(f, spec.node_id) for f in FunctionCode}
        self._readers |= self._live_objects()
        self._writers[(0x6040, 0)] = self._write_controlword
        if spec.kind.parameters.max_voltage is not None:
            self._writers[spec.kind.parameters.max_voltage] = self._write_max_voltage
        self._position, self._motor_vel, self._current_a, self._at_stop = 0.0, 0.0, 0.0, False

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

    # ------------------------------------------------------------------- CiA 402

    def _tpdo2_frame(self) -> Frame:
        pack_tpdo2_into(self._tpdo2, self._statusword, self._error_register)
        return self._ids[FunctionCode.TPDO2], self._tpdo2

    def _emit_status(self, out: list[Frame]) -> bool:
        """Update statusword and error register; TPDO2 if they changed (and OPERATIONAL,
        and TPDO2 is valid)."""
        statusword = _STATUSWORD[self.state] | (_CLAMP_FLAGS if self._clamping else 0)
        register = self._register()
        if statusword == self._statusword and register == self._error_register:
            return False
        self._statusword, self._error_register = statusword, register
        if self.nmt is not NmtState.OPERATIONAL or not self._tpdo2_on:
            return False
        out.append(self._tpdo2_frame())
        return True

    def _register(self) -> int:
        register = REGISTER[self.fault] if self.fault is not None else 0
        return register | (REGISTER[EmcyCode.INVALID_COMMAND] if self._clamping else 0)

    def _emcy(self, code: EmcyCode, out: list[Frame]) -> None:
        if code is not EmcyCode.NO_ERROR:
            self.record_error(code)
        if self.nmt in EMCY_STATES:
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
            if self.state is DriveState.FAULT and self._fault_reset_due_s is None:
                self._fault_reset_due_s = now_s + FAULT_RESET_DELAY_S  # the next cycle
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

    def _complete_fault_reset(self, now_s: float, out: list[Frame], cycle: bool = False) -> None:
        """The fault reset taken at an earlier cycle, once due (``cycle``: a SYNC starts one)."""
        due_s = self._fault_reset_due_s
        if due_s is not None and (cycle or now_s >= due_s):
            self._fault_reset_due_s = None
            self._fault_reset(out)

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

    def _power_on_stage(self) -> None:
        """CiA 402 and the parameters at power-on (NMT reset node)."""
        self._restore_parameters()
        self.state = cia402.settle(DriveState.NOT_READY_TO_SWITCH_ON)
        self.fault = None
        self._clamping, self._controlword, self._latched_mv = False, 0, 0
        self._last_rpdo_s = self._last_sync_s = self._overcurrent_s = 0.0
        self._fault_reset_due_s = None
        self._statusword = self._error_register = -1
        self._update_output()

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

    def _write_max_voltage(self, value: int) -> None:
        if value > round(self.spec.motor.supply_voltage_v * 1000):
            raise SdoAbortedError(SdoAbort.VALUE_TOO_HIGH)
        self._max_voltage_mv = value
        self._latched_mv = max(-value, min(value, self._latched_mv))
        self._update_output()

    def _write_controlword(self, value: int) -> None:
        self._apply_controlword(value, self._now_s, self._out)
