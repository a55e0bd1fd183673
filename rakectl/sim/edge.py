"""The ``edge`` family: plunges whose path passes within :data:`EDGE_BAND_M` of an
object's side.

Random placement rarely puts a plunge's path where an object's rounded top edge
forces the descending tines sideways through the soil: that band of paths is a few
tenths of a millimetre wide (docs/safety.md, "Not covered"). Each case here is a
plunge beside a mine (half the cases), a stone or a root, on the campaign's soils
(:func:`~rakectl.sim.cases.draw_soil`), under its faults, half of them supervised.
:func:`edge_resistance_n` is what the soil resists with at a case's object, which
``rakectl fuzz --family edge --plot`` sets each case's side force against.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from drivers.ground_params import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.soil import cutting_force_n, original_surface_height_m
from drivers.soil_params import SoilParams
from rakectl.sim.cases import (
    FAULT_KINDS,
    PLUNGE_END_DEPTH_M,
    CommandKind,
    Family,
    FuzzCase,
    MotionCommand,
    draw_faults,
    draw_mine,
    draw_soil,
    height_clear_of,
)
from rakectl.sim.results import CaseResult
from rakectl.sim.scene import laid_in

EDGE_BAND_M = 0.004  # an edge case's path passes this close to the object's side, either way


def edge_object(rng: np.random.Generator, kind: int, side_m: float, toward_robot: bool,
                 top_depth_m: float) -> BuriedObjects:
    """One mine (``kind`` 0), stone (1) or root (2) whose near (``toward_robot``) or far
    side is at reach ``side_m``."""
    body: StoneParams | RootParams | MineParams
    if kind == 2:
        body = RootParams(0.0, top_depth_m)
    elif kind == 1:
        body = StoneParams(0.0, top_depth_m, float(rng.uniform(0.03, 0.15)),
                           float(rng.uniform(0.03, 0.1)))
    else:
        body = draw_mine(rng, 0.0, top_depth_m)
    half_m = 0.5 * body.width_m
    body = dataclasses.replace(body, reach_m=side_m + half_m if toward_robot else side_m - half_m)
    return BuriedObjects(stones=(body,) if isinstance(body, StoneParams) else (),
                         roots=(body,) if isinstance(body, RootParams) else (),
                         mines=(body,) if isinstance(body, MineParams) else ())


def edge_case(seed: int, index: int) -> FuzzCase:
    """An edge case: a plunge (straight down from above the ground to 0.15 m deep at
    0.05–0.25 m/s, the impedance on or off) whose path passes within
    :data:`EDGE_BAND_M` of an object's side (or over a root's round side), over a mine
    (indices 0, 1 mod 4), a stone (2 mod 4) or a root (3 mod 4), its top 5–100 mm below
    the surface where it lies (:func:`~rakectl.sim.scene.laid_in`), on the campaign's
    soils; faults and supervision as in the random family. (The operator's jog is left
    to the random family: in soil it descends a few millimetres a second and stops where
    the force rises.)"""
    rng = np.random.default_rng([seed, index, 2])
    kind = 0 if index % 4 < 2 else index % 4 - 1
    reach_m = float(rng.uniform(0.95, 1.35))
    soil = draw_soil(rng)
    surface_m = original_surface_height_m(soil, reach_m)
    top_depth_m = float(rng.uniform(0.005, 0.1))
    toward_robot = bool(rng.integers(0, 2))  # the object beyond the path, or before it
    # > 0: the path over it; a root's round side spans its radius (10 mm)
    inside_m = float(rng.uniform(-EDGE_BAND_M, 0.01 if kind == 2 else EDGE_BAND_M))
    side_m = reach_m - inside_m if toward_robot else reach_m + inside_m
    objects = laid_in(edge_object(rng, kind, side_m, toward_robot, top_depth_m), soil)
    command = MotionCommand(CommandKind.PLUNGE, reach_m, reach_m, PLUNGE_END_DEPTH_M,
                            PLUNGE_END_DEPTH_M, float(rng.uniform(0.05, 0.25)), 0.0,
                            float(rng.uniform(0.02, 0.1)), bool(rng.integers(0, 2)))
    command = dataclasses.replace(command, start_height_m=max(
        command.start_height_m, height_clear_of(objects, reach_m, surface_m)))
    duration_s = (command.start_height_m + PLUNGE_END_DEPTH_M + 0.1) \
        / command.speed_m_per_s + 1.0
    faults = draw_faults(rng, (index // 4) % (len(FAULT_KINDS) + 1), duration_s)
    return FuzzCase(seed, index, GroundParams(soil, objects), int(rng.integers(0, 2**32)),
                    command, faults, duration_s, (index // 24) % 2 == 1, Family.EDGE)


def edge_body(case: FuzzCase) -> MineParams | StoneParams | RootParams:
    """The one object an edge case's plunge passes beside."""
    objects = case.ground.objects
    bodies: tuple[MineParams | StoneParams | RootParams, ...] = (
        *objects.mines, *objects.stones, *objects.roots)
    return bodies[0]


def edge_cut_m(case: FuzzCase) -> float:
    """How far below the original surface over an edge case's path its object's rounded
    top edge reaches (its top plus the edge's radius; a root's round side: its radius;
    0 if that is above the surface): the deepest cut the tines are in while the edge
    forces them sideways."""
    body = edge_body(case)
    radius_m = body.thickness_m / 2 if isinstance(body, RootParams) else body.edge_radius_m
    surface_m = original_surface_height_m(case.ground.soil, case.command.reach_far_m)
    return max(0.0, float(surface_m + body.depth_m + radius_m))


def resistance_n(soil: SoilParams, cut_m: float) -> float:
    """H at a cut of ``cut_m``: the cutting resistance over the rake's width
    (:func:`drivers.soil.cutting_force_n`, a mean cell) of the strongest layer the cut
    reaches (the cells lie within ``strength_rel_std`` of it)."""
    return max((cutting_force_n(layer, soil, cut_m) for layer in soil.layers
                if layer.from_depth_m <= cut_m), default=0.0)


def edge_resistance_n(case: FuzzCase) -> float:
    """H at :func:`edge_cut_m` (:func:`resistance_n`). What the soil resists with when an
    edge forces the tines sideways through it, which the object carries besides the
    mount's share (docs/safety.md, "Not covered"); the descent budget keeps it under
    90 N less the clamp's F_L."""
    return resistance_n(case.ground.soil, edge_cut_m(case))


@dataclasses.dataclass(frozen=True)
class EdgeReading:
    """An edge case's largest side force on its object, beside the soil's resistance
    at the object's edge."""

    index: int
    body: str  # "mine", "stone" or "root"
    resistance_n: float
    side_n: float
    safe: bool


def edge_readings(results: Iterable[CaseResult]) -> list[EdgeReading]:
    """The edge family's results (others and refused sites left out) with their cases
    drawn again from the seed and index."""
    readings = []
    for r in results:
        if r.family != str(Family.EDGE) or r.refused:
            continue
        case = edge_case(r.seed, r.index)
        body = edge_body(case)
        kind, side_n = (("mine", r.f_mine_side_max_n) if isinstance(body, MineParams) else
                        ("stone", r.f_stone_side_max_n) if isinstance(body, StoneParams) else
                        ("root", r.f_root_side_max_n))
        readings.append(EdgeReading(r.index, kind, edge_resistance_n(case), side_n, r.safe))
    return readings
