"""Arming against the clamp's bound on held commands: the drives apply a command until
the next one or, without one, until their watchdog; the clamp carries
clamp.reaction_latency_s of that. The daemon (lock-step rig, emulated drives in one
process) refuses to arm under rt_mode enforce when the watchdog is longer than the clamp
carries, and arms when it is not."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.ground_params import BuriedObjects, StoneParams
from drivers.settings import EmulatorConfig
from rakectl.api.schema import Request, decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.config.service import RtModeSetting
from rakectl.config.settings import Settings, held_command_gap
from rakectl.core.control import workspace_of
from rakectl.core.kinematics import inverse
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from rakectl.protocol.codec import decode_rpdo
from rakectl.protocol.files import DriveProfile


def _enforcing(watchdog_ms: int) -> Settings:
    """rt_mode enforce with the timing check's limits out of the way (the lock-step rig's
    loop does not sleep), and this drive watchdog."""
    s = Settings()
    daemon = dataclasses.replace(s.daemon, rt_mode=RtModeSetting.ENFORCE, arm_timing_s=0.0,
                                 arm_max_latency_p99_us=1e6, arm_max_late_share=1.0,
                                 arm_max_latency_ratio=0.0)
    return dataclasses.replace(s, daemon=daemon,
                               drives=dataclasses.replace(s.drives,
                                                          watchdog_timeout_ms=watchdog_ms))


def _call(rig: LockstepRig, line: bytes) -> Mapping[str, Any]:
    request = decode_request(line)
    assert isinstance(request, Request), request
    return make_handler(rig.daemon)(request)


def _arm(rig: LockstepRig) -> Mapping[str, Any]:
    return _call(rig, b'{"cmd": "arm"}')


def test_the_robot_defaults_carry_the_watchdog() -> None:
    s = Settings()
    assert s.drives.watchdog_timeout_ms == 3
    assert s.clamp.reaction_latency_s == pytest.approx(0.004)
    assert held_command_gap(s) == ""
    slower = dataclasses.replace(s, rate_hz=500.0)  # 3 ms + 2 ms > 4 ms
    assert "plus one loop period (2 ms) = 5 ms" in held_command_gap(slower)


@pytest.mark.parametrize(("watchdog_ms", "armed"), [(20, False), (3, True)])
def test_enforce_arms_only_when_the_clamp_carries_the_watchdog(
        tmp_path: Path, watchdog_ms: int, armed: bool) -> None:
    rig = LockstepRig(tmp_path, _enforcing(watchdog_ms))
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        if not armed:
            with pytest.raises(CommandRejected) as refused:
                _arm(rig)
            message = str(refused.value)
            assert message.startswith("cannot arm: clamp.reaction_latency_s (4 ms) does not "
                                      "cover"), message
            assert "drives.watchdog_timeout_ms (20 ms) plus one loop period (1 ms)" in message
            assert "daemon.rt_mode: enforce" in message
            rig.daemon.tick()
            assert rig.daemon.state is DaemonState.DISARMED  # nothing changed
            return
        _arm(rig)
        rig.until(DaemonState.ARMED, 8000)
    finally:
        rig.close()


def _with_anvil(mount_n_per_m: float, side_n_per_m: float = 5.0e3
                ) -> tuple[Settings, EmulatorConfig]:
    """The daemon with the tine-mount check on, and the emulated robot with its anvil (a
    steel block whose top is 30 mm above the ground at 1 m of reach, its near side pressed
    15 mm above the ground) and this mount, started 60 mm above the ground beside it."""
    s = Settings()
    selftest = dataclasses.replace(s.selftest, press=True, anvil_reach_m=1.0,
                                   anvil_height_m=0.03, anvil_side_height_m=0.015)
    e = EmulatorConfig()
    anvil = StoneParams(reach_m=1.0, depth_m=-0.03, width_m=0.06, thickness_m=0.2)
    ground = dataclasses.replace(e.physics.ground, objects=BuriedObjects(stones=(anvil,)))
    arm = dataclasses.replace(e.physics.arm, tine_mount_stiffness_n_per_m=mount_n_per_m,
                              tine_mount_side_stiffness_n_per_m=side_n_per_m)
    r_m, theta_rad = inverse(workspace_of(s), 1.05, 0.06)
    emulator = dataclasses.replace(
        e, physics=dataclasses.replace(e.physics, ground=ground, arm=arm),
        drives=dataclasses.replace(e.drives, start_r_m=r_m, start_theta_rad=theta_rad))
    return dataclasses.replace(s, selftest=selftest), emulator


@pytest.mark.parametrize(("down_n_per_m", "side_n_per_m"), [(5.0e3, 0.0), (2.9e3, 5.8e3)],
                         ids=["rigid-sideways", "softer-down"])
def test_a_mount_not_as_configured_sideways_refuses_to_arm_naming_it(
        tmp_path: Path, down_n_per_m: float, side_n_per_m: float) -> None:
    """The press on the anvil's near side: a mount whose horizontal springs are blocked
    (the emulator's rigid sideways mount) faults the first arming, naming
    clamp.side_contact_stiffness_n_per_m; one whose vertical springs are half as stiff as
    the horizontal ones, each way within its own tolerance, faults naming the ratio."""
    settings, emulator = _with_anvil(down_n_per_m, side_n_per_m=side_n_per_m)
    rig = LockstepRig(tmp_path, settings, emulator)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        assert _arm(rig)["state"] == "checking"
        rig.until(DaemonState.FAULT, 30000)
        check = _call(rig, b'{"cmd": "status"}')["mount_check"]
        assert not check["passed"]
        assert check["stiffness_n_per_m"] == pytest.approx(down_n_per_m, rel=0.2)
        assert "sideways: stiffness " in check["message"]
        if side_n_per_m == 0.0:
            assert check["side_stiffness_n_per_m"] > 5.0 * 5e3 and check["ratio"] is None
            assert ("does not match 5000 N/m configured (clamp.side_contact_stiffness_n_per_m"
                    in check["message"])
        else:
            assert check["side_stiffness_n_per_m"] == pytest.approx(side_n_per_m, rel=0.2)
            assert check["ratio"] < 1.0 / settings.selftest.mount_ratio_tolerance
            assert "the mount is softer vertically than the other way" in check["message"]
    finally:
        rig.close()


@pytest.mark.parametrize(("mount_n_per_m", "profile"), [
    (5.0e3, DriveProfile.CIA402), (5.0e4, DriveProfile.CIA402), (5.0e3, DriveProfile.ROBOTEQ)])
def test_the_first_arming_presses_the_anvil_and_refuses_a_stiffer_mount(
        tmp_path: Path, mount_n_per_m: float, profile: DriveProfile) -> None:
    """selftest.press: the first arming runs the weight check, then the press on the
    anvil; the mount the clamp is configured for arms, one ten times stiffer faults naming
    both stiffnesses, and the status says why; the second arming checks again. On
    Roboteq-class drives (drives.profile: roboteq) the force is read through currents in
    0.1 A, and the mount still reads within 20 %."""
    settings, emulator = _with_anvil(mount_n_per_m)
    settings = dataclasses.replace(settings, drives=dataclasses.replace(
        settings.drives, profile=profile))
    emulator = dataclasses.replace(emulator, drives=dataclasses.replace(
        emulator.drives, profile=profile))
    rig = LockstepRig(tmp_path, settings, emulator)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        assert _arm(rig)["state"] == "checking"
        status = _call(rig, b'{"cmd": "status"}')
        assert status["weight_check"] == {"passed": None, "message": "running"}
        assert status["mount_check"] == {"passed": None, "message": "after the weight check"}
        end = DaemonState.ARMED if mount_n_per_m == 5.0e3 else DaemonState.FAULT
        rig.until(end, 30000)
        status = _call(rig, b'{"cmd": "status"}')
        assert status["weight_check"]["passed"]
        check = status["mount_check"]
        if end is DaemonState.ARMED:
            assert check["passed"] and check["stiffness_n_per_m"] == pytest.approx(5e3, rel=0.2)
            assert check["side_stiffness_n_per_m"] == pytest.approx(5e3, rel=0.2)
            assert check["side_expected_n_per_m"] == 5e3 and not check["side_at_least"]
            tip = status["tip"]  # back where the check started
            assert (tip["reach_m"], tip["depth_m"]) == pytest.approx((1.05, -0.06), abs=0.003)
            return
        assert not check["passed"] and check["stiffness_n_per_m"] > 1.2 * 5e3
        assert status["fault"] == check["message"]
        assert "does not match 5000 N/m configured (clamp.contact_stiffness_n_per_m" in (
            check["message"])
        assert rig.emulator.ground.truth.max_force_down_n < 20.0
        _call(rig, b'{"cmd": "reset"}')
        rig.until(DaemonState.DISARMED, 3000)
        assert _arm(rig)["state"] == "checking"  # the weight passed: the press alone
        status = _call(rig, b'{"cmd": "status"}')
        assert status["weight_check"]["passed"]
        assert status["mount_check"] == {"passed": None, "message": "running"}
        rig.until(DaemonState.FAULT, 30000)
    finally:
        rig.close()


def test_a_check_that_fails_sends_0_v_from_its_own_tick(tmp_path: Path) -> None:
    """The weight check judged on a tick (its tolerance set so that it fails): that tick
    still sent the voltages the check's reference had asked for, with the disabling
    controlword, and 0 V only from the next; the fault's own tick is 0 V now."""
    s = Settings()
    rig = LockstepRig(tmp_path, dataclasses.replace(
        s, selftest=dataclasses.replace(s.selftest, tolerance=0.001)))
    sent: list[tuple[int, int, int]] = []  # (tick, voltage mV, controlword) of the r drive
    send = rig.controller_bus.send

    def spy(msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0x201:
            sent.append((rig.daemon.ticks, *decode_rpdo(bytes(msg.data))))
        send(msg, timeout)

    rig.controller_bus.send = spy  # type: ignore[method-assign]
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        assert _arm(rig)["state"] == "checking"
        rig.until(DaemonState.FAULT, 30000)
        assert "weight check" in rig.daemon.fault_reason
        fault_tick = rig.daemon.ticks
        before = [mv for tick, mv, _ in sent if tick == fault_tick - 1]
        assert before and before[0] != 0  # holding against the weight until then
        assert [(mv, word) for tick, mv, word in sent if tick == fault_tick] == [(0, 0)]
    finally:
        rig.close()
