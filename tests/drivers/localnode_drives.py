"""Two drives built on the canopen package's LocalNode: a CANopen slave the project did not write.

Run as ``python -m tests.drivers.localnode_drives --config EMULATOR.yaml [--set KEY=VALUE]
[--truth CSV]`` in place of ``python -m drivers`` (the emulated bench's ``emulator_module``):
the controller then brings up and drives a slave whose CANopen side is not the emulator's.

canopen's ``LocalNode`` over each drive type's EDS does the CANopen work: the object
dictionary and its SDO server (expedited and segmented), the NMT states and the heartbeat
producer (0x1017, its own periodic task), the PDOs' layout read from the EDS and their
packing and unpacking (``PdoMap``). What LocalNode leaves to the device is here, kept thin:

- NMT reset node or reset communication from the bus: LocalNode only changes state; a
  CiA 301 device restores its communication objects (0x1000-0x1FFF; reset node: all) to
  their EDS values, sends its boot-up and enters PRE-OPERATIONAL.
- SYNC, in OPERATIONAL: TPDO1 sampled from the physics, the last RPDO1's voltage and
  controlword latched, then the physics advanced one period (lock-stepped, as the
  emulator's LOCKSTEP timing).
- CiA 402 device control: the standard's transitions for the commands the controller sends
  (shutdown, switch on, enable operation, disable voltage, quick stop, fault reset), from
  RPDO1 or an SDO write of 0x6040; the statusword in 0x6041 and TPDO2 on change.
- The command watchdog 0x2003: no RPDO1 for that long while OPERATION ENABLED is FAULT at
  0 V, with an EMCY 0x8250. Leaving OPERATIONAL also puts the output at 0 V.

With ``drives.profile: roboteq`` in the configuration, both are Roboteq-class drives over
``roboteq_class_drive.eds`` instead (:class:`LocalRoboteqDrive`): no CiA 402, the motor
command in ‰ of the supply, an emergency shutdown and its release, the command watchdog
0x3001 that stops the motor until the next command.

Not played: the heartbeat consumer 0x1016 (stored, no reaction), over-current faults, the
pre-defined error field, a PDO remapped over SDO (the maps are the EDS's, read at power-on).
The physics is the emulator's (drivers.arm.ArmPlant against drivers.ground.Ground), built
from the same configuration: it is not what this slave tests.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import signal
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import canopen

from drivers.arm import ArmPlant
from drivers.cli import load_config, open_bus
from drivers.drive_spec import DriveKind
from drivers.drives import workspace
from drivers.ground import Ground
from drivers.settings import EmulatorConfig
from rakectl.core.motor_model import MotorParams, joint_per_motor_rad, joint_resolution
from rakectl.protocol.files import DriveProfile

NMT_RESET_NODE, NMT_RESET_COMMUNICATION, NMT_ENTER_PRE_OPERATIONAL = 0x81, 0x82, 0x80
EMCY_COMMAND_WATCHDOG = 0x8250
ERROR_REGISTER_COMMUNICATION = 0x10  # 0x1001 bit 4
RPM_PER_RAD_PER_S = 30.0 / math.pi
TRUTH_HEADER = "t_s,sync_counter,r_m,theta_rad,voltage_r_v,voltage_theta_v,tip_reach_m," \
               "tip_height_m,force_down_n\n"

# CiA 402 statuswords (bits 0-3, 5, 6) of the states this drive takes
SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON = 0x0040, 0x0021, 0x0023
OPERATION_ENABLED, FAULT = 0x0027, 0x0008


def next_state(state: int, controlword: int, previous_controlword: int) -> int:
    """One CiA 402 transition for a controlword (the standard's table, quick stop taken
    straight to SWITCH ON DISABLED)."""
    if state == FAULT:
        rising = controlword & 0x80 and not previous_controlword & 0x80
        return SWITCH_ON_DISABLED if rising else FAULT
    if controlword & 0x80:
        return state
    if controlword & 0x02 == 0 or controlword & 0x06 == 0x02:  # disable voltage, quick stop
        return SWITCH_ON_DISABLED
    if controlword & 0x07 == 0x06:  # shutdown
        return READY_TO_SWITCH_ON
    if controlword & 0x0F == 0x07:  # switch on (or disable operation)
        return SWITCHED_ON if state in (READY_TO_SWITCH_ON, OPERATION_ENABLED) else state
    if controlword & 0x0F == 0x0F:  # enable operation: 3 then 4, one per SYNC
        return {READY_TO_SWITCH_ON: SWITCHED_ON, SWITCHED_ON: OPERATION_ENABLED}.get(state, state)
    return state


class LocalDrive:
    """One drive: a LocalNode, its CiA 402 state and its latched command."""

    def __init__(self, network: canopen.Network, node_id: int, kind: DriveKind,
                 motor: MotorParams, serial_number: int) -> None:
        self.node = canopen.LocalNode(node_id, str(kind.eds_path))
        self.motor, self.serial_number = motor, serial_number
        network.add_node(self.node)
        self.node.add_write_callback(self._on_write)
        self.state, self.controlword, self.previous_controlword = SWITCH_ON_DISABLED, 0, 0
        self.voltage_mv, self.error_register = 0, 0
        self.last_rpdo_s: float | None = None
        self._sent_status: tuple[int, int] | None = None
        self.node.tpdo.read(from_od=True)
        self.node.rpdo.read(from_od=True)
        self.node.rpdo.subscribe()
        self.node.rpdo[1].add_callback(self._on_rpdo1)
        self.reset(node=True)

    # ----------------------------------------------------------------- NMT

    def reset(self, node: bool) -> None:
        """Reset node (all objects) or communication (0x1000-0x1FFF): EDS values, boot-up,
        PRE-OPERATIONAL."""
        store = self.node.data_store
        for index in list(store):
            if node or 0x1000 <= index <= 0x1FFF:
                del store[index]
        self.node.sdo[0x1018][4].raw = self.serial_number
        if node:
            self.state, self.error_register = SWITCH_ON_DISABLED, 0
        self.voltage_mv, self.last_rpdo_s, self._sent_status = 0, None, None
        self._store_status()
        self.node.nmt.send_command(NMT_RESET_NODE)  # state INITIALISING: LocalNode sends boot-up
        self.node.nmt.send_command(NMT_ENTER_PRE_OPERATIONAL)  # and starts its heartbeat

    def on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """After LocalNode's own handler (subscribed first): what a device does on reset."""
        if len(data) == 2 and data[1] in (0, self.node.id):
            if data[0] in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
                self.reset(node=data[0] == NMT_RESET_NODE)
            elif not self.operational:
                self.voltage_mv = 0

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    # ----------------------------------------------------------------- commands

    def _on_rpdo1(self, pdo: canopen.pdo.PdoMap) -> None:
        if self.operational:
            self.voltage_mv = pdo[0x2000].raw
            self.controlword = pdo[0x6040].raw
            self.last_rpdo_s = pdo.timestamp

    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index == 0x6040:  # controlword over SDO (the bring-up's fault reset)
            self._apply(int.from_bytes(data, "little"))

    def _apply(self, controlword: int) -> None:
        self.state = next_state(self.state, controlword, self.previous_controlword)
        self.previous_controlword = controlword
        self._store_status()

    def latch(self, now_s: float) -> float:
        """At SYNC: the command watchdog, the latched controlword; the voltage to apply."""
        watchdog_s = self.node.sdo[0x2003].raw / 1000.0
        if (self.state == OPERATION_ENABLED and watchdog_s > 0 and self.last_rpdo_s is not None
                and now_s - self.last_rpdo_s > watchdog_s):
            self.state, self.error_register = FAULT, self.error_register | 0x01
            self.error_register |= ERROR_REGISTER_COMMUNICATION
            self.node.emcy.send(EMCY_COMMAND_WATCHDOG, self.error_register)
            self._store_status()
        else:
            self._apply(self.controlword)
        if self.state != OPERATION_ENABLED or not self.operational:
            return 0.0
        limit_mv = self.node.sdo[0x2001].raw
        return max(-limit_mv, min(limit_mv, self.voltage_mv)) / 1000.0

    # ----------------------------------------------------------------- feedback

    def _store_status(self) -> None:
        self.node.sdo[0x6041].raw = self.state
        self.node.sdo[0x1001].raw = self.error_register

    def send_status(self) -> None:
        """TPDO2 when the statusword or the error register changed (transmission type 255)."""
        status = (self.state, self.error_register)
        if status != self._sent_status:
            tpdo2 = self.node.tpdo[2]
            tpdo2[0x6041].raw, tpdo2[0x1001].raw = status
            tpdo2.transmit()
            self._sent_status = status

    def send_sample(self, position: float, velocity: float, current_a: float) -> None:
        """TPDO1: position [counts], motor velocity [rpm], current [mA] (joint units in)."""
        encoder = dataclasses.replace(self.motor, encoder_counts_per_rev=self.node.sdo[0x2004].raw)
        tpdo1 = self.node.tpdo[1]
        tpdo1[0x6064].raw = round(position / joint_resolution(encoder))
        rpm = round(velocity / joint_per_motor_rad(self.motor) * RPM_PER_RAD_PER_S)
        tpdo1[0x606C].raw = max(-32767, min(32767, rpm))
        tpdo1[0x2100].raw = max(-32767, min(32767, round(current_a * 1000.0)))
        tpdo1.transmit()


