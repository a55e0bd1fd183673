"""The descent budget's options, declared once (pure): the strongest soil the robot may
meet and the rake's cutting geometry, from which :mod:`rakectl.core.descent` derives how
deep the tines may go below the soil beside them. A section of
:class:`rakectl.config.settings.Settings`.

Why a budget at all: where an object's rounded edge forces descending tines sideways,
the soil beside them resists with its cutting resistance H(c) at their depth c below
it, and the object carries H(c) on top of what the mount pushes (docs/safety.md, "Not
covered"). The clamp bounds the mount's share by F_L = (1 − clamp.model_margin) ·
clamp.force_limit_n; the budget keeps H(c) within the rest.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from rakectl.config.declare import setting
from rakectl.errors import ConfigError


@dataclass(frozen=True)
class SurveyPoint:
    """One point of a survey of the undisturbed surface along the reach."""

    reach_m: float = setting(1.0, "Reach of the point.", unit="m", ge=0, le=20)
    height_m: float = setting(
        0.0, "Height of the surface there above ground level 0, the survey's error added: "
        "never below the true surface.", unit="m", ge=-0.5, le=1)


@dataclass(frozen=True)
class DescentSettings:
    """The strongest admitted soil and the rake's cutting geometry (the descent budget)."""

    cohesion_max_pa: float = setting(
        15.0e3, "Largest mean soil cohesion c the robot may meet (the campaign's soils: "
        "2–15 kPa).", unit="Pa", gt=0, le=1e6)
    friction_angle_max_rad: float = setting(
        math.radians(35.0), "Largest internal friction angle φ of the soil.", unit="rad",
        ge=0, lt=1.3)
    tool_friction_angle_max_rad: float = setting(
        math.radians(23.5), "Largest soil–tine friction angle δ.", unit="rad", ge=0, lt=1.3)
    unit_weight_max_n_per_m3: float = setting(
        20.0e3, "Largest unit weight γ of the soil.", unit="N/m³", gt=0, le=1e5)
    surcharge_max_pa: float = setting(
        0.0, "Largest surcharge q on the soil beside the tines (spoil heaped there: about "
        "γ times its height, 0.3 kPa for 20 mm).", unit="Pa", ge=0, le=1e5)
    rake_width_m: float = setting(
        0.15, "Width of soil the rake cuts (its tines and the soil failing between them).",
        unit="m", gt=0, le=2)
    rake_angle_rad: float = setting(
        math.radians(60.0), "Angle of the tines' face from the horizontal.", unit="rad",
        gt=0.1, lt=1.5)
    strength_factor: float = setting(
        3.2, "Strength of the strongest spot of soil over the soil's mean. Spots spread "
        "lognormally by ±50 % exceed 3.2 once in 290, by ±20 % exceed 1.7 once in 370 (the "
        "emulator's 5 mm cells).", ge=1, le=100)
    drag_margin_n: float = setting(
        0.0, "Kept back from the cutting resistance's budget (clamp.force_limit_n · "
        "clamp.model_margin) for its estimate's error.", unit="N", ge=0, le=90)
    enforce: bool = setting(
        False, "Hold every depth reference at the ground map's floor (rakectl.core.ground_map): "
        "no deeper than the step below the highest soil within side_reach_m. Off until the "
        "lane and the jog plan within it: they stall against the floor where no pass has "
        "mapped the ground.")
    ceiling_m: float = setting(
        0.06, "Highest the soil's surface stands above ground level 0 anywhere in the "
        "workspace (a site survey): the map's top where no pass has been, outside the "
        "survey's span.", unit="m",
        ge=-0.5, le=1)
    survey: tuple[SurveyPoint, ...] = setting(
        (), "The undisturbed surface along the reach, surveyed: points in increasing reach, "
        "none above ceiling_m; between two consecutive points the higher stands for the "
        "surface. Within its span it is the map's top where no pass has been, ceiling_m "
        "outside it (empty: ceiling_m everywhere). Each point gives both its reach_m and "
        "its height_m.", whole_items=True)
    side_reach_m: float = setting(
        0.01, "How far along the reach an object's edge can push descending tines (a mine's "
        "rim 3 mm, a stone's edge 5 mm) plus the reach's error.", unit="m", ge=0.005, le=0.1)
    mount_force_margin_n: float = setting(
        3.0, "Added to the vertical force read from the currents before the tines' height "
        "above the tip is taken as that force over clamp.contact_stiffness_n_per_m (the "
        "estimate lags a sudden press by its filter).", unit="N", ge=0, le=90)
    min_step_m: float = setting(
        0.5e-3, "Smallest descent step worth taking; a strongest soil whose first step is "
        "smaller is refused at load.", unit="m", gt=0, le=0.1)


def descent_checks(descent: DescentSettings, force_limit_n: float, model_margin: float
                   ) -> list[tuple[str, str]]:
    """The budget must leave the cutting resistance something, the tine's face must admit
    a failure wedge, and the strongest soil's first step must be worth taking:
    (dotted key, message) for each violation."""
    # the derivation, imported here: rakectl.core.descent imports this module's types
    from rakectl.core.descent import TRACKING_MARGIN_M, SoilBound
    budget_n = force_limit_n * model_margin
    for i, (a, b) in enumerate(itertools.pairwise(descent.survey)):
        if not b.reach_m > a.reach_m:
            return [(f"descent.survey[{i + 1}].reach_m", f"must be > the previous point's "
                     f"({a.reach_m:g} m), got {b.reach_m:g}")]
    for i, point in enumerate(descent.survey):
        if point.height_m > descent.ceiling_m:
            return [(f"descent.survey[{i}].height_m", f"must be <= descent.ceiling_m "
                     f"({descent.ceiling_m:g} m), got {point.height_m:g}")]
    if descent.drag_margin_n >= budget_n:
        return [("descent.drag_margin_n", f"must be < clamp.force_limit_n · clamp.model_margin "
                 f"({budget_n:g} N), got {descent.drag_margin_n:g}")]
    try:
        bound = SoilBound.from_settings(descent, force_limit_n, model_margin)
    except ConfigError as error:
        return [("descent.rake_angle_rad", f"leaves {error}")]
    if descent.enforce and bound.first_step_m - TRACKING_MARGIN_M < descent.min_step_m:
        return [("descent.enforce", "leaves no step: the declared soil (descent.*_max, "
                 f"strength_factor) allows {bound.first_step_m * 1e3:.3g} mm below the soil "
                 f"beside the tines, less the limiter's {TRACKING_MARGIN_M * 1e3:g} mm "
                 f"tracking margin is under descent.min_step_m "
                 f"({descent.min_step_m * 1e3:g} mm): declare the site's soil")]
    if bound.first_step_m < descent.min_step_m:
        return [("descent.min_step_m", "leaves no step within the bound: the strongest "
                 "admitted soil (descent.*_max, strength_factor) reaches the cutting "
                 f"resistance's budget ({bound.budget_n:g} N: clamp.force_limit_n · "
                 f"clamp.model_margin − descent.drag_margin_n) {bound.first_step_m * 1e3:.3g} "
                 f"mm deep, less than {descent.min_step_m * 1e3:g} mm")]
    return []
