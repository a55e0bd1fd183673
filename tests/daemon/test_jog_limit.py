"""A jog driven into a joint's limit, through the full chain (the daemon and the emulated
drives in lock-step): the limits are the joints' end stops, where the emulated drive
faults on the hit (EMCY 0xFF01), so the jog stops short of them."""

from __future__ import annotations

from pathlib import Path

import pytest

from rakectl.core.jog import LIMIT_MARGIN
from rakectl.daemon.states import DaemonState
from tests.rig_commands import command, disarmed_rig


@pytest.mark.parametrize(("line", "joint"), [
    (b'{"cmd": "jog", "space": "joint", "theta_rad_per_s": -0.5}', 1),
    (b'{"cmd": "jog", "space": "joint", "r_m_per_s": 0.25}', 0)])
def test_a_jog_into_a_joint_limit_stops_short_of_its_end_stop(tmp_path: Path, line: bytes,
                                                              joint: int) -> None:
    """θ up at its fastest (capped at 0.15 rad/s), r out at 0.1 m/s, for 8 s of requests
    every 0.1 s. Before, the reference stopped at the limit itself and the θ drive faulted
    on its end stop, the rake then sinking under its weight. Now the arm stops within the
    margin, never at the stop, and stays armed."""
    with disarmed_rig(tmp_path) as rig:
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        ws = rig.daemon.workspace
        low = (ws.r_min_m, ws.theta_min_rad)[joint]
        high = (ws.r_max_m, ws.theta_max_rad)[joint]
        closest = float("inf")
        for _ in range(80):
            command(rig, line)
            for _ in range(100):
                rig.tick()
                fb = rig.daemon.client.feedback
                q = (fb.r_m, fb.theta_rad)[joint]
                closest = min(closest, q - low, high - q)
        d = rig.daemon
        assert d.state is DaemonState.JOG, d.fault_reason
        assert 0.0 < closest < LIMIT_MARGIN[joint]
