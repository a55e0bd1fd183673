"""Why the drives' power stage must short the motors whenever it is not driving them (a
hardware requirement, docs/safety.md): every fault, stop and watchdog trip leaves the rake
at 0 V, falling under its unbalanced weight, and the bound on that fall is the motors'
back-EMF braking it. The emulator's own arm, from rest above a mine's plate at the
ground's surface, both motors at 0 V for 1.5 s: the bridge driven at 0 V (the motor
shorted) against a bridge turned off (the motor free, as many CiA 402 drives leave it in
SWITCH ON DISABLED or FAULT unless configured otherwise)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from drivers.arm import ArmPlant
from drivers.drives import workspace
from drivers.ground import Ground
from drivers.ground_params import BuriedObjects, MineParams
from drivers.motor import Bridge
from drivers.settings import EmulatorConfig
from rakectl.core import kinematics


def _fall(bridge: Bridge, reach_m: float, above_m: float) -> tuple[float, bool]:
    """The largest force on the plate and whether the mine fired."""
    config = EmulatorConfig()
    physics, ws = config.physics, workspace(config)
    mine = MineParams(reach_m=reach_m, depth_m=0.0, width_m=0.1)
    ground = Ground(replace(physics.ground, objects=BuriedObjects(mines=(mine,))), physics.seed)
    plant = ArmPlant(physics.arm, physics.motor_r, physics.motor_theta, ws, physics.substep_s,
                     physics.seed)
    plant.set_pose_at_rest(*kinematics.inverse(ws, reach_m, above_m))
    plant.set_bridges(bridge, bridge)
    for _ in range(1500):
        plant.step(0.0, 0.0, ground, 0.001)
    body = ground.bodies[0]
    return body.peak_down_n, body.activated


@pytest.mark.parametrize("above_m", [0.06, 0.1])
def test_a_rake_at_0_v_falls_within_the_limit_only_with_its_motors_shorted(
        above_m: float) -> None:
    """Measured at reach 1.4 m: shorted, 9.8 N from 100 mm; free, 92.2 N from 100 mm (the
    mine fires) and 73 N from 60 mm."""
    shorted_n, shorted_fired = _fall(Bridge.DRIVEN, 1.4, above_m)
    free_n, _ = _fall(Bridge.OPEN, 1.4, above_m)
    assert shorted_n < 20.0 and not shorted_fired
    assert free_n > 3.0 * shorted_n and free_n > 60.0
