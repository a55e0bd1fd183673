"""Plants that ``rakectl simulate`` closes the loop around (pure).

A plant takes the position reference x_ref for one tick and returns the
measured position at the next tick. ``truth()`` gives extra ground-truth
columns for the telemetry, named by ``columns``.
"""

from __future__ import annotations

import math
from typing import Protocol


class Plant(Protocol):
    columns: tuple[str, ...]

    def reset(self) -> float:
        """Put the plant in its initial state; return the first measured x in m."""
        ...

    def step(self, reach_ref_m: float, x_ref_m: float) -> float:
        """Hold the reference for one period; return the measured x at its end."""
        ...

    def truth(self) -> tuple[float, ...]:
        """Ground truth at the current tick, one value per name in ``columns``."""
        ...

    def summary(self) -> dict[str, float | int | bool]:
        """Ground-truth figures of the whole run."""
        ...


class FirstOrderPlant:
    """The paper's position loop P(s) = 1/(τs + 1), exact under a zero-order hold."""

    columns: tuple[str, ...] = ()

    def __init__(self, time_constant_s: float, dt_s: float, x0_m: float = 0.0) -> None:
        if not (time_constant_s > 0 and dt_s > 0):
            raise ValueError("first-order plant: time constant and dt must be > 0")
        self._decay = math.exp(-dt_s / time_constant_s)
        self._x0_m = x0_m
        self.x_m = x0_m

    def reset(self) -> float:
        self.x_m = self._x0_m
        return self.x_m

    def step(self, reach_ref_m: float, x_ref_m: float) -> float:
        """The reach is ignored: this plant is the vertical axis alone."""
        self.x_m = self._decay * self.x_m + (1.0 - self._decay) * x_ref_m
        return self.x_m

    def truth(self) -> tuple[float, ...]:
        return ()

    def summary(self) -> dict[str, float | int | bool]:
        return {}
