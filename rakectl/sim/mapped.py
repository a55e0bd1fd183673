"""The ``mapped`` family: lanes that map the ground as they cut it, with the descent
limiter on, over a buried object whose side they descend beside.

The limiter (``descent.enforce``, docs/safety.md "Not covered") lets the tines down
only a step d* below the highest soil a pass has mapped within the side reach, so a
plunge into unmapped ground stops in the air and the random and edge families, run with
their sites declared, touch only objects standing out of the soil. What it bounds is
the descent beside a buried object's edge once the passes above have cut down to it:
this family draws that.

Each case is a lane (the lane kind's parameters: steps, target depths, stroke and
plunge speeds, half of them force-adaptive) with its site declared
(:mod:`rakectl.sim.site`), on a soil of the campaign's whose declaration leaves the
limiter a step of at least :data:`MIN_STEP_M` (each pass deepens by about d* less
3 mm: the limiter's tracking margin and the mount's compression), drawn again until one
does. Under it one object (a mine at indices 0, 1 mod 4, a stone at 2, a root at 3),
its top 2–12 mm below the soil beside its side; that side, in a quarter of the cases,
within :data:`~rakectl.sim.edge.EDGE_BAND_M` of the lane's far end, where every cycle
plunges (the lane's passes terrace up toward its ends, beside soil they never cross), in
the others at least :data:`INSIDE_ENDS_M` inside both ends. A lane the limit holds short
of its target is asked again, as an operator would, until the case ends (60 s). Faults
and supervision as in the other families.
"""

from __future__ import annotations

import dataclasses
from typing import Final

import numpy as np

from drivers.ground_params import GroundParams
from drivers.soil import original_surface_height_m
from drivers.soil_params import SoilParams
from rakectl.config.settings import ClampSettings
from rakectl.core.descent import SoilBound
from rakectl.sim.cases import (
    FAULT_KINDS,
    CommandKind,
    Family,
    FuzzCase,
    MotionCommand,
    draw_faults,
    draw_soil,
    height_clear_of,
    loguniform,
)
from rakectl.sim.edge import EDGE_BAND_M, edge_object
from rakectl.sim.site import site_descent

DURATION_S: Final = 60.0  # simulated: the passes above the object take most of it
MIN_STEP_M: Final = 4.5e-3  # of the declared soil's d*
MAX_SOIL_DRAWS: Final = 1000
TOP_BELOW_SOIL_M: Final = (0.002, 0.012)  # the object's top under the soil beside its side
AT_FAR_END: Final = 0.25  # the share of cases whose object's side is at the lane's far end
INSIDE_ENDS_M: Final = 0.06  # the others' side at least this far inside the lane's ends


def admitted_soil(rng: np.random.Generator, near_m: float, far_m: float) -> SoilParams:
    """The first of the campaign's soils whose site, declared for this lane, leaves the
    limiter a step of at least MIN_STEP_M."""
    clamp = ClampSettings()  # the budget is its share of the limit
    for _ in range(MAX_SOIL_DRAWS):
        soil = draw_soil(rng)
        bound = SoilBound.from_settings(site_descent(soil, near_m, far_m), clamp.force_limit_n,
                                        clamp.model_margin)
        if bound.first_step_m >= MIN_STEP_M:
            return soil
    raise RuntimeError(f"no soil in {MAX_SOIL_DRAWS} draws leaves a {MIN_STEP_M * 1e3:g} mm "
                       "step")  # about one draw in five does


def mapped_case(seed: int, index: int) -> FuzzCase:
    """The ``index``-th case of the mapped family of campaign ``seed`` (see the module)."""
    rng = np.random.default_rng([seed, index, 3])
    kind = 0 if index % 4 < 2 else index % 4 - 1
    far_m = float(rng.uniform(0.95, 1.35))
    near_m = far_m - float(rng.uniform(0.2, 0.4))
    soil = admitted_soil(rng, near_m, far_m)
    command = MotionCommand(CommandKind.LANE, far_m, near_m, float(rng.uniform(0.005, 0.03)),
                            float(rng.uniform(0.03, 0.08)), loguniform(rng, 0.01, 1.0),
                            loguniform(rng, 0.002, 0.1), float(rng.uniform(0.02, 0.06)), True,
                            adaptive=bool(rng.integers(0, 2)))
    toward_robot = bool(rng.integers(0, 2))  # the object beyond its side, or before it
    if rng.uniform() < AT_FAR_END:  # its side at the far end's plunges
        inside_m = float(rng.uniform(-EDGE_BAND_M, 0.01 if kind == 2 else EDGE_BAND_M))
        side_m = far_m - inside_m if toward_robot else far_m + inside_m
    else:  # where the lane's passes cut deepest, clear of its terraced ends
        side_m = float(rng.uniform(near_m + INSIDE_ENDS_M, far_m - INSIDE_ENDS_M))
    top_m = original_surface_height_m(soil, side_m) - float(rng.uniform(*TOP_BELOW_SOIL_M))
    objects = edge_object(rng, kind, side_m, toward_robot, -top_m)
    command = dataclasses.replace(command, start_height_m=max(
        command.start_height_m,
        height_clear_of(objects, far_m, original_surface_height_m(soil, far_m))))
    faults = draw_faults(rng, (index // 4) % (len(FAULT_KINDS) + 1), DURATION_S)
    return FuzzCase(seed, index, GroundParams(soil, objects), int(rng.integers(0, 2**32)),
                    command, faults, DURATION_S, (index // 24) % 2 == 1, Family.MAPPED,
                    declared_site=True)
