"""`rakectl fuzz --trace`: one case substep by substep, read without changing it (the
campaign's own result), its largest push on an object the one the result records,
and the massless tines' balance along the reach at it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rakectl.sim import campaign, trace
from rakectl.sim.case_files import read_case_file
from rakectl.sim.cases import Family
from tests.cli_run import run_rakectl

RIM = Path(__file__).resolve().parents[1] / "data" / "fuzz" / "open-mine-rim-9937.json"
OVER_READ = RIM.parent / "20261202-5801.json"


def test_a_traced_case_runs_as_the_campaign_runs_it() -> None:
    """The recorder only reads: the result is the campaign's, field for field."""
    case, _ = read_case_file(RIM)
    traced = trace.trace_case(case)
    assert traced.result == campaign.run_case(case)
    assert traced.body_kinds == ("stone", "stone", "mine", "mine")


def test_the_largest_push_is_the_side_force_the_result_records() -> None:
    """The open rim case (a mine's side over the limit): the traced peak is the mine's
    recorded side force, to the bit; there the tines balance along the reach (the mine
    against the soil and the mount) within 0.5 N, and the soil's share is its cutting
    resistance at their cut (a mean cell's H within the cells' spread, ±20 %). Every
    traced call balances within 10 N (7.0 N at most), a call in which the mine and a
    stone both push the tines counting both."""
    case, _ = read_case_file(RIM)
    traced = trace.trace_case(case)
    peak = traced.rows[traced.peak]
    assert traced.body_kinds[peak.body] == "mine"
    assert abs(peak.body_reach_n) == traced.result.f_mine_side_max_n > 90.0
    assert abs(peak.residual_n) < 0.5
    assert peak.soil_reach_n * peak.body_reach_n < 0.0  # the soil pushes back
    h_n = traced.resistance_n(peak)
    assert 0.8 * h_n <= abs(peak.soil_reach_n) <= 1.2 * h_n
    touching: list[bool] = []  # per tick of the case, whether an object pushes the tines
    campaign.run_case(case, on_tick=lambda loop: touching.append(any(
        b.force_reach_n != 0.0 or b.force_up_n != 0.0 for b in loop.ground.bodies)))
    first_s = touching.index(True) * 0.001  # the case's own clock (1 kHz), as the result's
    assert traced.rows[0].time_s == pytest.approx(first_s, abs=1e-9)
    assert peak.time_s < traced.result.duration_s
    assert max(abs(row.residual_n) for row in traced.rows) < 10.0  # every call, near enough
    calls: dict[tuple[float, int], list[trace.SubstepForces]] = {}
    for row in traced.rows:
        calls.setdefault((row.time_s, row.part), []).append(row)
    shared = [rows for rows in calls.values() if len(rows) > 1]  # the mine and a stone
    assert shared and all(rows[0].residual_n == pytest.approx(rows[1].residual_n, abs=1e-9)
                          for rows in shared)
    window = traced.window(traced.peak)
    assert peak in window and {row.body for row in window} == {peak.body}
    assert len(window) == 2 * trace.WINDOW + 1


def test_a_case_without_a_push_along_the_reach_has_no_peak() -> None:
    """Random cases of seed 20261127: case 2 touches no object (no rows); case 0 presses
    objects' tops only (rows, all up)."""
    untouched = trace.trace_case(campaign.generated_case(20261127, 2, Family.RANDOM, False))
    assert untouched.rows == () and untouched.peak == -1
    assert "no object pushed the tines along the reach" in trace.describe(untouched)
    figures = trace.summary(untouched)
    assert {key: figures[key] for key in ("index", "seed", "family", "traced_calls")} == {
        "index": 2, "seed": 20261127, "family": "random", "traced_calls": 0}
    assert "body" not in figures and figures["ground_soil_pressed_by"] == "tines"
    tops = trace.trace_case(campaign.generated_case(20261127, 0, Family.RANDOM, False))
    assert tops.rows and tops.peak == -1
    assert all(row.body_reach_n == 0.0 < row.body_up_n for row in tops.rows)
    assert any(line.startswith("no object pushed the tines along the reach (tops only: ")
               for line in trace.describe(tops))


def test_the_largest_vertical_reading_is_the_results_against_what_the_mount_carried() -> None:
    """The largest vertical reading is the result's, to the bit, with the calls around it.
    Where the soil alone is pressed by the tines (case 2 of 20261127), the reading is what
    the mount carried into the ground. 20261202/5801 read 65.6 N while the mount carried
    14.2 N: the tines rest in a root's rounded side, the soil the root hides from them is
    pressed by its surface and counted on them (docs/safety-log.md, 2026-12-01)."""
    plain = trace.trace_case(campaign.generated_case(20261127, 2, Family.RANDOM, False))
    peak = plain.ground_peak
    assert peak is not None and peak.reading_n == plain.result.f_true_z_max_n > 0.0
    assert peak.hidden_by == -1 and peak.mount_n == pytest.approx(peak.reading_n, abs=1e-9)
    assert plain.excess is not None and abs(plain.excess.excess_n) < 1e-6
    assert peak in plain.ground and len(plain.ground) == 2 * trace.WINDOW + 1
    assert [row.time_s for row in plain.ground] == sorted(row.time_s for row in plain.ground)
    case, recorded = read_case_file(OVER_READ)
    over = trace.trace_case(case)
    assert over.result == recorded
    peak = over.ground_peak
    assert peak is not None and peak.reading_n == over.result.f_true_z_max_n
    assert over.body_kinds[peak.hidden_by] == "root"
    assert 14.0 < peak.mount_n < 15.5 and peak.reading_n - peak.mount_n > 45.0
    assert peak.reading_n == pytest.approx(peak.soil_up_n + peak.bodies_up_n, abs=1e-9)
    assert over.excess is not None and over.excess.excess_n >= peak.excess_n
    lines = trace.describe(over)
    assert any(line.startswith("largest vertical reading: 65.6 N at t = 1.312 s") and
               "the mount carried 14.2 N into the ground" in line and
               "pressed by the root's surface (body 0)" in line for line in lines), lines


def test_the_cli_traces_a_case_file_and_a_campaign_case() -> None:
    out = run_rakectl("fuzz", "--trace", str(RIM), "--json")
    assert out.returncode == 1, out.stderr  # the case is over the limit: as --replay says
    figures = json.loads(out.stdout.splitlines()[-1])
    assert figures["body"] == "mine" and abs(figures["body_reach_n"]) > 90.0
    assert figures["ground_n"] == pytest.approx(31.6, abs=0.05)
    assert figures["ground_soil_pressed_by"] == "mine"
    assert "largest push along the reach: the mine" in out.stdout
    assert "largest vertical reading: 31.6 N" in out.stdout
    out = run_rakectl("fuzz", "--trace", "0", "--seed", "20261128", "--family", "edge",
                      "--json")
    assert out.returncode in (0, 1), out.stderr
    figures = json.loads(out.stdout.splitlines()[-1])
    assert (figures["index"], figures["seed"], figures["family"]) == (0, 20261128, "edge")


def test_the_cli_refuses_what_it_cannot_trace() -> None:
    out = run_rakectl("fuzz", "--trace", "no-such-case.json")
    assert out.returncode == 2
    assert "--trace no-such-case.json: neither a case index" in out.stderr
    out = run_rakectl("fuzz", "--trace", "3", "--replay", str(RIM))
    assert out.returncode == 2 and "give one of them" in out.stderr
