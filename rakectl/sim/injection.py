"""What a campaign case does to the simulated chain: the operator's command, and the
faults injected between controller, bus and drives.

The commands: a plunge (straight down at a fixed reach and speed), the daemon's
own jog as an operator's client drives it, and the hold the force supervision
backs off to; a lane or a stroke is the daemon's own planner
(:class:`~rakectl.core.lane.LanePlanner`).

Faults as the robot would meet them: lost feedback (the controller keeps the
previous measurement), a lost command (the drive applies the previous voltages
again, and its watchdog counts the silence), a drive fault episode (both motors
at 0 V for its length), a controller stall and a SIGKILL (no tick runs: the
drives apply the last command until their command watchdog,
``drives.watchdog_timeout_ms``, expires, then 0 V, latched). A
latched drive fault or a controller fault (as the daemon's: a non-finite number,
an infeasible clamp) leaves both motors at 0 V for :data:`~rakectl.sim.campaign.AFTER_FAULT_S` more,
the rake falling onto whatever is below it; that is judged too.
"""

from __future__ import annotations

import math

import numpy as np

from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.jog import Jog, JogFrame
from rakectl.sim.cases import Faults, FuzzCase
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import Scenario

JOG_COMMAND_PERIOD_S = 0.1  # the operator's client repeats its jog this often


class PlungeReference:
    """Straight down at a fixed reach and constant speed, then hold (a hostile command)."""

    def __init__(self, reach_m: float, start_depth_m: float, end_depth_m: float,
                 speed_m_per_s: float, dt_s: float, contact: bool) -> None:
        self.reach_m, self.depth_m = reach_m, start_depth_m
        self._end_m, self._step_m, self._contact = end_depth_m, speed_m_per_s * dt_s, contact

    @property
    def contact(self) -> bool:
        return self._contact

    @property
    def done(self) -> bool:
        return self.depth_m >= self._end_m

    def observe(self, reach_m: float, depth_m: float) -> None:
        pass

    def step(self) -> None:
        self.depth_m = min(self._end_m, self.depth_m + self._step_m)


class JogReference:
    """The daemon's jog (:class:`~rakectl.core.jog.Jog`) as an operator drives it: the
    same velocity every 0.1 s for ``jog_s``, then silence; the dead-man stops it."""

    def __init__(self, case: FuzzCase, settings: Scenario, workspace: kinematics.Workspace,
                 r_m: float, theta_rad: float) -> None:
        c = case.command
        dt_s = 1.0 / settings.rate_hz
        self._jog = Jog(settings.jog, workspace, dt_s, r_m, theta_rad)
        self._space = JogFrame(c.jog_space)
        if self._space is JogFrame.TASK:  # (reach, height): 0 rad is straight down
            self._velocity = (-math.sin(c.jog_angle_rad) * 10.0,
                              -math.cos(c.jog_angle_rad) * 10.0)
        else:  # (r, θ); the jog clips each to its highest speed
            self._velocity = (math.cos(c.jog_angle_rad) * 10.0, math.sin(c.jog_angle_rad) * 10.0)
        self._period = round(JOG_COMMAND_PERIOD_S / dt_s)
        self._commands = max(1, round(c.jog_s / JOG_COMMAND_PERIOD_S))
        self._tick = 0
        self.reach_m, self.depth_m = self._jog.tip()

    @property
    def contact(self) -> bool:
        return self._jog.contact

    @property
    def done(self) -> bool:
        return self._jog.expired and not self._jog.moving

    def observe(self, reach_m: float, depth_m: float) -> None:
        self._jog.observe(reach_m, depth_m)

    def step(self, held: bool = False) -> None:
        """One tick; ``held``: the force supervision's caution holds the jog where it is,
        as the daemon holds it, while the operator's requests and the dead-man go on."""
        if self._tick % self._period == 0 and self._tick // self._period < self._commands:
            self._jog.command(self._space, *self._velocity)
        self._tick += 1
        self._jog.step(held)
        self.reach_m, self.depth_m = self._jog.tip()


class HoldReference:
    """Where the force supervision's hard level leaves a plunge or a jog: backed off."""

    def __init__(self, reach_m: float, depth_m: float) -> None:
        self.reach_m, self.depth_m = reach_m, depth_m

    contact = False
    done = True

    def observe(self, reach_m: float, depth_m: float) -> None:
        pass

    def step(self) -> None:
        pass


# --------------------------------------------------------------------------- the loop


class FaultyRakeLoop(RakeLoop):
    """RakeLoop with the case's faults injected between controller, bus and drives."""

    def __init__(self, settings: Scenario, start_reach_m: float, start_depth_m: float,
                 faults: Faults, clamp: VoltageClamp | None = None) -> None:
        super().__init__(settings, start_reach_m, start_depth_m, clamp)
        self.faults = faults
        self._rng = np.random.default_rng(faults.seed)
        self._armed = False
        self._tick_index = 0
        self._last = self.arm.measure()
        self._silent_ticks = 0  # since the drives last received a command
        self._watchdog_ticks = round(settings.drives.watchdog_timeout_ms * 1e-3 / self.dt_s)
        self.latched = False  # the drives hold 0 V from now on (watchdog or a fault)
        self.feedback_lost = self.commands_lost = self.drive_fault_ticks = 0
        self.stalled_ticks = 0
        self.watchdog_tripped = False

    def arm_faults(self) -> None:
        self._armed = True

    def _controller_runs(self, t_s: float) -> bool:
        f = self.faults
        if not self._armed:
            return True
        if 0.0 <= f.kill_at_s <= t_s:
            return False
        return not (f.stall_s > 0.0 and f.stall_start_s <= t_s < f.stall_start_s + f.stall_s)

    def _tick(self, reach_ref_m: float, depth_ref_m: float) -> None:
        f = self.faults
        t_s = self._tick_index * self.dt_s
        runs = self._controller_runs(t_s) and not self.fault
        if runs:
            m = self.arm.measure()
            if self._armed and self._rng.uniform() < f.feedback_loss_probability:
                m, self.feedback_lost = self._last, self.feedback_lost + 1
            self._last = m
            voltages = self.controller.step(reach_ref_m, depth_ref_m, m.r_m, m.theta_rad,
                                            m.r_vel_m_per_s, m.theta_vel_rad_per_s,
                                            mount_force_n=self.supervisor.f_current_n)
            if self.controller.clamp.infeasible and not self.fault:  # as the daemon does
                self.fault = "the voltage clamp cannot meet its bound"
        else:
            self.stalled_ticks += not self.fault
        self.contact.peak_down_n = 0.0
        applied = self._pending_v
        if self._armed and f.drive_fault_start_s <= t_s < f.drive_fault_start_s + f.drive_fault_s:
            applied, self.drive_fault_ticks = (0.0, 0.0), self.drive_fault_ticks + 1
        if self.latched or self.fault:
            applied = (0.0, 0.0)
        self.arm.step(applied[0], applied[1], self.contact, self.dt_s)
        lost = runs and self._armed and self._rng.uniform() < f.command_loss_probability
        if lost:
            self.commands_lost += 1  # the drive keeps applying the previous voltages
        if not runs or lost:  # no command this tick: the drive's watchdog counts
            self._silent_ticks += 1
            if self._silent_ticks >= self._watchdog_ticks and not self.latched:
                self.latched = self.watchdog_tripped = True
        else:
            self._pending_v, self._silent_ticks = voltages, 0
        if self._armed:
            self._tick_index += 1
