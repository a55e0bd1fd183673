"""The soil's configuration: its layers, surface and grid (the model: drivers.soil).

Kept apart from the model so that the model can be compiled (drivers.compiled)
while these declarations stay Python classes whose annotations the
configuration loader and its reference read.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from rakectl.config.declare import setting
from rakectl.errors import ConfigError


@dataclass(frozen=True)
class SoilLayer:
    """One soil layer, from ``from_depth_m`` below the original surface downward."""

    from_depth_m: float = setting(0.0, "Top of the layer below the original surface.",
                                  unit="m", ge=0, le=10)
    stiffness_n_per_m: float = setting(
        2.0e5, "K_e of the tip against the undeformed interface (paper: 2×10² N/mm); "
        "~1e4 loose sand to ~1e6 hard clay.", unit="N/m", gt=0, le=1e8)
    collapse_force_n: float = setting(
        10.0, "Elastic force at which the interface collapses (≈ bearing capacity × "
        "tine tip area, e.g. 150 kPa × 7e-5 m²).", unit="N", gt=0, le=1e5)
    damping_time_s: float = setting(
        1.0e-3, "Contact dashpot as a time constant τ: B = K_e·τ (radiation damping).",
        unit="s", ge=0, le=0.1)
    cohesion_pa: float = setting(5.0e3, "Cohesion c (loose topsoil ~2–10 kPa).",
                                 unit="Pa", ge=0, le=1e6)
    friction_angle_rad: float = setting(math.radians(30.0), "Internal friction angle φ.",
                                        unit="rad", ge=0, lt=1.3)
    tool_friction_angle_rad: float = setting(math.radians(20.0),
                                             "Soil–steel friction angle δ (≈ ⅔ φ).",
                                             unit="rad", ge=0, lt=1.3)
    unit_weight_n_per_m3: float = setting(16.0e3, "Unit weight γ of the soil.",
                                          unit="N/m³", gt=0, le=3e4)


SUBSOIL = SoilLayer(from_depth_m=0.10, stiffness_n_per_m=4.0e5, collapse_force_n=25.0,
                    cohesion_pa=12.0e3, friction_angle_rad=math.radians(28.0),
                    tool_friction_angle_rad=math.radians(18.0), unit_weight_n_per_m3=18.0e3)


@dataclass(frozen=True)
class SurfaceWave:
    """A sinusoid of the original surface: amplitude · sin(2π reach/wavelength + phase)."""

    amplitude_m: float = setting(0.005, "Amplitude.", unit="m", ge=0, le=0.5)
    wavelength_m: float = setting(0.3, "Wavelength along the reach.", unit="m", gt=0, le=100)
    phase_rad: float = setting(0.0, "Phase at reach 0.", unit="rad", ge=-7, le=7)


@dataclass(frozen=True)
class SoilParams:
    """Soil of the lane, the rake's cutting geometry and the grid."""

    layers: tuple[SoilLayer, ...] = setting(
        (SoilLayer(), SUBSOIL), "Layers ordered by from_depth_m; the first starts at 0.")
    width_m: float = setting(0.15, "Effective cutting width w of the rake.", unit="m",
                             gt=0, le=2)
    rake_angle_rad: float = setting(math.radians(60.0), "Tine face angle α from horizontal.",
                                    unit="rad", gt=0.1, le=math.pi / 2)
    surcharge_pa: float = setting(0.0, "Surcharge q on the surface ahead of the tine.",
                                  unit="Pa", ge=0, le=1e6)
    drag_smoothing_speed_m_per_s: float = setting(
        0.01, "v_s of the drag's tanh(v/v_s) near zero speed.", unit="m/s", gt=0, le=1)
    drag_max_damping_ns_per_m: float = setting(
        2.0e4, "Largest slope c_max of the drag near zero speed (numerical regularization).",
        unit="N·s/m", gt=0, le=1e6)
    surface_slope: float = setting(0.0, "Rise of the original surface per metre of reach, "
                                   "about the lane centre.", unit="m/m", ge=-1, le=1)
    surface_waves: tuple[SurfaceWave, ...] = setting((), "Sinusoids added to the surface.")
    stiffness_rel_std: float = setting(0.2, "Relative std dev of K_e between cells.",
                                       ge=0, le=2)
    strength_rel_std: float = setting(0.2, "Relative std dev of collapse and cutting "
                                      "strength between cells.", ge=0, le=2)
    lane_reach_min_m: float = setting(0.3, "Start of the lane (nearest the robot).", unit="m",
                                      ge=0, le=20)
    lane_reach_max_m: float = setting(1.7, "End of the lane.", unit="m", gt=0, le=20)
    cell_m: float = setting(0.005, "Grid resolution along the reach.", unit="m",
                            ge=1e-4, le=0.5)

    def __post_init__(self) -> None:
        if not self.layers or self.layers[0].from_depth_m != 0.0:
            raise ConfigError("layers: the first layer must start at from_depth_m 0")
        depths = [layer.from_depth_m for layer in self.layers]
        if any(b <= a for a, b in itertools.pairwise(depths)):
            raise ConfigError("layers: from_depth_m must strictly increase")
        if not self.lane_reach_max_m >= self.lane_reach_min_m + 2 * self.cell_m:
            raise ConfigError("lane_reach_max_m: must exceed lane_reach_min_m by 2 cells")
