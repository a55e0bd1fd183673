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
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from rakectl.errors import NonFiniteError
from rakectl.excavation import LanePlanner
from rakectl.impedance import DelayForceEstimator, ImpedanceController, ImpedanceFilter
from rakectl.plants import FirstOrderPlant, Plant
from rakectl.settings import PlantKind, Settings, TrajectoryKind
from rakectl.trajectory import TrajectoryReference

BASE_COLUMNS = ("t_s", "x_d_m", "x_ref_m", "x_m", "x_e_hat_m", "x_c_m", "f_hat_n")
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

    def step(self) -> None: ...


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


def build_controller(settings: Settings) -> ImpedanceController:
    dt_s = 1.0 / settings.rate_hz
    imp, est = settings.impedance, settings.estimator
    return ImpedanceController(
        ImpedanceFilter(imp.mass_kg, imp.damping_ns_per_m, imp.stiffness_n_per_m, dt_s),
        DelayForceEstimator(est.environment_stiffness_n_per_m, est.delay_s, est.max_delay_s, dt_s),
        desired_force_n=settings.desired_force_n,
    )


def build_reference(settings: Settings) -> Reference:
    dt_s = 1.0 / settings.rate_hz
    if settings.trajectory.kind is TrajectoryKind.LANE:
        lane = settings.lane
        return LanePlanner(lane, dt_s, lane.reach_far_m, -lane.clearance_m)
    return TrajectoryReference(settings.trajectory, dt_s)


def build_plant(settings: Settings, reference: Reference) -> Plant:
    dt_s = 1.0 / settings.rate_hz
    if settings.plant.kind is PlantKind.FIRST_ORDER:
        return FirstOrderPlant(settings.plant.time_constant_s, dt_s, reference.depth_m)
    from rakectl.rake_plant import RakePlant  # the emulator's physics, for simulation only
    from rakectl.scenario import Scenario

    if not isinstance(settings, Scenario):
        raise TypeError("plant kind rake needs a Scenario (controller + emulator settings)")
    return RakePlant(settings, reference.reach_m, reference.depth_m)


def run(settings: Settings, progress: ProgressCallback | None = None) -> SimulationResult:
    """Simulate at ``settings.rate_hz`` for ``duration_s`` (or until a lane is done)."""
    reference = build_reference(settings)
    plant = build_plant(settings, reference)
    controller = build_controller(settings)
    dt_s = 1.0 / settings.rate_hz
    max_ticks = round(settings.duration_s * settings.rate_hz)
    hold_ticks = round(HOLD_AFTER_DONE_S * settings.rate_hz)
    columns = BASE_COLUMNS + plant.columns
    data = np.empty((max_ticks, len(columns)))
    x_m = plant.reset()
    controller.reset(x_m)
    contact_delay_s = settings.estimator.delay_s
    in_contact: bool | None = None
    started = time.perf_counter()
    ticks = max_ticks
    for k in range(max_ticks):
        if reference.contact is not in_contact:
            in_contact = reference.contact
            if in_contact:
                controller.estimator.enter_contact(contact_delay_s, x_m)
            else:
                controller.estimator.set_delay(0.0)
        x_d_m, x_c_m = reference.depth_m, controller.filter.x_c_m
        x_ref_m = controller.step(x_d_m, x_m)
        data[k, :7] = (k * dt_s, x_d_m, x_ref_m, x_m, controller.estimator.x_e_m, x_c_m,
                       controller.f_hat_n)
        if not (math.isfinite(x_ref_m) and math.isfinite(controller.f_hat_n)):
            raise NonFiniteError(f"non-finite value at tick {k} (t = {k * dt_s:.3f} s)")
        x_m = plant.step(reference.reach_m, x_ref_m)
        data[k, 7:] = plant.truth()
        reference.step()
        if progress is not None and k % 1000 == 0:
            progress(k, max_ticks)
        if reference.done:
            hold_ticks -= 1
            if hold_ticks < 0:
                ticks = k + 1
                break
    if progress is not None:
        progress(max_ticks, max_ticks)
    return SimulationResult(columns, data[:ticks], time.perf_counter() - started,
                            plant.summary())


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
