"""Arming against the clamp's bound on held commands: the drives apply a command until
the next one or, without one, until their watchdog; the clamp carries
clamp.reaction_latency_s of that. The daemon (lock-step rig, emulated drives in one
process) refuses to arm under rt_mode enforce when the watchdog is longer than the clamp
carries, and arms when it is not."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from rakectl.api.schema import decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.config.service import RtModeSetting
from rakectl.config.settings import Settings, held_command_gap
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected


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


def _arm(rig: LockstepRig) -> dict[str, object]:
    request = decode_request(b'{"cmd": "arm"}')
    assert not isinstance(request, str), request
    return make_handler(rig.daemon)(request)


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
