"""A campaign case's site declared (rakectl.sim.site): its soil bound, its surveyed
surface, and the campaign run with the descent limiter on (``rakectl fuzz
--declared-site``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from drivers.soil import original_surface_height_m
from rakectl.cli import fuzz as fuzz_cli
from rakectl.config.descent import DescentSettings
from rakectl.sim import campaign, cases, site
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
    """Sampled ten times finer than the survey, over the span and its margins."""
    case = cases.generate(SEED, index)
    soil, c = case.ground.soil, case.command
    ceiling_m = site.declared_descent(case).ceiling_m
    low_m = min(c.reach_near_m, c.reach_far_m) - site.SURVEY_MARGIN_M
    high_m = max(c.reach_near_m, c.reach_far_m) + site.SURVEY_MARGIN_M
    highest_m = max(original_surface_height_m(soil, float(x))
                    for x in np.linspace(low_m, high_m, 2000))
    assert highest_m < ceiling_m <= highest_m + 2 * site.SURVEY_ERROR_M


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