class LocalRoboteqDrive(LocalDrive):
    """A Roboteq-class drive on LocalNode (``drives.profile: roboteq``): no CiA 402; the
    motor command 0x2000:01 in ‰ of the supply, driven in OPERATIONAL unless an emergency
    shutdown (0x200C, until a release 0x200D) holds it off; the command watchdog 0x3001
    stops it (status flag 5) until the next command; feedback in its own objects and units
    (TPDO1: counts, rpm, 0.1 A; TPDO2: fault and status flags)."""

    def __init__(self, network: canopen.Network, node_id: int, motor: MotorParams,
                 serial_number: int) -> None:
        self.shutdown, self.expired, self.per_mille = False, False, 0
        super().__init__(network, node_id, DriveKind.ROBOTEQ_CLASS, motor, serial_number)

    def reset(self, node: bool) -> None:
        if node:
            self.shutdown = False
        self.expired, self.per_mille = False, 0
        super().reset(node)
        self.node.sdo[0x210D][2].raw = round(self.motor.supply_voltage_v * 10)

    def _on_rpdo1(self, pdo: canopen.pdo.PdoMap) -> None:
        if self.operational:
            self.per_mille, self.last_rpdo_s, self.expired = pdo[0].raw, pdo.timestamp, False

    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index in (0x200C, 0x200D):
            self.shutdown = index == 0x200C
            self._store_status()

    def latch(self, now_s: float) -> float:
        watchdog_s = self.node.sdo[0x3001].raw / 1000.0
        if (not self.shutdown and watchdog_s > 0 and self.last_rpdo_s is not None
                and now_s - self.last_rpdo_s > watchdog_s):
            self.expired, self.per_mille = True, 0
        self._store_status()
        if self.shutdown or self.expired or not self.operational:
            return 0.0
        command = max(-1000, min(1000, self.per_mille))
        return command * self.motor.supply_voltage_v / 1000.0

    def _flags(self) -> tuple[int, int]:
        status = 0x0001 | (0x0008 if self.shutdown or self.expired else 0) | (
            0x0020 if self.expired else 0)
        return (0x0010 if self.shutdown else 0), status

    def _store_status(self) -> None:
        faults, status = self._flags()
        self.node.sdo[0x2112].raw, self.node.sdo[0x2111].raw = faults, status

    def send_status(self) -> None:
        status = self._flags()
        if status != self._sent_status:
            tpdo2 = self.node.tpdo[2]
            tpdo2[0].raw, tpdo2[1].raw = status
            tpdo2.transmit()
            self._sent_status = status

    def send_sample(self, position: float, velocity: float, current_a: float) -> None:
        encoder = dataclasses.replace(self.motor, encoder_counts_per_rev=self.node.sdo[0x3003].raw)
        tpdo1 = self.node.tpdo[1]
        tpdo1[0].raw = round(position / joint_resolution(encoder))
        rpm = round(velocity / joint_per_motor_rad(self.motor) * RPM_PER_RAD_PER_S)
        tpdo1[1].raw = max(-32767, min(32767, rpm))
        tpdo1[2].raw = max(-32767, min(32767, round(current_a * 10.0)))
        tpdo1.transmit()


