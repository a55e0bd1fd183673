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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rakectl.errors import NonFiniteError
from rakectl.impedance import DelayForceEstimator, ImpedanceController, ImpedanceFilter
from rakectl.plants import FirstOrderPlant, Plant
from rakectl.settings import PlantKind, Settings
from rakectl.trajectory import desired_position_m

BASE_COLUMNS = ("t_s", "x_d_m", "x_ref_m", "x_m", "x_e_hat_m", "x_c_m", "f_hat_n")
ProgressCallback = Callable[[int, int], None]


@dataclass
class SimulationResult:
    columns: tuple[str, ...]
    data: NDArray[np.float64]  # one row per tick
    wall_time_s: float

    def column(self, name: str) -> NDArray[np.float64]:
        return self.data[:, self.columns.index(name)]

    def summary(self) -> dict[str, float | int]:
        f_hat = self.column("f_hat_n")
        t = self.column("t_s")
        simulated_s = float(t[-1] - t[0]) + (float(t[1] - t[0]) if len(t) > 1 else 0.0)
        return {
            "ticks": len(t),
            "duration_s": simulated_s,
            "f_hat_final_n": float(f_hat[-1]),
            "f_hat_max_n": float(np.max(f_hat)),
            "tracking_error_final_m": float(self.column("x_d_m")[-1] - self.column("x_m")[-1]),
            "wall_time_s": self.wall_time_s,
            "realtime_factor": simulated_s / self.wall_time_s if self.wall_time_s > 0 else math.inf,
        }


def build_controller(settings: Settings) -> ImpedanceController:
    dt_s = 1.0 / settings.rate_hz
    imp, est = settings.impedance, settings.estimator
    return ImpedanceController(
        ImpedanceFilter(imp.mass_kg, imp.damping_ns_per_m, imp.stiffness_n_per_m, dt_s),
        DelayForceEstimator(est.environment_stiffness_n_per_m, est.delay_s, est.max_delay_s, dt_s),
        desired_force_n=settings.desired_force_n,
    )


def build_plant(settings: Settings) -> Plant:
    dt_s = 1.0 / settings.rate_hz
    if settings.plant.kind is PlantKind.FIRST_ORDER:
        return FirstOrderPlant(settings.plant.time_constant_s, dt_s, settings.trajectory.start_m)
    raise NotImplementedError(f"plant kind {settings.plant.kind.value} is not available yet")


def run(settings: Settings, plant: Plant | None = None,
        progress: ProgressCallback | None = None) -> SimulationResult:
    """Simulate ``settings.duration_s`` at ``settings.rate_hz``, as fast as possible."""
    plant = plant if plant is not None else build_plant(settings)
    controller = build_controller(settings)
    dt_s = 1.0 / settings.rate_hz
    ticks = round(settings.duration_s * settings.rate_hz)
    columns = BASE_COLUMNS + plant.columns
    data = np.empty((ticks, len(columns)))
    x_m = plant.reset()
    controller.reset(x_m)
    traj = settings.trajectory
    started = time.perf_counter()
    for k in range(ticks):
        t_s = k * dt_s
        x_d_m = desired_position_m(traj, t_s)
        x_c_m = controller.filter.x_c_m
        x_ref_m = controller.step(x_d_m, x_m)
        data[k, :7] = (t_s, x_d_m, x_ref_m, x_m, controller.estimator.x_e_m, x_c_m,
                       controller.f_hat_n)
        data[k, 7:] = plant.truth()
        if not (math.isfinite(x_ref_m) and math.isfinite(controller.f_hat_n)):
            raise NonFiniteError(f"non-finite value at tick {k} (t = {t_s:.3f} s)")
        x_m = plant.step(x_ref_m)
        if progress is not None and k % 1000 == 0:
            progress(k, ticks)
    if progress is not None:
        progress(ticks, ticks)
    return SimulationResult(columns, data, time.perf_counter() - started)


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
