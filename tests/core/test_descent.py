"""The descent budget's soil bound: the earthmoving equation against the emulator's own
implementation, its root against bisection and the documented figures, its monotony in
every soil property it takes the largest of, and the configuration that fails fast."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.soil import cutting_factors, cutting_force_n
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.config.descent import DescentSettings
from rakectl.config.loader import load_settings
from rakectl.core.control import build_descent
from rakectl.core.descent import SoilBound, wedge_factors
from rakectl.errors import ConfigError

FORCE_LIMIT_N, MODEL_MARGIN = 90.0, 0.2
BUDGET_N = 18.0  # 90 N less the clamp's F_L = 72 N

phis = st.floats(math.radians(15.0), math.radians(40.0))
deltas = st.floats(math.radians(5.0), math.radians(30.0))
rakes = st.floats(math.radians(40.0), math.radians(80.0))


def _bound(**changes: float) -> SoilBound:
    return SoilBound.from_settings(dataclasses.replace(DescentSettings(), **changes),
                                   FORCE_LIMIT_N, MODEL_MARGIN)


def _emulated_h_n(d: DescentSettings, depth_m: float) -> float:
    """The emulator's drag of a mean cell in the soil ``d`` names."""
    layer = SoilLayer(cohesion_pa=d.cohesion_max_pa, friction_angle_rad=d.friction_angle_max_rad,
                      tool_friction_angle_rad=d.tool_friction_angle_max_rad,
                      unit_weight_n_per_m3=d.unit_weight_max_n_per_m3)
    params = SoilParams(layers=(layer,), width_m=d.rake_width_m, rake_angle_rad=d.rake_angle_rad,
                        surcharge_pa=d.surcharge_max_pa)
    return cutting_force_n(layer, params, depth_m)


@settings(max_examples=200, deadline=None)
@given(rake=rakes, phi=phis, delta=deltas)
def test_wedge_factors_match_the_emulators_search(rake: float, phi: float, delta: float) -> None:
    ours, theirs = wedge_factors(rake, phi, delta), cutting_factors(rake, phi, delta)
    assert ours.n_gamma == pytest.approx(theirs.n_gamma, rel=1e-9)
    assert ours.n_c == pytest.approx(theirs.n_c, rel=1e-6)  # N_c at β, known to the grid's step
    assert ours.failure_angle_rad == pytest.approx(theirs.failure_angle_rad, abs=1e-5)


@settings(max_examples=200, deadline=None)
@given(cohesion=st.floats(0.0, 3e4), phi=phis, delta=deltas, gamma=st.floats(1e4, 2.5e4),
       q=st.floats(0.0, 2e3), width=st.floats(0.05, 0.5), rake=rakes,
       depth=st.floats(1e-4, 0.15))
def test_resistance_matches_the_emulators_drag(cohesion: float, phi: float, delta: float,
                                               gamma: float, q: float, width: float,
                                               rake: float, depth: float) -> None:
    d = DescentSettings(cohesion_max_pa=max(cohesion, 1.0), friction_angle_max_rad=phi,
                        tool_friction_angle_max_rad=delta, unit_weight_max_n_per_m3=gamma,
                        surcharge_max_pa=q, rake_width_m=width, rake_angle_rad=rake,
                        strength_factor=1.0)
    bound = SoilBound.from_settings(d, FORCE_LIMIT_N, MODEL_MARGIN)
    assert bound.resistance_n(depth) == pytest.approx(_emulated_h_n(d, depth), rel=1e-6)
    assert bound.resistance_n(0.0) == bound.resistance_n(-depth) == 0.0


@settings(max_examples=100, deadline=None)
@given(factor=st.floats(1.0, 5.0), force=st.floats(0.5, 80.0))
def test_the_depth_is_the_root_bisection_finds(factor: float, force: float) -> None:
    d = dataclasses.replace(DescentSettings(), strength_factor=factor)
    bound = SoilBound.from_settings(d, FORCE_LIMIT_N, MODEL_MARGIN)
    low, high = 0.0, 1.0
    for _ in range(100):  # on the emulator's drag of the strongest spot
        mid = 0.5 * (low + high)
        low, high = (mid, high) if factor * _emulated_h_n(d, mid) < force else (low, mid)
    assert bound.depth_m(force) == pytest.approx(low, rel=1e-6)
    assert bound.resistance_n(bound.depth_m(force)) == pytest.approx(force, rel=1e-9)


