"""A campaign case's site as its operator would declare it, for the descent limiter.

With ``descent.enforce`` the controller needs two site inputs (docs/safety.md, "Not
covered"): the strongest soil it may meet (the ``descent:`` section, checked in
operation by the drag read from the currents) and where the surface stands (its
``survey`` along the reach, and ``ceiling_m`` beyond it). A case run with its site
declared takes both from its own ground, as a survey would give them:

- the soil: each parameter of the earthmoving equation at its strongest over the
  case's layers, and the spots' factor at the 99.99th percentile of the cells' lognormal
  spread (about one 5 mm cell in 10 000 stronger);
- the survey: the undisturbed surface every :data:`SURVEY_STEP_M` over the commanded
  reach span and :data:`SURVEY_MARGIN_M` either side, :data:`SURVEY_ERROR_M` added
  (between two points the surface stands less than that above the higher: its waves
  bend it by microns over 2 mm); the ceiling the highest of those points.

A site whose declared soil leaves the limiter no step is refused as the daemon refuses
such a configuration at load: :func:`refusal` names why, and nothing moves.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import TYPE_CHECKING, Final

from drivers.soil import original_surface_height_m
from drivers.soil_params import SoilParams
from rakectl.config.descent import DescentSettings, SurveyPoint, descent_checks

if TYPE_CHECKING:  # cases draws its sites with this module
    from rakectl.sim.cases import FuzzCase

SPOT_QUANTILE: Final = 0.9999  # of a cell's strength over the soil's mean
SURVEY_MARGIN_M: Final = 0.1  # beyond the commanded reach span, either side
SURVEY_STEP_M: Final = 0.002  # between surveyed points
SURVEY_ERROR_M: Final = 0.001  # added to the highest surveyed point


def spot_factor(strength_rel_std: float, quantile: float = SPOT_QUANTILE) -> float:
    """The ``quantile`` of a lognormal cell strength of mean 1 and relative spread
    ``strength_rel_std`` (never below 1)."""
    sigma = math.sqrt(math.log1p(strength_rel_std ** 2))
    return max(1.0, math.exp(-0.5 * sigma * sigma + NormalDist().inv_cdf(quantile) * sigma))


def surveyed_surface(soil: SoilParams, reach_a_m: float, reach_b_m: float
                     ) -> tuple[SurveyPoint, ...]:
    """The undisturbed surface over the span and SURVEY_MARGIN_M either side, every
    SURVEY_STEP_M, SURVEY_ERROR_M added."""
    low_m = min(reach_a_m, reach_b_m) - SURVEY_MARGIN_M
    points = math.ceil((max(reach_a_m, reach_b_m) + SURVEY_MARGIN_M - low_m) / SURVEY_STEP_M
                       - 1e-9)  # the last at or past the span's end
    reaches = (low_m + k * SURVEY_STEP_M for k in range(points + 1))
    return tuple(SurveyPoint(x, original_surface_height_m(soil, x) + SURVEY_ERROR_M)
                 for x in reaches)


def declared_descent(case: FuzzCase) -> DescentSettings:
    """The case's site declared: its strongest soil, its surveyed surface, the limiter on."""
    command = case.command
    return site_descent(case.ground.soil, command.reach_near_m, command.reach_far_m)


def site_descent(soil: SoilParams, reach_a_m: float, reach_b_m: float) -> DescentSettings:
    """A site of ``soil`` declared for work between two reaches (see the module)."""
    layers, survey = soil.layers, surveyed_surface(soil, reach_a_m, reach_b_m)
    return DescentSettings(
        cohesion_max_pa=max(layer.cohesion_pa for layer in layers),
        friction_angle_max_rad=max(layer.friction_angle_rad for layer in layers),
        tool_friction_angle_max_rad=max(layer.tool_friction_angle_rad for layer in layers),
        unit_weight_max_n_per_m3=max(layer.unit_weight_n_per_m3 for layer in layers),
        strength_factor=spot_factor(soil.strength_rel_std), enforce=True,
        ceiling_m=max(point.height_m for point in survey), survey=survey)


def refusal(descent: DescentSettings, force_limit_n: float, model_margin: float) -> str:
    """Why the daemon would refuse this declaration at load ('' if it would not)."""
    return "; ".join(f"{key}: {message}"
                     for key, message in descent_checks(descent, force_limit_n, model_margin))
