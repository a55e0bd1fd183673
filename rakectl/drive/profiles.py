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

Both write the heartbeats (0x1017, 0x1016:1) and the SYNC counter overflow (0x1019).
The hot path's codecs for each profile are chosen in :class:`~rakectl.drive.client.DriveClient`
at start-up.
"""

from __future__ import annotations

import math

from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.joints import Joint, Parameter, motor_of
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveState, decode_statusword
from rakectl.protocol.files import DriveProfile

EDS_FILES = {
    DriveProfile.CIA402: {Joint.R: "dc_servo_drive.eds", Joint.THETA: "geared_motor_drive.eds"},
    DriveProfile.ROBOTEQ: {Joint.R: "roboteq_class_drive.eds",
                           Joint.THETA: "roboteq_class_drive.eds"},
}
SUPPLY_OBJECT = (0x210D, 2, "battery voltage")  # Roboteq-class, 0.1 V


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
