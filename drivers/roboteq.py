"""An emulated Roboteq-class motor controller: one channel of a manufacturer profile.

The same CiA 301 communication as :class:`drivers.node.DriveNode` (NMT, boot-up,
heartbeats, SYNC with or without counter, SDO, EMCY, PDOs remappable in CiA 301's
order) and the same power stage behind it, but the object dictionary of
``rakectl/protocol/eds/roboteq_class_drive.eds`` and no CiA 402 state machine:

* **Motor command** 0x2000:01 (i32, ‰ of the supply, −1000 … 1000), in RPDO1 or by
  SDO, applied at the next SYNC (synchronous, as the project's own drive). A command
  beyond ±1000 is applied as ±1000 and sends EMCY 0xFF02 once per episode.
* **Driven whenever it may be**: in NMT OPERATIONAL with no fault flag and no
  emergency stop, the bridge applies the latched command; leaving OPERATIONAL drops it
  to 0 V. There is no enable sequence.
* **Command watchdog** 0x3001 (ms, Roboteq's RWD; 0 = off): no RPDO1 or no SYNC for
  that long → 0 V and status flag 5, *not* a fault: the next command received applies
  again (as Roboteq's manuals state); one received before it fired is dropped.
  Power-on value 1000 ms.
* **Faults** (fault flags 0x2112): over current for the drive's over-current time
  (bit 3, "short circuit", EMCY 0x2310), the joint's hard stop hit (bit 5, "sensor
  fault", EMCY 0xFF01), the controller's heartbeat lost (0x1016: bit 8, "communication
  lost", this EDS's, EMCY 0x8130); an emergency shutdown 0x200C written sets bit 4
  (emergency stop, no EMCY). Each applies 0 V and latches until *release shutdown*
  0x200D is written (refused while a fault's cause lasts, as the CiA 402 drive's fault
  reset is); then the drive drives again, from 0 V.
* **Feedback** (the layouts of :mod:`rakectl.protocol.roboteq`) on every SYNC (TPDO1):
  encoder counter 0x2104:01 (i32 counts), encoder motor speed 0x2103:01 (i16 rpm),
  motor amps 0x2100:01 (i16, 0.1 A). TPDO2: fault flags 0x2112 and status flags 0x2111
  (u16 each) on change and every 0x3004-th SYNC.
  Status flags: bit 0 serial mode (commands come from the bus), bit 3 power stage off,
  bit 5 command watchdog expired, bit 6 amps limit active. 0x210D:01/02: the supply
  (0.1 V).
* **Limits**: amps limit 0x3002 (0.1 A, at most the hardware's), encoder counts per
  motor revolution 0x3003 (only while the power stage is off); no voltage limit of its
  own (the command is a share of the supply).

:attr:`state` holds the CiA 402 state that behaves the same (OPERATION_ENABLED while
the bridge may drive, FAULT while a fault flag is set, SWITCH_ON_DISABLED otherwise),
for the emulator's ground truth and log; it is not on the bus.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

from canopen import SdoAbortedError

from drivers.drive_spec import DriveKind, DriveSpec, Frame, SdoAbort
from drivers.node import DriveNode
from drivers.power_stage import NO_FRAMES, OVERCURRENT_SHARE
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.codec import INT32_LIMIT, rad_per_s_to_rpm
from rakectl.protocol.nmt import EmcyCode, NmtState
from rakectl.protocol.roboteq import (
    FAULT_COMMUNICATION,
    FAULT_EMERGENCY_STOP,
    FAULT_OTHER,
    FAULT_SENSOR,
    FAULT_SHORT_CIRCUIT,
    PER_MILLE,
    STATUS_AMPS_LIMIT,
    STATUS_POWER_STAGE_OFF,
    STATUS_SERIAL_MODE,
    STATUS_WATCHDOG_EXPIRED,
    per_mille_to_mv,
)

FAULT_FLAG: Final = {EmcyCode.OVER_CURRENT: FAULT_SHORT_CIRCUIT,
                     EmcyCode.HARD_STOP_HIT: FAULT_SENSOR,
                     EmcyCode.HEARTBEAT_LOST: FAULT_COMMUNICATION}


class RoboteqNode(DriveNode):
    """One emulated Roboteq-class drive; see the module docstring."""

    FAST_PATH = False  # its PDOs are packed from their mapping, through the object readers

    def __init__(self, spec: DriveSpec) -> None:
        if spec.kind is not DriveKind.ROBOTEQ_CLASS:
            raise ValueError(f"a Roboteq-class drive needs DriveKind.ROBOTEQ_CLASS, not "
                             f"{spec.kind.name}")
        self._supply_mv = round(spec.motor.supply_voltage_v * 1000)
        self._shutdown = False  # 0x200C written, until 0x200D
        self._watchdog_expired = False
        super().__init__(spec)
        del self._writers[(0x2000, 0)], self._writers[(0x6040, 0)]
        self._writers |= {(0x2000, 1): self._write_command,
                          (0x200C, 0): self._write_emergency_shutdown,
                          (0x200D, 0): self._write_release_shutdown}

    # ------------------------------------------------------------------- public

    @property
    def fault_flags(self) -> int:
        flags = FAULT_FLAG.get(self.fault, FAULT_OTHER) if self.fault is not None else 0
        return flags | (FAULT_EMERGENCY_STOP if self._shutdown else 0)

    @property
    def status_flags(self) -> int:
        flags = STATUS_SERIAL_MODE
        if self.output_enabled is False:
            flags |= STATUS_POWER_STAGE_OFF
        if self._watchdog_expired:
            flags |= STATUS_WATCHDOG_EXPIRED
        if abs(self._current_a) >= OVERCURRENT_SHARE * self.motor_params.current_limit_a:
            flags |= STATUS_AMPS_LIMIT
        return flags

    @property
    def output_enabled(self) -> bool:
        return self.state is DriveState.OPERATION_ENABLED and not self._watchdog_expired

    def _watchdog_running(self) -> bool:
        """While it drives, unless 0x3001 is 0 (off); not once expired (until a command)."""
        return self.output_enabled and self._watchdog_ms > 0

    # ------------------------------------------------------------------- behaviour

    def _take_rpdo(self, index: int, subindex: int, value: int) -> None:
        if (index, subindex) == (0x2000, 1):
            self._write_command(value)

    def _write_command(self, value: int) -> None:
        self._rx_voltage_mv, self._fresh_voltage = per_mille_to_mv(value, self._supply_mv), True

    def _latch(self, voltage_mv: int, out: list[Frame]) -> None:
        self._watchdog_expired = False  # a command: the watchdog lets it through again
        super()._latch(voltage_mv, out)

    def _check_watchdog(self, now_s: float, out: list[Frame]) -> None:
        if not self._watchdog_running():
            return
        if now_s - min(self._last_rpdo_s, self._last_sync_s) >= self._watchdog_ms * 0.001:
            self._watchdog_expired, self._latched_mv = True, 0
            self._fresh_voltage = False  # a command from before it fired is not taken
            self._update_output()
            self.notes.append(("command_watchdog", EmcyCode.COMMAND_WATCHDOG_TIMEOUT))

    def _update_output(self) -> None:
        self.output_voltage_v = self._latched_mv * 0.001 if self.output_enabled else 0.0

    def _on_nmt(self, can_id: int, data: bytes | bytearray, now_s: float) -> Sequence[Frame]:
        self._now_s = now_s  # entering OPERATIONAL starts the watchdog from now
        return super()._on_nmt(can_id, data, now_s)

    def _set_nmt(self, state: NmtState) -> None:
        super()._set_nmt(state)
        self._settle()

    def _settle(self) -> None:
        """The CiA 402 state that behaves as the drive now does; 0 V unless it drives."""
        if self.fault is not None:
            state = DriveState.FAULT
        elif self._shutdown or self.nmt is not NmtState.OPERATIONAL:
            state = DriveState.SWITCH_ON_DISABLED
        else:
            state = DriveState.OPERATION_ENABLED
        if state is not self.state:
            if state is DriveState.OPERATION_ENABLED:  # the watchdog counts from now
                self._last_rpdo_s = self._last_sync_s = self._now_s
                self._watchdog_expired, self._latched_mv = False, 0
            self.state = state
        self._update_output()

    def _write_emergency_shutdown(self, value: int) -> None:
        self._shutdown, self._latched_mv = True, 0
        self._settle()

    def _write_release_shutdown(self, value: int) -> None:
        if self.fault is not None:
            self._fault_reset(self._out)
            if self.fault is not None:  # the cause lasts
                raise SdoAbortedError(SdoAbort.DEVICE_STATE)
        self._shutdown = False
        self._settle()

    def _power_on_stage(self) -> None:
        self._shutdown = self._watchdog_expired = False
        super()._power_on_stage()

    # ------------------------------------------------------------------- status

    def _emit_status(self, out: list[Frame]) -> bool:
        """Fault and status flags and the error register; TPDO2 if they changed."""
        image = self.fault_flags << 16 | self.status_flags
        register = self._register()
        if image == self._statusword and register == self._error_register:
            return False
        self._statusword, self._error_register = image, register
        if self.nmt is not NmtState.OPERATIONAL or not self._tpdo2_on:
            return False
        out.append(self._tpdo2_frame())
        return True

    def sense(self, position: float, motor_velocity_rad_per_s: float, current_a: float,
              at_hard_stop: bool, dt_s: float) -> Sequence[Frame]:
        out = list(super().sense(position, motor_velocity_rad_per_s, current_a, at_hard_stop,
                                 dt_s))
        if not out and self.nmt is NmtState.OPERATIONAL and self._tpdo2_on:
            self._emit_status(out)  # the amps-limit flag follows the current
        return out or NO_FRAMES

    def _live_objects(self) -> dict[tuple[int, int], Callable[[], int]]:
        supply_dv = round(self._supply_mv / 100)
        return {
            (0x1001, 0): lambda: self._error_register,
            (0x2000, 1): lambda: round(self._latched_mv * PER_MILLE / self._supply_mv),
            (0x2100, 1): lambda: round(self._current_a * 10),
            (0x2103, 1): lambda: rad_per_s_to_rpm(self._motor_vel),
            (0x2104, 1): lambda: max(-INT32_LIMIT, min(INT32_LIMIT,
                                                       round(self._position / self._resolution))),
            (0x210D, 1): lambda: supply_dv,
            (0x210D, 2): lambda: supply_dv,
            (0x2111, 0): lambda: self.status_flags,
            (0x2112, 0): lambda: self.fault_flags,
        }
