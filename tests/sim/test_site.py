"""A campaign case's site declared (rakectl.sim.site): its soil bound, its surveyed
surface, and the campaign run with the descent limiter on (``rakectl fuzz
--declared-site``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from drivers.ground_params import RootParams
from drivers.soil import original_surface_height_m
from rakectl.cli import fuzz as fuzz_cli
from rakectl.config.descent import DescentSettings
from rakectl.core.descent import SoilBound
from rakectl.sim import campaign, cases, edge, mapped, site
from rakectl.sim.results import RESULTS_FILE, finished_results
from rakectl.sim.scenario import Scenario

SEED = 20261128  # its random cases 0–3: a lane and a jog run, a plunge and a stroke refused


@pytest.mark.parametrize("rel_std", [0.05, 0.2, 0.5])
def test_the_spot_factor_is_the_quantile_of_the_cells_lognormal_spread(rel_std: float) -> None:
    """Against draws of the spread itself: mean 1, relative std ``rel_std``; about one
    cell in 10 000 stronger than the factor (within the draw's own error)."""
    sigma = np.sqrt(np.log1p(rel_std ** 2))
    cells = np.random.default_rng(7).lognormal(-0.5 * sigma ** 2, sigma, 4_000_000)
    assert cells.mean() == pytest.approx(1.0, abs=2e-3)
    above = int((cells > site.spot_factor(rel_std)).sum())
    assert 400 * 0.8 < above < 400 * 1.2  # 1e-4 of 4e6, ±4.5 standard deviations
    assert site.spot_factor(0.0) == 1.0


@pytest.mark.parametrize("index", range(8))
def test_the_survey_stands_above_the_surface_over_the_reach_span(index: int) -> None:
    """Sampled ten times finer than the survey over the span and its margins: the
    higher of the two survey points around each sample stands above it, by at most
    twice the survey's error; the ceiling is the highest point."""
    case = cases.generate(SEED, index)
    soil, c = case.ground.soil, case.command
    declared = site.declared_descent(case)
    reaches = [p.reach_m for p in declared.survey]
    heights = [p.height_m for p in declared.survey]
    assert reaches[0] == pytest.approx(min(c.reach_near_m, c.reach_far_m)
                                       - site.SURVEY_MARGIN_M)
    end_m = max(c.reach_near_m, c.reach_far_m) + site.SURVEY_MARGIN_M
    assert end_m - 1e-9 <= reaches[-1] < end_m + site.SURVEY_STEP_M
    assert declared.ceiling_m == max(heights)
    for x in np.linspace(reaches[0], reaches[-1], 10 * len(reaches)):
        k = min(int(np.searchsorted(reaches, x, side="right")), len(reaches) - 1)
        above_m = max(heights[max(0, k - 1)], heights[k]) - original_surface_height_m(soil,
                                                                                     float(x))
        assert 0.0 < above_m <= 2 * site.SURVEY_ERROR_M


def test_a_declared_case_runs_with_its_declaration_and_the_limiter_on() -> None:
    case = dataclasses.replace(cases.generate(SEED, 0), declared_site=True)
    declared = site.declared_descent(case)
    assert campaign.scenario_of(case).descent == declared and declared.enforce
    layers = case.ground.soil.layers
    assert declared.cohesion_max_pa == max(la.cohesion_pa for la in layers)
    assert campaign.scenario_of(cases.generate(SEED, 0)).descent == DescentSettings()


def test_a_site_its_declared_soil_leaves_no_step_is_refused_naming_why() -> None:
    case = dataclasses.replace(cases.generate(SEED, 1), declared_site=True)
    s = Scenario()
    why = site.refusal(site.declared_descent(case), s.clamp.force_limit_n, s.clamp.model_margin)
    assert why.startswith("descent.enforce: leaves no step")
    result = campaign.run_case(case)
    assert result.refused == why and result.duration_s == 0.0 and result.safe
    assert campaign.run_case(cases.generate(SEED, 1)).refused == ""  # undeclared: it runs


@pytest.mark.parametrize(("argv", "declared"), [
    (["--family", "mapped"], True), (["--family", "random", "--declared-site"], True),
    (["--family", "edge"], False), ([], False)])
def test_the_cli_banner_says_when_sites_are_declared(argv: list[str], declared: bool) -> None:
    args = fuzz_cli._parser().parse_args([*argv, "--scenarios", "3", "--first", "7"])
    line = fuzz_cli.banner(args, "1 local process", "physics: Python")
    assert line.startswith(f"fuzz: cases 7..9 of seed {args.seed} ({args.family}")
    assert ("sites declared, descent limiter on" in line) is declared


def test_the_cli_runs_declared_sites_counts_the_refused_and_replays_the_worst(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status = fuzz_cli.main(["--declared-site", "--scenarios", "4", "--seed", str(SEED),
                            "--workers", "2", "--out", str(tmp_path), "--json"])
    out = capsys.readouterr().out
    summary = json.loads(out.splitlines()[-1])
    assert status == 0 and summary["refused_sites"] == 2
    assert "sites refused at load" in out
    lines = [json.loads(line) for line in (tmp_path / RESULTS_FILE).read_text().splitlines()]
    assert sorted(r["index"] for r in lines) == [0, 1, 2, 3]
    assert all(r["declared_site"] for r in lines)
    assert {r["index"] for r in lines if r["refused"]} == {1, 2}
    assert all(r["duration_s"] > 0 for r in lines if not r["refused"])
    assert summary["by_kind"]["plunge"]["refused"] == 1
    # the same cases undeclared are other results: a resumed campaign never mixes them
    assert finished_results(tmp_path / RESULTS_FILE, SEED, range(4)) == {}
    assert len(finished_results(tmp_path / RESULTS_FILE, SEED, range(4),
                                declared_site=True)) == 4
    worst = json.loads((tmp_path / "worst-case.json").read_text())
    assert worst["case"]["declared_site"] is True
    now, recorded = campaign.replay(tmp_path / "worst-case.json")
    assert now == recorded and now.declared_site


@pytest.mark.parametrize("index", range(12))
def test_a_mapped_case_is_a_declared_lane_over_one_object_under_the_soil(index: int) -> None:
    """rakectl.sim.mapped: its site declared and admitted with a step of at least
    MIN_STEP_M, one object (a mine at indices 0, 1 mod 4, a stone at 2, a root at 3) whose
    top is 2–20 mm under the soil beside its side, that side at the lane's far end
    (within the edge band) or along the lane, the lane starting clear above it."""
    case = cases.generate(SEED, index, cases.Family.MAPPED)
    assert case == cases.generate(SEED, index, cases.Family.MAPPED)
    assert case.declared_site and case.family is cases.Family.MAPPED
    assert case.command.kind is cases.CommandKind.LANE and case.duration_s == mapped.DURATION_S
    s = Scenario()
    descent = site.declared_descent(case)
    assert site.refusal(descent, s.clamp.force_limit_n, s.clamp.model_margin) == ""
    bound = SoilBound.from_settings(descent, s.clamp.force_limit_n, s.clamp.model_margin)
    assert bound.first_step_m >= mapped.MIN_STEP_M
    o = case.ground.objects
    bodies = [*o.mines, *o.stones, *o.roots]
    assert len(bodies) == 1
    assert len(o.mines if index % 4 < 2 else o.stones if index % 4 == 2 else o.roots) == 1
    body, c = bodies[0], case.command
    band_m = 0.01 if isinstance(body, RootParams) else edge.EDGE_BAND_M  # a root's round side
    soil = case.ground.soil
    drawn = [x for x in (body.reach_m - 0.5 * body.width_m, body.reach_m + 0.5 * body.width_m)
             if (abs(x - c.reach_far_m) <= band_m + 1e-12
                 or c.reach_near_m + mapped.INSIDE_ENDS_M <= x <= c.reach_far_m
                 - mapped.INSIDE_ENDS_M)
             and mapped.TOP_BELOW_SOIL_M[0] - 1e-9 <= original_surface_height_m(soil, x)
             + body.depth_m <= mapped.TOP_BELOW_SOIL_M[1] + 1e-9]
    assert drawn  # the side it was drawn by
    surface_m = original_surface_height_m(case.ground.soil, c.reach_far_m)
    assert surface_m + c.start_height_m >= -body.depth_m or abs(
        c.reach_far_m - body.reach_m) > 0.5 * body.width_m  # above it, or beside it


def test_a_mapped_lane_meets_its_buried_object_within_the_limit() -> None:
    """Mapped case 2 of seed 20261128: a force-adaptive lane in its surveyed, declared
    soil cuts down to a stone whose top is under the soil, meets its side and stops there
    (found), the stone and the ground far under 90 N (the campaign's figures:
    docs/safety-log.md)."""
    case = cases.generate(SEED, 2, cases.Family.MAPPED)
    assert case.ground.objects.stones and case.command.adaptive
    result = campaign.run_case(case)
    assert result.declared_site and not result.refused and result.safe
    assert result.object_found and 0.0 < result.f_stone_side_max_n < 45.0
    assert result.f_true_z_max_n < 45.0
