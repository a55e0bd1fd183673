"""Desired vertical trajectories x_d(t) (pure)."""

from __future__ import annotations

from rakectl.settings import TrajectoryKind, TrajectorySettings


def desired_position_m(traj: TrajectorySettings, t_s: float) -> float:
    """x_d at time ``t_s``: depth into the soil, positive down."""
    elapsed_s = t_s - traj.start_time_s
    if elapsed_s <= 0.0:
        return traj.start_m
    if traj.kind is TrajectoryKind.RAMP:
        return traj.start_m + traj.speed_m_per_s * elapsed_s
    return traj.start_m + traj.amplitude_m