class LocalDrives:
    """Both drives and the physics on one canopen Network."""

    def __init__(self, config: EmulatorConfig, network: canopen.Network,
                 truth: TextIO | None) -> None:
        d, p = config.drives, config.physics
        if d.profile is DriveProfile.ROBOTEQ:
            self.drives: tuple[LocalDrive, LocalDrive] = (
                LocalRoboteqDrive(network, d.r_node_id, p.motor_r, d.r_serial_number),
                LocalRoboteqDrive(network, d.theta_node_id, p.motor_theta, d.theta_serial_number))
        else:
            self.drives = (LocalDrive(network, d.r_node_id, DriveKind.DC_SERVO, p.motor_r,
                                      d.r_serial_number),
                           LocalDrive(network, d.theta_node_id, DriveKind.GEARED_MOTOR,
                                      p.motor_theta, d.theta_serial_number))
        self.plant = ArmPlant(p.arm, p.motor_r, p.motor_theta, workspace(config), p.substep_s,
                              p.seed)
        self.plant.set_pose_at_rest(d.start_r_m, d.start_theta_rad)
        self.ground = Ground(p.ground, p.seed)
        self.period_s, self.time_s, self.truth = d.control_period_s, 0.0, truth
        for drive in self.drives:
            network.subscribe(0, drive.on_nmt)
        network.subscribe(0x80, self.on_sync)
        if truth is not None:
            truth.write(TRUTH_HEADER)

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        r, theta = self.drives
        if not (r.operational and theta.operational):
            return
        m = self.plant.measure()
        r.send_sample(m.r_m, m.r_vel_m_per_s, m.current_r_a)
        theta.send_sample(m.theta_rad, m.theta_vel_rad_per_s, m.current_theta_a)
        voltage_r, voltage_theta = r.latch(timestamp), theta.latch(timestamp)
        for drive in self.drives:
            drive.send_status()
        self.plant.step(voltage_r, voltage_theta, self.ground, self.period_s)
        self.time_s += self.period_s
        if self.truth is not None:
            reach, height = self.plant.tip_m()
            self.truth.write(f"{self.time_s:.6f},{data[0] if data else 0},{self.plant.r_m:.7f},"
                             f"{self.plant.theta_rad:.7f},{voltage_r:.4f},{voltage_theta:.4f},"
                             f"{reach:.6f},{height:.6f},"
                             f"{self.ground.truth.force_down_n:.4f}\n")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.drivers.localnode_drives",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, required=True)
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--truth", type=Path)
    args = parser.parse_args(argv)
    config = load_config(args.config, args.overrides)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    bus = open_bus(config.bus)
    network = canopen.Network(bus)
    network.connect()  # its Notifier on the bus given
    truth = args.truth.open("w") if args.truth else None
    try:
        drives = LocalDrives(config, network, truth)
        ids = ",".join(str(d.node.id) for d in drives.drives)
        print(f"emulator: ready node-ids {ids} on {config.bus.interface.value}:"
              f"{config.bus.channel} (canopen LocalNode)", flush=True)
        stop.wait()
    finally:
        network.disconnect()
        if truth is not None:
            truth.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
