"""The ``edge`` family: plunges whose path passes within :data:`EDGE_BAND_M` of an
object's side.

Random placement rarely puts a plunge's path where an object's rounded top edge
forces the descending tines sideways through the soil: that band of paths is a few
tenths of a millimetre wide (docs/safety.md, "Not covered"). Each case here is a
plunge beside a mine (half the cases), a stone or a root, on the campaign's soils
(:func:`~rakectl.sim.cases.draw_soil`), under its faults, half of them supervised.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drivers.ground_params import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.soil import original_surface_height_m
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
