"""Closed loops that ``rakectl simulate`` runs in simulated time (pure).

A loop holds a controller and a plant; each tick it takes the reference (tip
reach, depth x_d, contact flag) and advances one period. Its ``row()`` gives
the telemetry of the tick: the base columns then ``columns``.
"""

from __future__ import annotations

import math
from typing import Protocol

from rakectl.core.control import build_impedance
from rakectl.sim.scenario import Scenario

BASE_COLUMNS = ("x_ref_m", "x_m", "x_e_hat_m", "x_c_m", "f_hat_n")


class ClosedLoop(Protocol):
    columns: tuple[str, ...]  # ground-truth and detail columns after BASE_COLUMNS
    fault: str  # non-empty once the controller has faulted

    def reset(self) -> None: ...

    def step(self, reach_ref_m: float, depth_ref_m: float, contact: bool) -> None: ...

    def measured_tip(self) -> tuple[float, float]:
        """The tip (reach, depth) as the controller measures it."""
        ...

    def row(self) -> tuple[float, ...]:
        """BASE_COLUMNS then ``columns`` for the tick just stepped."""
        ...

    def summary(self) -> dict[str, float | int | bool]: ...


class FirstOrderLoop:
    """The paper's loop: impedance filter and P(s) = 1/(τs + 1), exact under a zero-order hold.

    The reach is ignored: this is the vertical axis alone.
    """

    columns: tuple[str, ...] = ()

    def __init__(self, settings: Scenario, x0_m: float) -> None:
        dt_s = 1.0 / settings.rate_hz
        self.controller = build_impedance(settings)
        self._decay = math.exp(-dt_s / settings.plant.time_constant_s)
        self._x0_m = x0_m
        self.x_m = x0_m
        self._row: tuple[float, ...] = ()
        self.fault = ""

    def reset(self) -> None:
        self.x_m = self._x0_m
        self.controller.reset(self.x_m)

    def step(self, reach_ref_m: float, depth_ref_m: float, contact: bool) -> None:
        c = self.controller
        x_c_m = c.filter.x_c_m
        x_ref_m = c.step(depth_ref_m, self.x_m)
        self._row = (x_ref_m, self.x_m, c.estimator.x_e_m, x_c_m, c.f_hat_n)
        if not (math.isfinite(x_ref_m) and math.isfinite(c.f_hat_n)):
            self.fault = "non-finite value in the impedance controller"
        self.x_m = self._decay * self.x_m + (1.0 - self._decay) * x_ref_m

    def row(self) -> tuple[float, ...]:
        return self._row

    def measured_tip(self) -> tuple[float, float]:
        return math.nan, self.x_m

    def summary(self) -> dict[str, float | int | bool]:
        return {}
