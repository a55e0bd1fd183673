"""The daemon with the descent limiter on (descent.enforce), on the emulated drives in one
process, lock-step: a jog down is held at the ground map's floor, and the operator's log
says where and how deep, once."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from rakectl.bench.tick import LockstepRig
from rakectl.config.settings import Settings
from rakectl.core.descent import SoilBound
from rakectl.core.ground_map import TRACKING_MARGIN_M
from rakectl.daemon.events import EventLog
from rakectl.daemon.states import DaemonState
from tests.rig_commands import command, disarmed_rig


class _Captured:
    """A structlog-like logger that keeps what it is given."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str, dict[str, Any]]] = []

    def __getattr__(self, level: str) -> Any:
        return lambda name, **fields: self.lines.append((level, name, fields))


JOG_DOWN = b'{"cmd": "jog", "space": "task", "height_m_per_s": -0.1}'


def _jog(rig: LockstepRig, line: bytes, ticks: int) -> list[float]:
    """``line`` asked every 0.1 s for ``ticks`` ticks, as the operator's client asks it;
    the tip's height after each tick."""
    heights = []
    for k in range(ticks):
        if k % 100 == 0:
            command(rig, line)
        rig.tick()
        heights.append(-rig.daemon.controller.depth_m)
    return heights


def _declared_loam() -> Settings:
    """The ceiling 300 mm above ground level 0 and a site declared loam: 6 kPa, 28°, δ 18°,
    cells ±20 %."""
    defaults = Settings()
    descent = dataclasses.replace(
        defaults.descent, enforce=True, ceiling_m=0.3, cohesion_max_pa=6e3,
        friction_angle_max_rad=math.radians(28.0), tool_friction_angle_max_rad=math.radians(18.0),
        unit_weight_max_n_per_m3=18e3, strength_factor=1.7)
    return dataclasses.replace(defaults, descent=descent)


def test_a_jog_down_is_held_at_the_floor_and_the_log_says_so(tmp_path: Path) -> None:
    """A ceiling (the highest the surface may stand) declared 300 mm above ground level 0,
    100 mm under where the rig arms, and a site declared loam (d* 4.75 mm): a jog straight
    down at 0.1 m/s stops at the floor under the ceiling, the tip never below it (measured:
    the tip dips 0.61 mm under the limiter's hold, within its 1 mm tracking margin), one
    warning naming the height, the daemon still jogging (no fault)."""
    defaults = _declared_loam()
    descent = defaults.descent
    step_m = SoilBound.from_settings(descent, defaults.clamp.force_limit_n,
                                     defaults.clamp.model_margin).first_step_m
    floor_height_m = descent.ceiling_m - step_m
    captured = _Captured()
    rig = LockstepRig(tmp_path, defaults)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        daemon = rig.daemon
        daemon.events = EventLog(captured)
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        heights = _jog(rig, JOG_DOWN, 3000)
        lowest_m = min(heights)
        assert daemon.state is DaemonState.JOG, daemon.fault_reason
        daemon.events.flush(daemon.state.name)
    finally:
        rig.close()
    assert floor_height_m <= lowest_m <= floor_height_m + TRACKING_MARGIN_M + 1e-3
    held = [fields for level, name, fields in captured.lines if name == "descent_limit"]
    assert len(held) == 1, held
    assert held[0]["message"].startswith("descent limit here: the tines are held at +29")
    assert [lvl for lvl, name, _ in captured.lines if name == "descent_limit"] == ["warning"]


def test_a_jog_after_one_held_at_the_floor_moves_sideways_and_up_at_once(tmp_path: Path
                                                                         ) -> None:
    """A jog down held at the floor (as above) leaves its reference up to jog.max_lag_m
    below the tip, which the limiter never let the joints follow. The next jog starts no
    deeper than the joints' reference went: 1 s sideways at 0.05 m/s moves the tip 46 mm,
    and 0.2 s up lifts it. Before, a jog started from the reference held below the floor,
    20 mm under the tip, and every step sideways would have lagged the tip more: the
    jog waited all its second, and the first 20 mm of a jog up moved nothing."""
    with disarmed_rig(tmp_path, _declared_loam()) as rig:
        d, c = rig.daemon, rig.daemon.controller
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        _jog(rig, JOG_DOWN, 3000)
        rig.until(DaemonState.HOLD, 2000)
        for _ in range(300):
            rig.tick()
        assert d.hold[1] > c.depth_m + 0.01  # the held reference: 10 mm or more below the tip
        reach_m = c.reach_m
        _jog(rig, b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0.05}', 1000)
        assert d.jog is not None and d.jog.waiting == 0
        assert c.reach_m - reach_m > 0.04, c.reach_m - reach_m
        rig.until(DaemonState.HOLD, 2000)
        depth_m = c.depth_m
        _jog(rig, b'{"cmd": "jog", "space": "task", "height_m_per_s": 0.05}', 200)
        assert depth_m - c.depth_m > 0.003, depth_m - c.depth_m
