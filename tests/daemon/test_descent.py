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
from tests.rig_commands import command


class _Captured:
    """A structlog-like logger that keeps what it is given."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str, dict[str, Any]]] = []

    def __getattr__(self, level: str) -> Any:
        return lambda name, **fields: self.lines.append((level, name, fields))


def test_a_jog_down_is_held_at_the_floor_and_the_log_says_so(tmp_path: Path) -> None:
    """A ceiling (the highest the surface may stand) declared 300 mm above ground level 0,
    100 mm under where the rig arms, and a site declared loam (d* 4.75 mm): a jog straight
    down at 0.1 m/s stops at the floor under the ceiling, the tip never below it (measured:
    the tip dips 0.61 mm under the limiter's hold, within its 1 mm tracking margin), one
    warning naming the height, the daemon still jogging (no fault)."""
    defaults = Settings()
    descent = dataclasses.replace(  # a site declared loam: 6 kPa, 28°, δ 18°, cells ±20 %
        defaults.descent, enforce=True, ceiling_m=0.3, cohesion_max_pa=6e3,
        friction_angle_max_rad=math.radians(28.0), tool_friction_angle_max_rad=math.radians(18.0),
        unit_weight_max_n_per_m3=18e3, strength_factor=1.7)
    defaults = dataclasses.replace(defaults, descent=descent)
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
        lowest_m = math.inf
        for k in range(3000):
            if k % 100 == 0:
                command(rig, b'{"cmd": "jog", "space": "task", "height_m_per_s": -0.1}')
            rig.tick()
            lowest_m = min(lowest_m, -daemon.controller.depth_m)
        assert daemon.state is DaemonState.JOG, daemon.fault_reason
        daemon.events.flush(daemon.state.name)
    finally:
        rig.close()
    assert floor_height_m <= lowest_m <= floor_height_m + TRACKING_MARGIN_M + 1e-3
    held = [fields for level, name, fields in captured.lines if name == "descent_limit"]
    assert len(held) == 1, held
    assert held[0]["message"].startswith("descent limit here: the tines are held at +29")
    assert [lvl for lvl, name, _ in captured.lines if name == "descent_limit"] == ["warning"]
