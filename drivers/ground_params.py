"""What a lane's ground is made of, as configuration: the soil and the buried objects'
declared parameters (physics.ground in the emulator's YAML). The model that uses them
is :mod:`drivers.objects` (the objects), :mod:`drivers.soil` and :mod:`drivers.ground`
(:class:`~drivers.ground.Ground`, which combines them)."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.soil_params import SoilParams
from rakectl.config.declare import section, setting


@dataclass(frozen=True)
class StoneParams:
    """A stone: rigid, never yields."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.08, "Depth of its top below ground level 0 (< 0 protrudes).",
                             unit="m", ge=-0.5, le=2)
    width_m: float = setting(0.10, "Extent along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.08, "Extent below its top.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(1.0e7, "Contact stiffness.", unit="N/m", gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)
    edge_radius_m: float = setting(0.005, "Radius of its top edges (0: square).", unit="m",
                                   ge=0, le=1)


@dataclass(frozen=True)
class RootParams:
    """A root crossing the lane: elastic, then plastic above its yield force."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.06, "Depth of its top below ground level 0.", unit="m",
                             ge=-0.5, le=2)
    width_m: float = setting(0.02, "Diameter along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.02, "Diameter, vertically.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(1.4e5, "Bending stiffness 48EI/L³.", unit="N/m",
                                       gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)
    yield_force_n: float = setting(400.0, "Force above which it bends permanently.",
                                   unit="N", gt=0, le=1e5)
    break_displacement_m: float = setting(0.03, "Permanent set at which it breaks.", unit="m",
                                          gt=0, le=2)


@dataclass(frozen=True)
class MineParams:
    """A pressure-fused anti-personnel mine; its whole top is the pressure plate."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.05, "Depth of its top (the plate) below ground level 0.",
                             unit="m", ge=-0.5, le=2)
    width_m: float = setting(0.08, "Diameter along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.05, "Height of the body.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(5.0e6, "Contact stiffness.", unit="N/m", gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)
    activation_force_n: float = setting(
        90.0, "Plate force that fires it (typical AP mines: 80–100 N).", unit="N",
        gt=0, le=1e4)
    edge_radius_m: float = setting(0.003, "Radius of its casing's top rim (0: square).",
                                   unit="m", ge=0, le=1)


@dataclass(frozen=True)
class BuriedObjects:
    """The objects buried in the lane."""

    stones: tuple[StoneParams, ...] = setting((), "Stones.")
    roots: tuple[RootParams, ...] = setting((), "Roots.")
    mines: tuple[MineParams, ...] = setting((), "Mines.")


@dataclass(frozen=True)
class GroundParams:
    """Soil and buried objects of a lane."""

    soil: SoilParams = section(SoilParams)
    objects: BuriedObjects = section(BuriedObjects)
