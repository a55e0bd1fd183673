"""A jog held by the force supervisor, and a jog started from a hold, through the full
chain (the daemon and the emulated drives in lock-step)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from rakectl.config.settings import Settings
from rakectl.core.supervision import ForceLevel
from rakectl.daemon.states import DaemonState
from tests.rig_commands import command, disarmed_rig

JOG_DOWN = b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0.0, "height_m_per_s": -0.05}'
JOG_CREEP = b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0.0, "height_m_per_s": -0.003}'
JOG_STILL = b'{"cmd": "jog", "space": "task", "reach_m_per_s": 0.0, "height_m_per_s": 0.0}'


def test_the_dead_man_counts_on_while_the_force_holds_a_jog(tmp_path: Path) -> None:
    """A jog down to 15 mm above the soil, stopped, then one creeping down at 3 mm/s,
    its requests every 0.1 s until the force supervisor's caution level holds it in the
    soil (the level lowered to 8 N, which the ground alone reaches: about 7 N true),
    then no request. The jog ends by the dead-man in its time, its reference within
    1 mm of where the caution held it (where the force falls below the caution level,
    the jog moves on from rest until the dead-man ends it). Before, the dead-man's clock
    stood still at the caution level: a jog held so was still jogging 3 s after its last
    request, and moved on at its old speed whenever the force fell below the level."""
    s = Settings()
    s = dataclasses.replace(s, supervision=dataclasses.replace(s.supervision,
                                                               caution_force_n=8.0))
    with disarmed_rig(tmp_path, s) as rig:
        d, truth = rig.daemon, rig.emulator.ground.truth
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        tick = 0
        while d.controller.depth_m < -0.015:  # the rake starts 0.4 m above the soil
            if tick % 100 == 0:
                command(rig, JOG_DOWN)
            rig.tick()
            tick += 1
        command(rig, b'{"cmd": "stop"}')
        for _ in range(500):
            rig.tick()
        tick = 0
        while d.supervisor.level is not ForceLevel.CAUTION and tick < 60_000:
            if tick % 100 == 0:
                command(rig, JOG_CREEP)
            rig.tick()
            tick += 1
        assert d.state is DaemonState.JOG and d.supervisor.level is ForceLevel.CAUTION
        assert truth.force_down_n > 5.0  # held by the ground, not by the estimate alone
        held_depth_m = d._ref[1]
        deadman_ticks = round(s.jog.deadman_s * s.rate_hz)
        silent, deepest_m = 0, held_depth_m
        while d.state is DaemonState.JOG and silent < 3 * deadman_ticks:
            rig.tick()
            silent += 1
            deepest_m = max(deepest_m, d._ref[1])
        assert d.state is DaemonState.HOLD, (silent, d.supervisor.level)
        assert silent <= deadman_ticks + 2, silent
        assert deepest_m - held_depth_m < 1e-3, (held_depth_m, deepest_m)


def test_a_jog_started_from_a_hold_starts_where_its_reference_is(tmp_path: Path) -> None:
    """With a desired force of 20 N the impedance holds the tip F_d/K_d (2 mm) below its
    reference in free space. A jog commanded at rest, four times, each ended by the
    dead-man: the reference the joints are given does not step as a jog starts, and the
    tip stays where it was. Before, a new jog started from the joints' reference, which
    has the impedance's offset in it, and the controller added the offset again: each
    jog's first tick stepped the reference 1.9 mm down, and the four jogs left the tip
    7.8 mm deeper with no motion asked for."""
    s = dataclasses.replace(Settings(), desired_force_n=20.0)
    with disarmed_rig(tmp_path, s) as rig:
        c = rig.daemon.controller
        command(rig, b'{"cmd": "arm"}')
        rig.until(DaemonState.ARMED, 8000)
        for _ in range(1000):
            rig.tick()
        start_m = c.depth_m
        for _ in range(4):
            before_m = c.x_ref_m
            command(rig, JOG_STILL)
            rig.tick()
            assert abs(c.x_ref_m - before_m) < 5e-5, (before_m, c.x_ref_m)
            rig.until(DaemonState.HOLD, 2000)
            for _ in range(500):
                rig.tick()
        assert abs(c.depth_m - start_m) < 5e-4, (start_m, c.depth_m)
