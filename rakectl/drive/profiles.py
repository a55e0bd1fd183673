"""Drive profiles (``drives.profile``): which EDS each drive type has, what bring-up
writes to it and reads back, and how its status reads as a CiA 402 state.

* ``cia402``, the project's own drives: ``dc_servo_drive.eds`` (r) and
  ``geared_motor_drive.eds`` (θ); CiA 402 over the controlword, the voltage 0x2000 in
  mV (:mod:`rakectl.protocol.codec`). Bring-up writes 0x2001 max voltage [mV], 0x2002
  current limit [mA], 0x2003 command watchdog [ms], 0x2004 encoder counts per turn.
* ``roboteq``, Roboteq-class motor controllers: ``roboteq_class_drive.eds`` for both;
  motor command 0x2000:01 in ‰ of the supply, no CiA 402 (:mod:`rakectl.protocol.roboteq`).
  Bring-up writes 0x3002 amps limit [0.1 A], 0x3001 command watchdog [ms] and 0x3003
  encoder counts per turn, and reads the battery voltage 0x210D:02 [0.1 V]: a drive
  whose supply reads above ``motors.<joint>.supply_voltage_v`` is refused, because the
  command is scaled by that setting (a higher supply would apply more than asked). It
  has no voltage limit of its own: the clamp's bound is that supply.

Both write the heartbeats (0x1017, 0x1016:1) and the SYNC counter overflow (0x1019;
bring-up clears the communication cycle period 0x1006 around it, as CiA 301 requires).
The hot path's codecs for each profile are chosen in :class:`~rakectl.drive.client.DriveClient`
at start-up.

:class:`DriveStart` ends each drive's bring-up the profile's way: a fault the previous
run left is cleared (a CiA 402 fault reset; a Roboteq-class release shutdown), waiting
for the drive to act on it in its own cycle, and the status the hot path starts from is
read.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.joints import (
    JOINTS,
    Joint,
    Parameter,
    allowed_range,
    drive_label,
    load_drive_od,
    motor_of,
    node_ids,
    od_variable,
)
from rakectl.errors import ConfigError, DriveFault, FrameError
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveState, decode_statusword
from rakectl.protocol.files import DriveProfile

EDS_FILES = {
    DriveProfile.CIA402: {Joint.R: "dc_servo_drive.eds", Joint.THETA: "geared_motor_drive.eds"},
    DriveProfile.ROBOTEQ: {Joint.R: "roboteq_class_drive.eds",
                           Joint.THETA: "roboteq_class_drive.eds"},
}
SUPPLY_OBJECT = (0x210D, 2, "battery voltage")  # Roboteq-class, 0.1 V
SYNC_OVERFLOW_OBJECT = (0x1019, 0)  # written only while the cycle period is 0 (CiA 301)
CYCLE_PERIOD_OBJECT = (0x1006, 0, "communication cycle period")  # µs
FAULT_RESET_HOLD_S = 0.010  # each controlword of a fault reset held this long: a drive
# samples its controlword once a cycle (CiA 402 drives: 1 … 10 ms)
FAULT_RESET_TIMEOUT_S = 0.5  # how long a drive may take to leave FAULT after the reset
FAULT_RESET_POLL_S = 0.005  # how often its status is read meanwhile
FAULTED = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)


def eds_file(drives: DrivesSettings, joint: Joint) -> str:
    """The EDS file of the drive of ``joint`` (in rakectl/protocol/eds/)."""
    return EDS_FILES[drives.profile][joint]


def drive_parameters(joint: Joint, drives: DrivesSettings,
                     motors: MotorsSettings) -> tuple[Parameter, ...]:
    """What bring-up writes to the drive of ``joint``, each with the limit it sets."""
    motor, key = motor_of(motors, joint), f"motors.{joint.name.lower()}"
    consumer = drives.controller_node_id << 16 | drives.heartbeat_timeout_ms
    common = (
        Parameter(0x1017, 0, "producer heartbeat", "ms", drives.heartbeat_period_ms,
                  "drives.heartbeat_period_ms", "heartbeat_period_ms"),
        Parameter(0x1016, 1, "consumer heartbeat", "", consumer,
                  "drives.controller_node_id/heartbeat_timeout_ms", "consumer_heartbeat"),
        Parameter(0x1019, 0, "SYNC counter overflow", "", drives.sync_counter_overflow,
                  "drives.sync_counter_overflow", "sync_counter_overflow"),
    )
    if drives.profile is DriveProfile.ROBOTEQ:
        return (
            Parameter(0x3002, 0, "amps limit", "× 0.1 A",  # rounded down: never above
                      math.floor(motor.current_limit_a * 10 + 1e-9),
                      f"{key}.current_limit_a", "current_limit_ma", 100),
            Parameter(0x3001, 0, "command watchdog", "ms", drives.watchdog_timeout_ms,
                      "drives.watchdog_timeout_ms", "watchdog_timeout_ms"),
            Parameter(0x3003, 0, "encoder counts/rev", "", motor.encoder_counts_per_rev,
                      f"{key}.encoder_counts_per_rev", "encoder_counts_per_rev"),
            *common,
        )
    return (
        Parameter(0x2001, 0, "max voltage", "mV", round(motor.supply_voltage_v * 1000),
                  f"{key}.supply_voltage_v", "max_voltage_mv"),
        Parameter(0x2002, 0, "current limit", "mA", round(motor.current_limit_a * 1000),
                  f"{key}.current_limit_a", "current_limit_ma"),
        Parameter(0x2003, 0, "watchdog timeout", "ms", drives.watchdog_timeout_ms,
                  "drives.watchdog_timeout_ms", "watchdog_timeout_ms"),
        Parameter(0x2004, 0, "encoder counts/rev", "", motor.encoder_counts_per_rev,
                  f"{key}.encoder_counts_per_rev", "encoder_counts_per_rev"),
        *common,
    )


def check_parameter_ranges(drives: DrivesSettings, motors: MotorsSettings) -> None:
    """Every parameter bring-up would write, within its drive's EDS limits (what bring-up
    checks before it sends anything; ``rakectl run --check`` without a bus): ConfigError
    naming the setting, the drive, the object and the EDS."""
    for joint, node_id in zip(JOINTS, node_ids(drives), strict=True):
        od = load_drive_od(eds_file(drives, joint), node_id)
        for p in drive_parameters(joint, drives, motors):
            low, high = allowed_range(od_variable(od, p.index, p.subindex))
            if not low <= p.value <= high:
                raise ConfigError(f"{p.setting}: {drive_label(joint, node_id)} {p.where()} "
                                  f"{p.name} = {p.value} {p.unit} is outside {low}..{high} "
                                  f"of {eds_file(drives, joint)}")


def state_of(profile: DriveProfile, status: int) -> DriveState:
    """The CiA 402 state a drive's status reads as: a CiA 402 drive's statusword, or a
    Roboteq-class drive's flags (:func:`rakectl.protocol.roboteq.flags_image`).
    FrameError for a statusword of no state."""
    if profile is DriveProfile.ROBOTEQ:
        return roboteq.state_of(status)
    return decode_statusword(status)


def supply_problem(supply_dv: int, supply_v: float) -> str | None:
    """Why a Roboteq-class drive whose battery reads ``supply_dv`` (0.1 V) must be refused
    when the configuration states ``supply_v``; None if it may be driven. A reading equal
    to it passes: the true supply may then be up to the reading's step above it (0.1 V,
    0.4 % at 24 V; docs/installation.md)."""
    if supply_dv * 100 > round(supply_v * 1000):
        return (f"its supply reads {supply_dv / 10:g} V (0x{SUPPLY_OBJECT[0]:04X}:"
                f"{SUPPLY_OBJECT[1]}), above the {supply_v:g} V the motor command is scaled "
                "by: it would apply more than commanded; set motors.<joint>.supply_voltage_v "
                "to the highest the supply reaches")
    return None


class DriveStart:
    """The end of each drive's bring-up, the profile's way, over the bring-up's own SDO
    transfers (``read``, ``write``; their failures are the bring-up's one-line ones)."""

    def __init__(self, profile: DriveProfile, read: Callable[[Joint, int, int, str], int],
                 write: Callable[[Joint, Parameter], None],
                 label: Callable[[Joint], str]) -> None:
        self._profile, self._read, self._write, self._label = profile, read, write, label

    def state_of(self, joint: Joint, status: int) -> DriveState:
        """:func:`state_of` for the drive of ``joint``: DriveFault naming it if none."""
        try:
            return state_of(self._profile, status)
        except FrameError as error:
            raise DriveFault(f"{self._label(joint)}: {error}") from error

    def status(self, joint: Joint) -> int:
        """The status the hot path starts from: the statusword 0x6041 of a CiA 402 drive; a
        Roboteq-class drive's fault and status flags, once its power stage is switched off
        by an emergency shutdown (0x200C), as a CiA 402 drive starts switched off."""
        if self._profile is DriveProfile.ROBOTEQ:
            self._write(joint, Parameter(0x200C, 0, "emergency shutdown", "", 1,
                                         "bring-up: the power stage off until armed"))
        return self.read_status(joint)

    def read_status(self, joint: Joint) -> int:
        """The status as :meth:`status` gives it, read only (a Roboteq-class drive's
        emergency shutdown not written again)."""
        if self._profile is not DriveProfile.ROBOTEQ:
            return self._read(joint, 0x6041, 0, "statusword")
        return (self._read(joint, 0x2112, 0, "fault flags") << 16
                | self._read(joint, 0x2111, 0, "status flags"))

    def clear_old_fault(self, joint: Joint) -> int:
        """A drive still in FAULT from the previous run (its controller's heartbeat was
        lost when that run ended) is fault-reset here, now that reset communication has
        cleared the cause: a rising edge of controlword bit 7 over SDO, each value held a
        drive cycle (a Roboteq-class drive: release shutdown 0x200D), then its status read
        until the fault is gone. Returns the code cleared (0x603F; the fault flags 0x2112),
        0 if none; DriveFault if the fault stays ``FAULT_RESET_TIMEOUT_S``."""
        if self._profile is DriveProfile.ROBOTEQ:
            return self._release_old_fault(joint)
        if self._state(joint) not in FAULTED:
            return 0
        code = self._read(joint, 0x603F, 0, "error code")
        for controlword in (0x0000, 0x0080):  # bit 7 low for a cycle, then its rising edge
            self._write(joint, Parameter(0x6040, 0, "controlword", "", controlword,
                                         "bring-up fault reset"))
            time.sleep(FAULT_RESET_HOLD_S)
        cleared = _until(lambda: self._state(joint) not in FAULTED)
        self._write(joint, Parameter(0x6040, 0, "controlword", "", 0x0000,
                                     "bring-up fault reset: bit 7 low again"))
        if not cleared:
            raise DriveFault(f"{self._label(joint)}: in FAULT (0x603F = 0x{code:04X}) since "
                             "before bring-up, and a fault reset does not clear it within "
                             f"{FAULT_RESET_TIMEOUT_S:g} s")
        return code

    def _state(self, joint: Joint) -> DriveState:
        return self.state_of(joint, self._read(joint, 0x6041, 0, "statusword"))

    def _release_old_fault(self, joint: Joint) -> int:
        """A Roboteq-class drive faulted (its error register 0x1001 set, or a fault flag
        but the emergency stop's: a power stage merely switched off is no fault) is
        released (0x200D); DriveFault if its fault stays."""
        flags = self._read(joint, 0x2112, 0, "fault flags")
        if not self._roboteq_faulted(joint, flags):
            return 0
        self._write(joint, Parameter(0x200D, 0, "release shutdown", "", 1,
                                     "bring-up fault reset"))
        if not _until(lambda: not self._roboteq_faulted(
                joint, self._read(joint, 0x2112, 0, "fault flags"))):
            raise DriveFault(f"{self._label(joint)}: fault flags 0x{flags:04X} (0x2112) since "
                             "before bring-up, and a release shutdown does not clear them "
                             f"within {FAULT_RESET_TIMEOUT_S:g} s")
        return flags

    def _roboteq_faulted(self, joint: Joint, flags: int) -> bool:
        return bool(flags & ~roboteq.FAULT_EMERGENCY_STOP
                    or self._read(joint, 0x1001, 0, "error register"))


def _until(cleared: Callable[[], bool]) -> bool:
    """Whether ``cleared()`` comes true within ``FAULT_RESET_TIMEOUT_S`` (asked every
    ``FAULT_RESET_POLL_S``): a drive acts on a command in its next cycle, not at once."""
    deadline_s = time.monotonic() + FAULT_RESET_TIMEOUT_S
    while not cleared():
        if time.monotonic() >= deadline_s:
            return False
        time.sleep(FAULT_RESET_POLL_S)
    return True