@pytest.mark.parametrize(("cohesion_pa", "phi_deg", "first_step_mm"), [
    (15e3, 30.0, 3.0),  # docs/safety.md, "Not covered": the campaign's strongest soil
    (2e3, 30.0, 20.6),  # the campaign's weakest
])
def test_a_mean_cell_reaches_the_budget_at_the_documented_cut(cohesion_pa: float, phi_deg: float,
                                                               first_step_mm: float) -> None:
    bound = _bound(cohesion_max_pa=cohesion_pa, friction_angle_max_rad=math.radians(phi_deg),
                   tool_friction_angle_max_rad=math.radians(20.0),
                   unit_weight_max_n_per_m3=16e3, strength_factor=1.0)
    assert bound.budget_n == pytest.approx(BUDGET_N)
    assert bound.first_step_m * 1e3 == pytest.approx(first_step_mm, abs=0.05)


def test_the_robots_bound_is_the_strongest_spot_of_the_strongest_soil() -> None:
    bound = _bound()
    assert bound.resistance_n(bound.first_step_m) == pytest.approx(BUDGET_N)
    # 3.2 times the mean cell of 15 kPa, 35°, δ 23.5°, 20 kN/m³: under a millimetre
    assert 0.7e-3 < bound.first_step_m < 0.9e-3
    assert _bound(drag_margin_n=6.0).first_step_m < bound.first_step_m


# The soils of the levers' table in docs/safety.md ("Not covered"), in its columns' order:
# (cohesion Pa, φ°, δ°, γ N/m³, the strongest spot's factor).
LEVER_SOILS = [(500.0, 32.0, 20.0, 16e3, 1.7), (6e3, 28.0, 18.0, 18e3, 1.7),
               (10e3, 20.0, 15.0, 18e3, 1.7), (12e3, 30.0, 20.0, 18e3, 1.7),
               (15e3, 30.0, 20.0, 16e3, 3.2)]


