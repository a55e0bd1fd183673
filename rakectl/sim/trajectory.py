"""Desired vertical trajectories x_d(t) (pure)."""

from __future__ import annotations

from rakectl.sim.scenario import TrajectoryKind, TrajectorySettings


def desired_position_m(traj: TrajectorySettings, t_s: float) -> float:
    """x_d at time ``t_s``: depth into the soil, positive down."""
    elapsed_s = t_s - traj.start_time_s
    if elapsed_s <= 0.0:
        return traj.start_m
    if traj.kind is TrajectoryKind.RAMP:
        return traj.start_m + traj.speed_m_per_s * elapsed_s
    return traj.start_m + traj.amplitude_m


class TrajectoryReference:
    """A ramp or step at a fixed reach, as a per-tick reference (always in contact)."""

    contact = True
    done = False

    def __init__(self, traj: TrajectorySettings, dt_s: float) -> None:
        self.traj = traj
        self.dt_s = dt_s
        self.ticks = 0
        self.reach_m = traj.reach_m
        self.depth_m = desired_position_m(traj, 0.0)

    def observe(self, reach_m: float, depth_m: float) -> None:
        """A fixed trajectory does not react to the measured tip."""

    def step(self) -> None:
        self.ticks += 1
        self.depth_m = desired_position_m(self.traj, self.ticks * self.dt_s)
