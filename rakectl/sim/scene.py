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

Each body's reach and depth are drawn apart from the others', and the planar ground
reads every body across the rake's whole width, so two bodies whose extents overlap
would be two bodies in one place, a stone inside a mine (more than half the random
family's scenes draw such a pair): no ground holds that, a body laid into a mine
covers its plate, and tines between the two read both at once. :func:`apart` leaves
out each body that overlaps one kept before it.
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


def overlap(a: StoneParams | RootParams | MineParams,
            b: StoneParams | RootParams | MineParams) -> bool:
    """Whether ``a`` and ``b``'s extents overlap both along the reach and in depth (by
    more than touching; a root's is the square about its section)."""
    along_m = min(a.reach_m + 0.5 * a.width_m, b.reach_m + 0.5 * b.width_m) \
        - max(a.reach_m - 0.5 * a.width_m, b.reach_m - 0.5 * b.width_m)
    down_m = min(a.depth_m + a.thickness_m, b.depth_m + b.thickness_m) \
        - max(a.depth_m, b.depth_m)
    return along_m > 0.0 and down_m > 0.0


def apart(objects: BuriedObjects, first: MineParams | None = None) -> BuriedObjects:
    """``objects`` less each body that overlaps (:func:`overlap`) one kept before it:
    ``first`` (one of ``objects.mines``) kept first of all, then the mines, the stones and
    the roots in the order drawn. The bodies kept keep their order."""
    order: list[StoneParams | RootParams | MineParams] = [
        *([first] if first is not None else []),
        *(m for m in objects.mines if m is not first), *objects.stones, *objects.roots]
    kept: list[StoneParams | RootParams | MineParams] = []
    for body in order:
        if not any(overlap(body, other) for other in kept):
            kept.append(body)

    kept_ids = {id(body) for body in kept}

    def keep(bodies: tuple[Body, ...]) -> tuple[Body, ...]:
        return tuple(b for b in bodies if id(b) in kept_ids)

    return BuriedObjects(keep(objects.stones), keep(objects.roots), keep(objects.mines))