def test_the_safety_cases_table_of_levers_is_what_the_bound_computes() -> None:
    """Each d* of the table of the width and budget levers is the bound's, to the three
    figures printed."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "safety.md").read_text()
    rows = [line for line in text.splitlines()
            if re.match(r"\| [0-9.]+ m, [0-9]+ N \([0-9]+ N\)", line)]
    assert len(rows) >= 6
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        lever = re.match(r"([0-9.]+) m, ([0-9]+) N", cells[0])
        assert lever is not None
        width_m, f_l_n = float(lever[1]), float(lever[2])
        for printed, (c, phi, delta, gamma, factor) in zip(cells[1:], LEVER_SOILS, strict=True):
            bound = SoilBound.from_settings(
                dataclasses.replace(DescentSettings(), cohesion_max_pa=c,
                                    friction_angle_max_rad=math.radians(phi),
                                    tool_friction_angle_max_rad=math.radians(delta),
                                    unit_weight_max_n_per_m3=gamma, strength_factor=factor,
                                    rake_width_m=width_m),
                FORCE_LIMIT_N, 1.0 - f_l_n / FORCE_LIMIT_N)
            assert bound.first_step_m * 1e3 == pytest.approx(float(printed), rel=0.006), row


@settings(max_examples=300, deadline=None)
@given(phi=phis, delta=deltas, depth=st.floats(1e-4, 0.1), which=st.sampled_from(
    ["cohesion_max_pa", "friction_angle_max_rad", "tool_friction_angle_max_rad",
     "unit_weight_max_n_per_m3", "surcharge_max_pa"]), rise=st.floats(1e-3, 0.3))
def test_resistance_grows_with_every_property_the_bound_takes_the_largest_of(
        phi: float, delta: float, depth: float, which: str, rise: float) -> None:
    base = dataclasses.replace(DescentSettings(), friction_angle_max_rad=phi,
                               tool_friction_angle_max_rad=delta, surcharge_max_pa=500.0)
    value = getattr(base, which)
    stronger = dataclasses.replace(base, **{which: value * (1.0 + rise)})
    h = SoilBound.from_settings(base, FORCE_LIMIT_N, MODEL_MARGIN).resistance_n(depth)
    assert SoilBound.from_settings(stronger, FORCE_LIMIT_N, MODEL_MARGIN).resistance_n(depth) > h


@pytest.mark.parametrize(("override", "named"), [
    ("descent.drag_margin_n=18", "descent.drag_margin_n must be < clamp.force_limit_n · "
     "clamp.model_margin (18 N), got 18"),
    ("descent.min_step_m=0.002", "descent.min_step_m leaves no step within the bound: the "
     "strongest admitted soil"),
    ("descent.rake_angle_rad=1.45", "descent.rake_angle_rad leaves no admissible failure wedge"),
    ("descent.enforce=true", "descent.enforce leaves no step: the declared soil (descent.*_max, "
     "strength_factor) allows 0.783 mm below the soil beside the tines, less the limiter's 1 mm "
     "tracking margin"),
])
def test_a_bound_that_leaves_no_step_is_refused_naming_the_key(override: str,
                                                               named: str) -> None:
    overrides = [override]
    if "rake_angle" in override:  # a steep face with friction leaves no wedge
        overrides.append("descent.tool_friction_angle_max_rad=1.2")
    with pytest.raises(ConfigError) as info:
        load_settings(None, overrides)
    assert named in str(info.value)
    assert "\n" not in str(info.value)


def test_the_default_configuration_loads_with_its_first_step() -> None:
    s = load_settings()
    bound = SoilBound.from_settings(s.descent, s.clamp.force_limit_n, s.clamp.model_margin)
    assert bound.first_step_m >= s.descent.min_step_m


@pytest.mark.parametrize(("points", "named"), [
    ([(1.0, 0.0), (1.0, 0.01)], "descent.survey[1].reach_m must be > the previous point's "
     "(1 m), got 1"),
    ([(1.0, 0.0), (1.1, 0.07)], "descent.survey[1].height_m must be <= descent.ceiling_m "
     "(0.06 m), got 0.07"),
])
def test_a_survey_out_of_order_or_above_the_ceiling_is_refused_naming_the_point(
        tmp_path: Path, points: list[tuple[float, float]], named: str) -> None:
    config = tmp_path / "rakectl.yaml"
    config.write_text(yaml.safe_dump({"descent": {"survey": [
        {"reach_m": r, "height_m": h} for r, h in points]}}))
    with pytest.raises(ConfigError) as info:
        load_settings(config, [])
    assert named in str(info.value)
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump({"descent": {"survey": [
        {"reach_m": 1.0, "height_m": 0.0}, {"reach_m": 1.1, "height_m": 0.01}]}}))
    assert load_settings(good, []).descent.survey[1].height_m == 0.01


def test_the_controllers_ground_map_starts_from_the_configured_survey(tmp_path: Path) -> None:
    """A site declared loam with a survey from 1.0 to 1.1 m: the controller's map stands
    at the survey within its span and at the ceiling beyond it."""
    config = tmp_path / "site.yaml"
    config.write_text(yaml.safe_dump({"descent": {
        "enforce": True, "cohesion_max_pa": 6e3, "friction_angle_max_rad": math.radians(28.0),
        "tool_friction_angle_max_rad": math.radians(18.0), "unit_weight_max_n_per_m3": 18e3,
        "strength_factor": 1.7, "ceiling_m": 0.05,
        "survey": [{"reach_m": 1.0 + 0.01 * k, "height_m": 0.001 * k} for k in range(11)]}}))
    limiter = build_descent(load_settings(config, []))
    assert limiter is not None
    ground = limiter.map
    assert ground.top_m[ground.cell(1.0425)] == pytest.approx(0.005)  # 1.04–1.05 m: k = 5
    assert ground.top_m[ground.cell(1.2)] == ground.top_m[ground.cell(0.9)] == 0.05
