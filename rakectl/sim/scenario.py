"""A scenario for offline simulation: the controller's settings plus what only a simulation has.

The plant it closes the loop around, the desired trajectory, its length and
the emulated hardware. This is the only place where rakectl's settings meet
drivers': the daemon's own configuration (:class:`rakectl.config.settings.Settings`)
knows nothing of the emulator or of simulated time.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar

from drivers.settings import EmulatorSettings
from rakectl.config.declare import section, setting
from rakectl.config.settings import Settings


class PlantKind(enum.StrEnum):
    """What ``rakectl simulate`` closes the loop around."""

    FIRST_ORDER = "first_order"  # the paper's P(s) = 1/(τs + 1) on the vertical axis
    RAKE = "rake"  # motors, arm and soil models of drivers/


class TrajectoryKind(enum.StrEnum):
    RAMP = "ramp"  # x_d = start + speed · (t − t0) for t ≥ t0, at a fixed reach
    STEP = "step"  # x_d = start + amplitude for t ≥ t0, at a fixed reach
    LANE = "lane"  # raking strokes over a lane, deeper each cycle (paper Fig. 3)


@dataclass(frozen=True)
class PlantSettings:
    """The plant of an offline simulation."""

    kind: PlantKind = setting(PlantKind.FIRST_ORDER, "Plant model: first_order or rake.")
    time_constant_s: float = setting(
        0.2, "Time constant τ of the first-order position loop P(s) = 1/(τs+1).", unit="s", gt=0
    )


@dataclass(frozen=True)
class TrajectorySettings:
    """Desired vertical trajectory x_d(t) (depth into the soil, positive down)."""

    kind: TrajectoryKind = setting(TrajectoryKind.RAMP,
                                   "ramp, step, or lane (a raking lane: lane.*).")
    start_m: float = setting(0.0, "x_d before the trajectory starts.", unit="m", ge=-1, le=1)
    start_time_s: float = setting(0.0, "When the ramp or step starts.", unit="s", ge=0)
    speed_m_per_s: float = setting(0.007, "Ramp speed.", unit="m/s", ge=-1, le=1)
    amplitude_m: float = setting(0.01, "Step height.", unit="m", ge=-1, le=1)
    reach_m: float = setting(1.0, "Horizontal reach of the tip for ramp and step.", unit="m",
                             gt=0, le=10)


@dataclass(frozen=True)
class Scenario(Settings):
    """Settings of the controller under test and of the hardware it runs against."""

    # the emulator process's section physics: is this emulator: (drivers.settings)
    OTHER_NAMES: ClassVar[dict[str, str]] = {"physics": "emulator"}

    plant: PlantSettings = section(PlantSettings)
    trajectory: TrajectorySettings = section(TrajectorySettings)
    duration_s: float = setting(20.0, "Length of a simulation.", unit="s", gt=0, le=3600)
    emulator: EmulatorSettings = section(EmulatorSettings)
