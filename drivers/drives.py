"""The emulated drives a configuration describes: their specs, the node each type calls
for, and the workspace of the arm behind them (pure)."""

from __future__ import annotations

from drivers.drive_spec import DriveKind, DriveSpec
from drivers.node import DriveNode
from drivers.roboteq import RoboteqNode
from drivers.settings import EmulatorConfig
from rakectl.core.kinematics import Workspace
from rakectl.protocol.files import DriveProfile


def workspace(config: EmulatorConfig) -> Workspace:
    g = config.geometry
    return Workspace(g.pivot_height_m, g.r_min_m, g.r_max_m, g.theta_min_rad, g.theta_max_rad)


def drive_specs(config: EmulatorConfig) -> tuple[DriveSpec, DriveSpec]:
    """(r drive, θ drive) as the configuration describes them."""
    d, p = config.drives, config.physics
    roboteq = d.profile is DriveProfile.ROBOTEQ
    return (
        DriveSpec(d.r_node_id, DriveKind.ROBOTEQ_CLASS if roboteq else DriveKind.DC_SERVO,
                  p.motor_r, d.r_serial_number, d.controller_node_id, d.overcurrent_time_s),
        DriveSpec(d.theta_node_id, DriveKind.ROBOTEQ_CLASS if roboteq else DriveKind.GEARED_MOTOR,
                  p.motor_theta, d.theta_serial_number, d.controller_node_id,
                  d.overcurrent_time_s),
    )


def drive_node(spec: DriveSpec) -> DriveNode:
    """The emulated drive its type calls for."""
    return RoboteqNode(spec) if spec.kind is DriveKind.ROBOTEQ_CLASS else DriveNode(spec)
