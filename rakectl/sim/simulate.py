"""Offline closed-loop simulation: the controller's own code in simulated time.

``run`` is pure computation (no files); ``write_results`` puts the telemetry
and summary on disk. The CLI composes them.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from rakectl.core.lane import LanePlanner
from rakectl.core.supervision import ForceLevel
from rakectl.errors import NonFiniteError
from rakectl.sim.plants import BASE_COLUMNS, ClosedLoop, FirstOrderLoop
from rakectl.sim.scenario import PlantKind, Scenario, TrajectoryKind
from rakectl.sim.trajectory import TrajectoryReference

ProgressCallback = Callable[[int, int], None]
# After a lane is done the run goes on this long, holding, then stops.
HOLD_AFTER_DONE_S = 0.5
# Ticks whose true vertical force is below this count as out of contact when
# comparing F̂ with the truth.
CONTACT_FORCE_N = 0.5


class Reference(Protocol):
    """Where the tip should be this tick, and whether it is meant to touch the soil."""

    reach_m: float
    depth_m: float

    @property
    def contact(self) -> bool: ...

    @property
    def done(self) -> bool: ...

    def observe(self, reach_m: float, depth_m: float) -> object:
        """The measured tip after the tick (a lane planner detects stalls with it; what it
        returns is not used here)."""
        ...

    def step(self) -> None: ...


@runtime_checkable
class Supervised(Protocol):
    """A loop with force supervision (the rake): what an adaptive lane is governed by."""

    @property
    def force_estimate_n(self) -> float: ...

    @property
    def caution_n(self) -> float: ...


@dataclass
class SimulationResult:
    columns: tuple[str, ...]
    data: NDArray[np.float64]  # one row per tick
    wall_time_s: float
    plant_summary: dict[str, float | int | bool] = field(default_factory=dict)

    def column(self, name: str) -> NDArray[np.float64]:
        return self.data[:, self.columns.index(name)]

    def summary(self) -> dict[str, float | int | bool]:
        f_hat = self.column("f_hat_n")
        t = self.column("t_s")
        dt_s = float(t[1] - t[0]) if len(t) > 1 else 0.0
        simulated_s = float(t[-1] - t[0]) + dt_s
        out: dict[str, float | int | bool] = {
            "ticks": len(t),
            "duration_s": simulated_s,
            "f_hat_final_n": float(f_hat[-1]),
            "f_hat_max_n": float(np.max(f_hat)),
            "tracking_error_final_m": float(self.column("x_d_m")[-1] - self.column("x_m")[-1]),
            "wall_time_s": self.wall_time_s,
            "realtime_factor": simulated_s / self.wall_time_s if self.wall_time_s > 0 else math.inf,
        }
        out.update(self.plant_summary)
        if "f_true_z_n" in self.columns:
            out.update(self._estimate_vs_truth())
        return out

    def _estimate_vs_truth(self) -> dict[str, float]:
        """How well F̂ bounds the true vertical force, over the ticks in contact."""
        f_true, f_hat = self.column("f_true_z_n"), self.column("f_hat_n")
        touching = f_true > CONTACT_FORCE_N
        if not touching.any():
            return {"contact_ticks": 0}
        shortfall = (f_true - f_hat)[touching]
        under = shortfall > 0
        return {
            "contact_ticks": int(touching.sum()),
            "f_hat_below_true_share": float(under.mean()),
            "f_hat_shortfall_median_n": float(np.median(shortfall[under])) if under.any() else 0.0,
            "f_hat_shortfall_max_n": float(shortfall.max()) if under.any() else 0.0,
        }


def build_reference(settings: Scenario) -> Reference:
    dt_s = 1.0 / settings.rate_hz
    if settings.trajectory.kind is TrajectoryKind.LANE:
        lane = settings.lane
        return LanePlanner(lane, dt_s, lane.reach_far_m, -lane.clearance_m)
    return TrajectoryReference(settings.trajectory, dt_s)


def build_loop(settings: Scenario, reference: Reference) -> ClosedLoop:
    """The closed loop for ``reference``; a lane plans within the loop's descent limiter."""
    if settings.plant.kind is PlantKind.FIRST_ORDER:
        return FirstOrderLoop(settings, reference.depth_m)
    from rakectl.sim.rake_plant import RakeLoop  # the emulator's physics, loaded only for it

    loop = RakeLoop(settings, reference.reach_m, reference.depth_m)
    descent = loop.controller.descent
    if descent is not None and isinstance(reference, LanePlanner):
        reference.plan_within(descent.limit_at_m)
    return loop


def run(settings: Scenario, progress: ProgressCallback | None = None) -> SimulationResult:
    """Simulate at ``settings.rate_hz`` for ``duration_s`` (or until a lane is done)."""
    reference = build_reference(settings)
    loop = build_loop(settings, reference)
    dt_s = 1.0 / settings.rate_hz
    max_ticks = round(settings.duration_s * settings.rate_hz)
    hold_ticks = round(HOLD_AFTER_DONE_S * settings.rate_hz)
    columns = ("t_s", "x_d_m", *BASE_COLUMNS, *loop.columns)
    data = np.empty((max_ticks, len(columns)))
    loop.reset()
    started = time.perf_counter()
    ticks = max_ticks
    for k in range(max_ticks):
        x_d_m = reference.depth_m
        loop.step(reference.reach_m, x_d_m, reference.contact)
        if loop.fault:
            raise NonFiniteError(f"controller fault at tick {k} (t = {k * dt_s:.3f} s): "
                                 f"{loop.fault}")
        data[k, 0] = k * dt_s
        data[k, 1] = x_d_m
        data[k, 2:] = loop.row()
        advance_reference(reference, loop)
        if progress is not None and k % 1000 == 0:
            progress(k, max_ticks)
        if reference.done:
            hold_ticks -= 1
            if hold_ticks < 0:
                ticks = k + 1
                break
    if progress is not None:
        progress(max_ticks, max_ticks)
    summary = loop.summary()
    if isinstance(reference, LanePlanner):
        summary.update(_lane_summary(reference))
    return SimulationResult(columns, data[:ticks], time.perf_counter() - started, summary)


def advance_reference(reference: Reference, loop: ClosedLoop) -> None:
    """After a tick, what the daemon does with its reference: the stall check, the stroke
    governor (adaptive lanes), the hard force level's stop, and the next reference unless
    the caution level holds the motion still."""
    reference.observe(*loop.measured_tip())
    level = getattr(loop, "force_level", ForceLevel.OK)
    if isinstance(reference, LanePlanner) and isinstance(loop, Supervised):
        reference.govern(loop.force_estimate_n, loop.caution_n)
    if level is ForceLevel.HARD and isinstance(reference, LanePlanner):
        reference.force_stop(*loop.measured_tip())
    if level is not ForceLevel.CAUTION:
        reference.step()


def _lane_summary(planner: LanePlanner) -> dict[str, float | int | bool]:
    found = planner.found_at
    return {
        "cycles": planner.cycle,
        "depth_reached_m": planner.floor_m,
        "object_found": found is not None,
        "object_reach_m": found[0] if found else math.nan,
        "object_depth_m": found[1] if found else math.nan,
        "stopped_by_force": planner.stopped_by_force,
        "held_by_descent": planner.held_by_descent,
    }


def write_results(result: SimulationResult, out_dir: Path) -> None:
    """Write telemetry.csv (one row per tick) and summary.json into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "telemetry.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(result.columns)
        np.savetxt(f, result.data, delimiter=",", fmt="%.9g")
    with open(out_dir / "summary.json", "w") as f:
        json.dump(result.summary(), f, indent=2)
        f.write("\n")
