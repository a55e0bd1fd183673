"""Settings of the emulated hardware: arm, motors, ground (pure declarations)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar

from drivers.arm import DEFAULT_SUBSTEP_S
from drivers.ground_params import GroundParams
from drivers.mechanics import ArmParams
from rakectl.config.declare import section, setting
from rakectl.config.service import BusSettings
from rakectl.config.settings import GeometrySettings, node_id_clashes
from rakectl.core.motor_model import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, MotorParams
from rakectl.protocol.files import DriveProfile


@dataclass(frozen=True)
class EmulatorSettings:
    """The physics behind the drives: what the real robot would be."""

    arm: ArmParams = section(ArmParams)
    motor_r: MotorParams = section(MotorParams, R_MOTOR_DEFAULT,
                                   "Motor, lead screw and drive of the sliding joint r.")
    motor_theta: MotorParams = section(MotorParams, THETA_MOTOR_DEFAULT,
                                       "Motor, gearhead and drive of the rotary joint θ.")
    ground: GroundParams = section(GroundParams)
    substep_s: float = setting(DEFAULT_SUBSTEP_S, "Integration substep of the arm and ground.",
                               unit="s", gt=0, le=1e-3)
    seed: int = setting(0, "Seed of soil heterogeneity and sensor noise.", ge=0, le=2**32 - 1)


# --------------------------------------------------------------------------- the emulator process


class TimingMode(enum.StrEnum):
    """How the emulator's physics keeps time."""

    LOCKSTEP = "lockstep"  # one control period per SYNC: deterministic (tests, slow VMs)
    WALLCLOCK = "wallclock"  # follows the wall clock: a controller that runs late sees it


@dataclass(frozen=True)
class EmulatedDrivesSettings:
    """The two emulated drives: node-IDs, identity, timing and the arm's start pose."""

    r_node_id: int = setting(1, "Node-ID of the r (DC-servo) drive.", ge=1, le=127)
    theta_node_id: int = setting(2, "Node-ID of the θ (geared-motor) drive.", ge=1, le=127)
    controller_node_id: int = setting(
        10, "Node-ID whose heartbeat the drives consume (0x1016 sub 1 at power-on).",
        ge=1, le=127)
    r_serial_number: int = setting(1001, "Serial number of the r drive (0x1018 sub 4).",
                                   ge=0, le=2**32 - 1)
    theta_serial_number: int = setting(2001, "Serial number of the θ drive (0x1018 sub 4).",
                                       ge=0, le=2**32 - 1)
    profile: DriveProfile = setting(
        DriveProfile.CIA402, "Which drives the emulator plays: cia402, the project's own "
        "(dc_servo_drive.eds and geared_motor_drive.eds: CiA 402, voltage in mV); roboteq, "
        "two Roboteq-class motor controllers (roboteq_class_drive.eds: motor command in ‰ "
        "of the supply, no CiA 402; drivers/roboteq.py).")
    timing: TimingMode = setting(TimingMode.LOCKSTEP, "lockstep: one control period of "
                                 "physics per SYNC; wallclock: physics follows the wall clock.")
    control_period_s: float = setting(0.001, "Physics advanced per SYNC (lockstep) and the "
                                      "quantum of the wall clock (wallclock).", unit="s",
                                      gt=0, le=0.1)
    max_catch_up_s: float = setting(0.05, "Most physics one catch-up may advance; wall time "
                                    "beyond it is dropped (and counted).", unit="s",
                                    gt=0, le=1)
    overcurrent_time_s: float = setting(
        0.5, "Current at its limit this long while enabled → EMCY OVER_CURRENT, fault.",
        unit="s", gt=0, le=60)
    start_r_m: float = setting(1.0, "Rake length at power-on (at rest).", unit="m",
                               gt=0, le=10)
    start_theta_rad: float = setting(0.2, "Joint angle at power-on (at rest).", unit="rad",
                                     gt=-1.5, lt=1.5)


@dataclass(frozen=True)
class FaultInjectionSettings:
    """Faults injected at the emulator's bus edge (tests): lost frames, a silent drive."""

    seed: int = setting(0, "Seed of the loss draws.", ge=0, le=2**32 - 1)
    rx_loss_probability: float = setting(0.0, "Chance that a drive misses a received frame.",
                                         ge=0, le=1)
    tx_loss_probability: float = setting(0.0, "Chance that a frame a drive sends is lost.",
                                         ge=0, le=1)
    loss_node_id: int = setting(0, "Drive the losses apply to; 0 = both.", ge=0, le=127)
    silence_node_id: int = setting(0, "Drive that stops sending anything; 0 = none.",
                                   ge=0, le=127)
    silence_after_s: float = setting(0.0, "When it goes silent, after the emulator started.",
                                     unit="s", ge=0, le=1e6)


@dataclass(frozen=True)
class EmulatorConfig:
    """Root of config/emulator.yaml: the emulated drives on the bus and the physics behind."""

    # a scenario's section emulator: is this file's physics: (its own, with the ground)
    OTHER_NAMES: ClassVar[dict[str, str]] = {"emulator": "physics"}

    bus: BusSettings = section(BusSettings)
    geometry: GeometrySettings = section(GeometrySettings)
    physics: EmulatorSettings = section(EmulatorSettings)
    drives: EmulatedDrivesSettings = section(EmulatedDrivesSettings)
    faults: FaultInjectionSettings = section(FaultInjectionSettings)

    def cross_checks(self) -> list[tuple[str, str]]:
        """Constraints between options: (dotted key, message) for each violation."""
        g, d, f = self.geometry, self.drives, self.faults
        errors: list[tuple[str, str]] = []
        if not g.r_max_m > g.r_min_m:
            errors.append(("geometry.r_max_m", f"must be > geometry.r_min_m ({g.r_min_m:g})"))
        if not g.theta_max_rad > g.theta_min_rad:
            errors.append(("geometry.theta_max_rad",
                           f"must be > geometry.theta_min_rad ({g.theta_min_rad:g})"))
        errors.extend(node_id_clashes({"drives.r_node_id": d.r_node_id,
                                       "drives.theta_node_id": d.theta_node_id,
                                       "drives.controller_node_id": d.controller_node_id}))
        if not g.r_min_m < d.start_r_m < g.r_max_m:
            errors.append(("drives.start_r_m", "must lie strictly inside geometry.r_min_m.."
                           "geometry.r_max_m (at a limit the hard stop would fault the drive)"))
        if not g.theta_min_rad < d.start_theta_rad < g.theta_max_rad:
            errors.append(("drives.start_theta_rad", "must lie strictly inside "
                           "geometry.theta_min_rad..geometry.theta_max_rad"))
        periods = d.control_period_s / self.physics.substep_s
        if abs(periods - round(periods)) > 1e-6 * periods:
            errors.append(("drives.control_period_s", "must be a whole number of "
                           f"physics.substep_s ({self.physics.substep_s:g})"))
        if d.max_catch_up_s < d.control_period_s:
            errors.append(("drives.max_catch_up_s", "must be >= drives.control_period_s"))
        for key, node_id in (("faults.loss_node_id", f.loss_node_id),
                             ("faults.silence_node_id", f.silence_node_id)):
            if node_id not in (0, d.r_node_id, d.theta_node_id):
                errors.append((key, "must be 0 or the node-ID of a drive"))
        return errors
