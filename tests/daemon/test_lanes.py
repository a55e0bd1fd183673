"""The daemon raking a lane with the emulated drives in one process, lock-step
(rakectl.bench.tick's rig): drives that answer late (the emulator served only after a
pause now and then, so the daemon reads the same feedback for several ticks and then
several answers at once, as on a loaded bench), and a stone under the plunge."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.cli import load_config
from drivers.roboteq import RoboteqNode
from drivers.settings import EmulatorConfig
from rakectl.bench.tick import LockstepRig
from rakectl.config.settings import Settings
from rakectl.daemon.states import DaemonState
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.roboteq import FAULT_EMERGENCY_STOP
from tests.rig_commands import command

LANE = (b'{"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 1.15, '
        b'"target_depth_m": 0.01, "depth_step_m": 0.01}')


@contextlib.contextmanager
def _raking(tmp_path: Path, lane: bytes, defaults: Settings | None = None,
            emulator: EmulatorConfig | None = None) -> Iterator[LockstepRig]:
    """A lock-step rig brought up, armed through the weight check, the lane started."""
    rig = LockstepRig(tmp_path, defaults, emulator)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        command(rig, lane)
        yield rig
    finally:
        rig.close()


def _rake(rig: LockstepRig, limit: int = 30_000) -> float:
    """Tick in lock-step while the lane runs; the largest true force on the ground."""
    daemon, truth = rig.daemon, rig.emulator.ground.truth
    force_max_n = 0.0
    for _ in range(limit):
        if daemon.state is not DaemonState.EXCAVATE:
            break
        rig.tick()
        force_max_n = max(force_max_n, truth.force_down_n)
    return force_max_n


def test_a_lane_with_answers_15_ms_late_every_150_ms_is_raked_to_its_depth(
        tmp_path: Path) -> None:
    """Before the force estimate and the plunge's settle check counted sampling instants
    (Feedback.samples) instead of ticks, this lane read F̂ up to 208 N in free space and
    once ended at 5.9 mm by a force-limit stop reported as done; on time it reads 48 N."""
    defaults = Settings()  # the emulated bench's patience with late feedback and commands
    defaults = dataclasses.replace(
        defaults, drives=dataclasses.replace(defaults.drives, feedback_timeout_cycles=25,
                                             watchdog_timeout_ms=100))
    with _raking(tmp_path, LANE, defaults) as rig:
        daemon, truth = rig.daemon, rig.emulator.ground.truth
        lowest_m = force_max_n = 0.0
        for k in range(60_000):
            if daemon.state is not DaemonState.EXCAVATE:
                break
            daemon.tick()
            rig.now_s += daemon.dt_s
            if k % 150 >= 15:  # silent for 15 ticks, then every answer at once
                rig.emulator.service(0.0)
            lowest_m = min(lowest_m, rig.emulator.plant.tine_m()[1])
            force_max_n = max(force_max_n, truth.force_down_n)
        status = command(rig, b'{"cmd": "status"}')
    assert daemon.state is DaemonState.HOLD, daemon.fault_reason
    excavation = status["excavation"]
    assert isinstance(excavation, dict)
    assert excavation["done"] and not excavation["stopped_by_force"], excavation
    assert excavation["depth_m"] == 0.01
    assert lowest_m < -0.008  # the tines really went down to the lane's depth
    assert daemon.f_hat_max_n < 120.0
    assert force_max_n < 90.0
    print(f"\nlate answers: F̂ max {daemon.f_hat_max_n:.1f} N, true {force_max_n:.1f} N, "
          f"tines down to {1e3 * lowest_m:.1f} mm")


def test_a_plunge_onto_a_stone_ends_the_lane_with_the_object_found(tmp_path: Path) -> None:
    """The plunge's reference waits for a tine that can go no deeper (lane._blocked): the
    daemon, like the simulations, ends the lane there with the object found (before, it
    watched only strokes, and the lane waited above the stone for ever)."""
    stone = ["physics.ground.objects.stones=[{reach_m: 1.25, depth_m: 0.002, "
             "width_m: 0.2, thickness_m: 0.1}]"]  # 28 mm of the mount's travel: 140 N
    lane = (b'{"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 1.15, '
            b'"target_depth_m": 0.03, "depth_step_m": 0.03}')
    with _raking(tmp_path, lane, emulator=load_config(None, stone)) as rig:
        daemon = rig.daemon
        force_max_n = _rake(rig)
        status = command(rig, b'{"cmd": "status"}')
    assert daemon.state is DaemonState.HOLD, daemon.state
    excavation = status["excavation"]
    assert isinstance(excavation, dict)
    found = excavation["object_found"]
    assert isinstance(found, dict), excavation
    assert found["reach_m"] == pytest.approx(1.25, abs=0.01)
    assert 0.0 <= found["depth_m"] < 0.03  # the arm's depth: the stone's top and the mount's
    assert force_max_n < 90.0


def test_on_roboteq_class_drives_the_daemon_arms_rakes_and_switches_them_off(
        tmp_path: Path) -> None:
    """drives.profile: roboteq on both sides (the emulator plays Roboteq-class drives): the
    weight check passes through their 0.1 A currents, the lane is raked to its depth on
    commands in ‰ of the supply, and disarming switches their power stages off (emergency
    shutdown) so that a command would not drive them."""
    defaults = Settings()
    defaults = dataclasses.replace(defaults, drives=dataclasses.replace(
        defaults.drives, profile=DriveProfile.ROBOTEQ))
    emulator = load_config(None, ["drives.profile=roboteq"])
    with _raking(tmp_path, LANE, defaults, emulator) as rig:
        daemon = rig.daemon
        assert all(isinstance(node, RoboteqNode) for node in rig.emulator.nodes)
        force_max_n = _rake(rig)
        status = command(rig, b'{"cmd": "status"}')
        assert daemon.state is DaemonState.HOLD, daemon.fault_reason
        excavation = status["excavation"]
        assert isinstance(excavation, dict)
        assert excavation["done"] and excavation["depth_m"] == 0.01, excavation
        assert force_max_n < 90.0
        command(rig, b'{"cmd": "disarm"}')
        for _ in range(200):
            rig.tick()
        assert daemon.state is DaemonState.DISARMED
        for node in rig.emulator.nodes:
            assert node.fault_flags == FAULT_EMERGENCY_STOP and node.output_voltage_v == 0.0
        assert daemon.client.feedback.state == [DriveState.SWITCH_ON_DISABLED] * 2
