"""What `status` tells an operator beyond the pose: the fastest the daemon jogs (its
configured caps, which a jog at the API's bounds moves at), which lane the excavation
is (its number since start-up and its parameters), and that docs/api.md documents the
reply's fields as the daemon gives them. The daemon and the emulated drives in
lock-step (rakectl.bench.tick's rig)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rakectl.bench.tick import LockstepRig
from rakectl.config.service import RtModeSetting
from rakectl.config.settings import Settings
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from tests.rig_commands import command, disarmed_rig

API_DOC = Path(__file__).resolve().parents[2] / "docs" / "api.md"
STATUS = b'{"cmd": "status"}'


@contextlib.contextmanager
def _armed(directory: Path, defaults: Settings | None = None) -> Iterator[LockstepRig]:
    """A lock-step rig's daemon, armed through the weight check; closed on the way out."""
    rig = LockstepRig(directory, defaults)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        yield rig
    finally:
        rig.close()


@pytest.fixture
def armed(tmp_path: Path) -> Iterator[LockstepRig]:
    """The default daemon, armed through the weight check."""
    with _armed(tmp_path) as rig:
        yield rig


def test_status_says_the_jog_caps_a_jog_at_the_apis_bound_moves_at(tmp_path: Path) -> None:
    """Configured below their defaults, the caps are the status's; a jog asked at the
    API's 0.25 m/s is accepted and moves the tip no faster than the cap the status
    says (before, the status did not say them: an operator saw the jog slower than asked
    with no figure to compare)."""
    defaults = Settings()
    defaults = dataclasses.replace(defaults, jog=dataclasses.replace(
        defaults.jog, max_tip_speed_m_per_s=0.04, max_r_speed_m_per_s=0.03,
        max_theta_speed_rad_per_s=0.12))
    with _armed(tmp_path, defaults) as rig:
        caps = command(rig, STATUS)["jog"]
        assert caps == {"max_tip_speed_m_per_s": 0.04, "max_r_speed_m_per_s": 0.03,
                        "max_theta_speed_rad_per_s": 0.12}
        start_m = command(rig, STATUS)["tip"]["reach_m"]
        for _ in range(10):  # 1 s of requests every 0.1 s, toward the robot
            assert command(rig, b'{"cmd": "jog", "space": "task", '
                                b'"reach_m_per_s": -0.25}')["state"] == "jog"
            for _ in range(100):
                rig.tick()
        moved_m = start_m - command(rig, STATUS)["tip"]["reach_m"]
    assert 0.5 * caps["max_tip_speed_m_per_s"] < moved_m <= caps["max_tip_speed_m_per_s"]


LANE = {"cmd": "excavate", "reach_far_m": 1.25, "reach_near_m": 1.15,
        "target_depth_m": 0.01, "depth_step_m": 0.005, "stroke_speed_m_per_s": 0.04}


def _excavate(rig: LockstepRig, **lane: float) -> dict[str, Any]:
    return command(rig, json.dumps({**LANE, **lane}).encode())


def _lane(rig: LockstepRig) -> dict[str, Any]:
    excavation = command(rig, STATUS)["excavation"]
    assert isinstance(excavation, dict)
    lane = excavation["lane"]
    assert isinstance(lane, dict)
    return lane


def test_each_lane_is_numbered_and_says_its_parameters(armed: LockstepRig) -> None:
    """The first lane since start-up is 1, the next 2, after a jog 3; a lane the
    daemon refuses takes no number. Each says its parameters as requested, the
    configured lane's where the request left one out (before, the status said only
    its progress: one lane could not be told from the next)."""
    rig, configured = armed, armed.daemon.settings.lane
    assert _excavate(rig) == {"state": "excavate", "lane": 1}
    rig.tick()
    assert _lane(rig) == {"number": 1, "reach_far_m": 1.25, "reach_near_m": 1.15,
                          "target_depth_m": 0.01, "depth_step_m": 0.005,
                          "stroke_speed_m_per_s": 0.04, "adaptive": configured.adaptive}
    command(rig, b'{"cmd": "stop"}')
    assert _lane(rig)["number"] == 1  # the stopped lane is still the status's
    with pytest.raises(CommandRejected, match="the lane leaves the workspace"):
        _excavate(rig, reach_far_m=9.0)
    second = {"cmd": "excavate", "reach_far_m": 1.3, "reach_near_m": 1.2,
              "target_depth_m": 0.02}
    assert command(rig, json.dumps(second).encode())["lane"] == 2
    assert _lane(rig) == {"number": 2, "reach_far_m": 1.3, "reach_near_m": 1.2,
                          "target_depth_m": 0.02, "depth_step_m": configured.depth_step_m,
                          "stroke_speed_m_per_s": configured.stroke_speed_m_per_s,
                          "adaptive": configured.adaptive}
    command(rig, b'{"cmd": "stop"}')
    command(rig, b'{"cmd": "jog", "space": "task", "height_m_per_s": 0.0}')
    assert "excavation" not in command(rig, STATUS)  # the jog's status, not a lane's
    command(rig, b'{"cmd": "stop"}')
    assert _excavate(rig)["lane"] == 3
    assert _lane(rig)["number"] == 3


def _documented(heading: str) -> list[str]:
    """The fields the first table after ``heading`` in docs/api.md names, in order."""
    text = API_DOC.read_text()
    table = re.search(rf"{re.escape(heading)}.*?\n\|---\|---\|\n(.*?)\n\n", text, re.S)
    assert table, f"docs/api.md has no table after {heading!r}"
    return [name for row in table.group(1).splitlines()
            for name in re.findall(r"`(\w+)`", row.split(" | ")[0])]


def test_the_documented_status_fields_are_the_daemons(armed: LockstepRig) -> None:
    """docs/api.md names every field of the status reply and of its excavation, and no
    other (the excavation's only while a lane is the newest)."""
    rig = armed
    idle = command(rig, STATUS)
    _excavate(rig)
    rig.tick()
    raking = command(rig, STATUS)
    assert set(_documented("## The `status` reply")) == set(raking) == set(idle) | {
        "excavation"}
    assert set(_documented("`excavation` holds:")) == set(raking["excavation"])


@pytest.mark.parametrize("mode", list(RtModeSetting))
def test_the_timing_verdict_says_whether_it_refuses_an_arming(tmp_path: Path,
                                                             mode: RtModeSetting) -> None:
    """Moments after start-up the loop has not measured its timing for long enough. Under
    rt_mode enforce status gives the verdict that refuses an arming; under the others
    the verdict is a warning and an arming goes on, which status now says (before, it
    read as a refusal, "arm again shortly", and `rakectl arm` then armed)."""
    s = Settings()
    s = dataclasses.replace(s, daemon=dataclasses.replace(s.daemon, rt_mode=mode))
    with disarmed_rig(tmp_path, s) as rig:
        check = command(rig, STATUS)["timing_check"]
        if mode is RtModeSetting.ENFORCE:
            assert check.endswith("daemon.arm_timing_s asks; arm again shortly"), check
            with pytest.raises(CommandRejected, match="cannot arm: the loop has measured"):
                command(rig, b'{"cmd": "arm"}')
        else:
            assert re.fullmatch(rf"a warning only, an arming goes on \(daemon\.rt_mode: "
                                rf"{mode.value}\): the loop has measured its timing for "
                                r"[0-9.]+ s of the 2 s daemon\.arm_timing_s asks", check), check
            command(rig, b'{"cmd": "arm"}')
            rig.until(DaemonState.ARMED, 8000)
