"""Buried objects laid in a campaign case's soil so that its scene can stand.

The ground model takes an object's depth below level 0 (``drivers.ground_params``),
but the untouched surface slopes and waves about level 0 by up to tens of
millimetres across a lane. A depth drawn from level 0 can leave a body floating: a
partly exposed mine drawn from level 0 stood 5–14 mm above a 9 % slope all along its
bottom, over a stone's corner (20261130/2428). So the campaign draws a depth below
the surface where the object lies, its lowest point across the object's extent
(:func:`laid_in`), and a mine placed at a cut depth (counted from level 0, as the lane
counts it) is sunk, if need be, until its bottom is :data:`BURIED_BOTTOM_M` in the soil
(:func:`standing`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TypeVar

from drivers.ground_params import BuriedObjects, MineParams, RootParams, StoneParams
from drivers.soil import original_surface_height_m
from drivers.soil_params import SoilParams

BURIED_BOTTOM_M = 0.01  # a body's bottom is at least this deep in the soil
SURFACE_SAMPLE_M = 1e-4  # the surface's lowest point across a body, sampled this finely

Body = TypeVar("Body", StoneParams, RootParams, MineParams)


def lowest_surface_m(soil: SoilParams, body: StoneParams | RootParams | MineParams) -> float:
    """The untouched surface's lowest point across ``body``'s extent (sampled every
    :data:`SURFACE_SAMPLE_M`, both ends included: its waves, at most 10 mm high and at
    least 0.1 m long, bend it by under 0.1 µm between two samples)."""
    left_m, width_m = body.reach_m - 0.5 * body.width_m, body.width_m
    n = max(1, math.ceil(width_m / SURFACE_SAMPLE_M))
    return min(original_surface_height_m(soil, left_m + width_m * k / n) for k in range(n + 1))


def _below_surface(soil: SoilParams, body: Body) -> Body:
    return dataclasses.replace(body, depth_m=body.depth_m - lowest_surface_m(soil, body))


def laid_in(objects: BuriedObjects, soil: SoilParams) -> BuriedObjects:
    """``objects`` whose depths were drawn below the surface where each lies (its lowest
    point across the object), as the depths below level 0 the ground model takes."""
    return BuriedObjects(tuple(_below_surface(soil, o) for o in objects.stones),
                         tuple(_below_surface(soil, o) for o in objects.roots),
                         tuple(_below_surface(soil, o) for o in objects.mines))


def standing(mine: MineParams, soil: SoilParams) -> MineParams:
    """``mine`` (its depth below level 0), sunk if need be until its bottom is
    :data:`BURIED_BOTTOM_M` below the surface's lowest point across it."""
    deepest_top_m = lowest_surface_m(soil, mine) - BURIED_BOTTOM_M + mine.thickness_m
    return dataclasses.replace(mine, depth_m=max(mine.depth_m, -deepest_top_m))


def floating_m(soil: SoilParams, body: StoneParams | RootParams | MineParams) -> float:
    """How far ``body``'s bottom stands above the surface's lowest point across it
    (< 0: that deep in the soil)."""
    return -body.depth_m - body.thickness_m - lowest_surface_m(soil, body)
