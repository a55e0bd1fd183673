"""The closed-loop safety campaign: generation, running, faults, replay, regression cases,
and what the clamp holds."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from drivers.ground_params import BuriedObjects, GroundParams, MineParams, StoneParams
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.cli import fuzz as fuzz_cli
from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.control import workspace_of
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim import campaign, case_files, cases, edge, results, scene
from rakectl.sim.cases import FAULT_KINDS, CommandKind, Faults, FuzzCase, MotionCommand
from rakectl.sim.injection import JOG_COMMAND_PERIOD_S, JogReference
from rakectl.sim.scenario import Scenario
from tests.png import png_size

# Cases run on every CI run (48 consecutive cover every kind and fault): some of the
# campaign's own, whose results there are pinned in PINNED (its first line: on which chain)
CI_SAMPLE, CI_SEED, CI_FIRST = 60, 20261127, 9702
PINNED = Path(__file__).resolve().parents[1] / "data" / "pinned" / "fuzz-20261127-9702.jsonl"
PINNED_FORCES = ("f_true_z_max_n", "f_mine_plate_max_n", "f_mine_side_max_n",
                 "f_stone_side_max_n", "f_root_side_max_n")
PINNED_OUTCOMES = ("seed", "kind", "faults", "supervised", "ticks_over_limit",
                   "mine_activated", "object_found", "watchdog_tripped", "controller_fault")
PIN_TOLERANCE_N = 1e-6
REGRESSIONS = sorted((Path(__file__).resolve().parents[1] / "data" / "fuzz").glob("*.json"))


class PassThroughClamp(VoltageClamp):
    """Keeps the attributes the controller reads but lets every request through."""

    __slots__ = ()

    def apply(self, r_m: float, theta_rad: float, r_vel_m_per_s: float,
              theta_vel_rad_per_s: float, voltage_r_v: float, voltage_theta_v: float
              ) -> tuple[float, float]:
        super().apply(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s, voltage_r_v,
                      voltage_theta_v)
        return voltage_r_v, voltage_theta_v


def pass_through_clamp() -> PassThroughClamp:
    s = Scenario()
    return PassThroughClamp(s.clamp, s.motors.r, s.motors.theta, 1.0 / s.rate_hz)


def plunge_onto(objects: BuriedObjects, speed_m_per_s: float, end_depth_m: float,
                reach_m: float = 1.1, faults: Faults | None = None) -> FuzzCase:
    """Pure position control (no impedance) straight down at ``reach_m`` onto ``objects``."""
    command = MotionCommand(CommandKind.PLUNGE, reach_m, reach_m, end_depth_m, end_depth_m,
                            speed_m_per_s, 0.0, 0.01, False)
    return FuzzCase(0, 0, GroundParams(SoilParams(), objects), 7, command, faults or Faults(),
                    (0.01 + end_depth_m) / speed_m_per_s + 1.0)


MINE_AT_3_CM = BuriedObjects(mines=(MineParams(0.8, 0.03, 0.08, 0.05,
                                               activation_force_n=80.0),))


def test_generation_is_deterministic_and_serializable() -> None:
    case = cases.generate(5, 3)
    assert case == cases.generate(5, 3)
    assert case != cases.generate(5, 4)
    assert case != cases.generate(6, 3)
    assert cases.case_from_dict(json.loads(json.dumps(case.to_dict()))) == case


def test_generation_spans_what_an_operator_can_command() -> None:
    """Any 48 consecutive cases: every command kind under every fault kind, with and
    without supervision; lanes fixed, adaptive and at the API's bounds; crusts, soils
    out of the reference range, mines at cut depths and partly exposed."""
    some = [cases.generate(2, i) for i in range(48)]
    assert {c.command.kind for c in some} == set(CommandKind)
    assert {k for c in some for k in c.faults.kinds()} == set(FAULT_KINDS)
    assert {c.supervised for c in some} == {False, True}
    lanes = [c for c in some if c.command.kind is CommandKind.LANE]
    assert {c.command.adaptive for c in lanes} == {False, True}
    assert not any(c.command.adaptive for c in some if c.command.kind is not CommandKind.LANE)
    many = [cases.generate(2, i) for i in range(400)]
    assert any(c.command.speed_m_per_s == 1.0 and c.command.travel_speed_m_per_s == 2.0
               for c in many)
    jogs = [c.command for c in many if c.command.kind is CommandKind.JOG]
    assert {j.jog_space for j in jogs} == {"task", "joint"}
    stiffness = [la.stiffness_n_per_m for c in many for la in c.ground.soil.layers]
    assert min(stiffness) < 2e4 and max(stiffness) > 2e6  # out of the reference range
    assert any(len(c.ground.soil.layers) == 2 and c.ground.soil.layers[0].collapse_force_n
               > 60.0 > c.ground.soil.layers[1].collapse_force_n * 4 for c in many)  # crust
    mines = [m for c in many for m in c.ground.objects.mines]
    assert all(80.0 <= m.activation_force_n <= 100.0 for m in mines)
    assert any(-m.depth_m > scene.lowest_surface_m(c.ground.soil, m)  # partly exposed
               for c in many for m in c.ground.objects.mines)
    at_cut = [c for c in many if c.command.kind in (CommandKind.LANE, CommandKind.STROKE)
              and any(0.0 <= d - m.depth_m <= 0.005 for m in c.ground.objects.mines
                      for d in cases._cut_depths(c.command))]
    assert len(at_cut) > 50


def test_edge_cases_descend_along_an_objects_side() -> None:
    """The edge family: plunges whose path passes within the band of an object's side (a
    root's round side: its radius), over mines in half the cases, stones and roots in the
    others, under every fault, half supervised; deterministic, serializable, and drawn
    apart from the random family."""
    some = [cases.generate(2, i, cases.Family.EDGE) for i in range(48)]
    assert some[3] == cases.generate(2, 3, cases.Family.EDGE) != cases.generate(2, 3)
    assert all(c.family is cases.Family.EDGE for c in some)
    assert cases.case_from_dict(json.loads(json.dumps(some[3].to_dict()))) == some[3]
    assert {c.command.kind for c in some} == {CommandKind.PLUNGE}
    assert {c.command.contact for c in some} == {False, True}
    assert {k for c in some for k in c.faults.kinds()} == set(FAULT_KINDS)
    assert {c.supervised for c in some} == {False, True}
    kinds = [(len(o.mines), len(o.stones), len(o.roots))
             for o in (c.ground.objects for c in some)]
    assert kinds.count((1, 0, 0)) == 24 and kinds.count((0, 1, 0)) == kinds.count((0, 0, 1))
    for c in some:
        body = (*c.ground.objects.mines, *c.ground.objects.stones, *c.ground.objects.roots)[0]
        path_m = c.command.reach_far_m
        gap_m = min(abs(path_m - (body.reach_m - 0.5 * body.width_m)),
                    abs(path_m - (body.reach_m + 0.5 * body.width_m)))
        assert gap_m <= max(edge.EDGE_BAND_M, 0.5 * body.width_m) + 1e-12
    old_file = some[0].to_dict()
    del old_file["family"]  # a case file from before the families: the random one
    assert cases.case_from_dict(old_file).family is cases.Family.RANDOM


@pytest.fixture(scope="module")
def ci_sample(tmp_path_factory: pytest.TempPathFactory) -> results.Report:
    """The campaign's CI sample: cases 9702–9761 of seed 20261127."""
    return campaign.campaign(CI_SAMPLE, seed=CI_SEED, workers=2, first=CI_FIRST,
                             out_dir=tmp_path_factory.mktemp("ci-sample"))


def test_small_campaign_is_safe_and_the_worst_case_replays(ci_sample: results.Report) -> None:
    """The campaign's CI sample: 60 cases, every command kind under every fault kind,
    with and without supervision (any 48 consecutive cases hold them all). None may
    press the ground or a mine (plate or side) harder than 90 N on any tick or fire a
    mine (docs/safety.md has the full campaign)."""
    report = ci_sample
    assert report.scenarios == len(report.results) == CI_SAMPLE
    assert {r.kind.split()[0] for r in report.results} == set(map(str, CommandKind))
    assert {k for r in report.results for k in r.faults} == set(FAULT_KINDS)
    assert any(r.watchdog_tripped for r in report.results)
    assert report.safe, report.summary()["over_limit"]
    assert report.f_true_z_max_n == max(r.f_true_z_max_n for r in report.results)
    now, recorded = campaign.replay(Path(report.worst_case_path))
    assert now == recorded == report.worst


def pin_differences(results: Sequence[results.CaseResult], pinned: dict[int, dict[str, Any]]
                    ) -> list[str]:
    """Where ``results`` differ from ``pinned`` (by case index): a peak force by more than
    PIN_TOLERANCE_N, or any outcome."""
    differences = [f"cases run {sorted(r.index for r in results)} != pinned {sorted(pinned)}"] \
        if {r.index for r in results} != set(pinned) else []
    for r in sorted(results, key=lambda r: r.index):
        pin = pinned.get(r.index)
        if pin is None:
            continue
        now = json.loads(json.dumps(r.to_dict()))  # as the results file has it
        differences += [f"case {r.index}: {key} {pin[key]!r} -> {now[key]!r}"
                        for key in PINNED_FORCES
                        if not abs(now[key] - pin[key]) <= PIN_TOLERANCE_N]
        differences += [f"case {r.index}: {key} {pin[key]!r} -> {now[key]!r}"
                        for key in PINNED_OUTCOMES if now[key] != pin[key]]
    return differences


def test_the_ci_sample_gives_its_pinned_results(ci_sample: results.Report) -> None:
    """The simulated chain (emulator, controller, clamp, supervision, faults) is the one
    the campaign's evidence in docs/safety.md was run on: the CI sample's peak forces
    (within PIN_TOLERANCE_N) and outcomes are the campaign's own for those cases, pinned
    in PINNED with the chain they were run on. A change to any part of the chain changes
    some of these. If it is meant, the campaign starts again on the new chain: its
    results for these cases (`rakectl fuzz --scenarios 60 --first 9702 --seed 20261127
    --out DIR`, DIR/results.jsonl) become the file's lines after a first line naming the
    chain, and docs/safety-log.md says why."""
    pinned = {int(line["index"]): line for line in map(json.loads, PINNED.read_text()
                                                        .splitlines()[1:])}
    differences = pin_differences(ci_sample.results, pinned)
    assert not differences, "\n".join(["the simulated chain changed:", *differences])


def test_a_changed_result_is_named_by_the_pin_check(ci_sample: results.Report) -> None:
    """The check above can fail: a peak force moved by twice the tolerance, an outcome
    flipped, or a case missing are each named."""
    pinned = {r.index: json.loads(json.dumps(r.to_dict())) for r in ci_sample.results}
    moved = dataclasses.replace(ci_sample.results[0], f_mine_side_max_n=ci_sample.results[0]
                                .f_mine_side_max_n + 2 * PIN_TOLERANCE_N)
    flipped = dataclasses.replace(ci_sample.results[1],
                                  watchdog_tripped=not ci_sample.results[1].watchdog_tripped)
    assert pin_differences(ci_sample.results, pinned) == []
    run = [moved, flipped, *ci_sample.results[2:-1]]
    found = pin_differences(run, pinned)
    assert len(found) == 3
    assert found[0] == f"cases run {sorted(r.index for r in run)} != pinned {sorted(pinned)}"
    assert f"case {moved.index}: f_mine_side_max_n " in found[1:][moved.index > flipped.index]
    assert f"case {flipped.index}: watchdog_tripped " in found[1:][flipped.index > moved.index]


def test_the_cli_plots_a_finished_campaign_without_running_it(
        ci_sample: results.Report, capsys: pytest.CaptureFixture[str]) -> None:
    out = Path(ci_sample.worst_case_path).parent
    argv = ["--scenarios", str(CI_SAMPLE), "--first", str(CI_FIRST), "--seed", str(CI_SEED),
            "--out", str(out), "--json"]
    assert fuzz_cli.main([*argv, "--plot"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert summary["resumed"] == CI_SAMPLE  # every case read back: nothing ran
    assert f"{CI_SAMPLE} scenarios, all read back from an earlier run (none ran)" in captured.out
    plot = out / fuzz_cli.FORCES_PLOT
    assert f"plot written to {plot}" in captured.err
    assert png_size(plot) == (990, 1210)  # 9 × 11 in at 110 dpi
    assert not (out / fuzz_cli.EDGE_PLOT).exists()  # the edge family's plot: its own
    plot.unlink()
    assert fuzz_cli.main([*argv[:-3], "--plot"]) == 2  # no --out: nowhere to write it
    assert "--plot needs --out" in capsys.readouterr().err and not plot.exists()


def test_the_cli_tables_a_finished_campaign_by_command_fault_and_supervision(
        ci_sample: results.Report, capsys: pytest.CaptureFixture[str]) -> None:
    """The summary's table, counted again here from the results: a case in its kind's
    row, in each fault row it injects, in one supervision row."""
    out = Path(ci_sample.worst_case_path).parent
    assert fuzz_cli.main(["--scenarios", str(CI_SAMPLE), "--first", str(CI_FIRST), "--seed",
                          str(CI_SEED), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| " + " | ".join(fuzz_cli.TABLE_COLUMNS) + " |" in text
    rows = {line.split(" | ")[0][2:]: line.strip("| ").split(" | ")
            for line in text.splitlines() if line.startswith("| ") and "---" not in line}
    groups: dict[str, list[results.CaseResult]] = {}
    for r in ci_sample.results:
        for group in (r.kind, *(f"fault: {f}" for f in r.faults or ("none",)),
                      f"supervision {'on' if r.supervised else 'off'}"):
            groups.setdefault(group, []).append(r)
    assert set(rows) == {"cases", *groups}
    for group, members in groups.items():
        assert rows[group][1:] == [
            str(len(members)), f"{max(r.f_true_z_max_n for r in members):.1f}",
            f"{max(r.f_mine_max_n for r in members):.1f}",
            f"{max(r.f_stone_side_max_n for r in members):.1f}",
            str(sum(r.watchdog_tripped for r in members)),
            str(sum(not r.safe for r in members))], group
    assert sum(int(rows[f"supervision {s}"][1]) for s in ("on", "off")) == CI_SAMPLE
    assert any(int(rows[g][5]) for g in groups)  # the sample trips the watchdog


def test_the_cli_compares_a_finished_campaign_with_an_earlier_run(
        ci_sample: results.Report, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--compare DIR``: the CI sample read back (nothing runs) against an earlier run
    made from its own results, one case's stone side and finding changed, four cases
    left out; a directory with no results is refused before anything runs."""
    out = Path(ci_sample.worst_case_path).parent
    lines = (out / results.RESULTS_FILE).read_text(encoding="utf-8").splitlines()
    moved = json.loads(lines[5])
    moved["f_stone_side_max_n"] += 12.5
    moved["object_found"] = not moved["object_found"]
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / results.RESULTS_FILE).write_text(
        "\n".join([lines[0], json.dumps(moved), *lines[6:]]) + "\n", encoding="utf-8")
    left_out = sorted(json.loads(line)["index"] for line in lines[1:5])
    argv = ["--scenarios", str(CI_SAMPLE), "--first", str(CI_FIRST), "--seed", str(CI_SEED),
            "--out", str(out), "--compare", str(earlier), "--json"]
    assert fuzz_cli.main(argv) == 0
    text = capsys.readouterr().out
    assert f"against {earlier}: 56 of 60 cases there, 1 differ, 55 the same to the bit; " \
        "4 not there" in text
    i, found = moved["index"], not moved["object_found"]
    assert f"outcomes changed: {i} object_found {not found!r} -> {found!r}" in text
    figures = json.loads(text.strip().splitlines()[-1])
    assert figures["resumed"] == CI_SAMPLE  # read back: nothing ran
    compared = figures["compare"]
    assert (compared["against"], compared["differ"], compared["missing"]) == (
        str(earlier), 1, left_out)
    stone = compared["largest_moves"]["f_stone_side_max_n"]
    assert [(m["index"], round(m["before_n"] - m["after_n"], 6)) for m in stone] == [(i, 12.5)]
    fresh = tmp_path / "fresh"
    assert fuzz_cli.main([*argv[:6], "--out", str(fresh), "--compare",
                          str(tmp_path / "nothing")]) == 2
    assert f"--compare {tmp_path / 'nothing'}: no campaign results there" in \
        capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / results.RESULTS_FILE).write_text(lines[0][:40], encoding="utf-8")  # cut short
    assert fuzz_cli.main([*argv[:6], "--out", str(fresh), "--compare", str(empty)]) == 2
    assert f"--compare {empty}: its {results.RESULTS_FILE} holds no case's result" in \
        capsys.readouterr().err
    # another seed's directory: 'outcomes changed: none', exit 0, before
    other_seed = ["--scenarios", "2", "--seed", str(CI_SEED + 1)]
    assert fuzz_cli.main([*other_seed, "--out", str(fresh), "--compare", str(out)]) == 2
    assert (f"--compare {out} holds none of these cases (it holds seed {CI_SEED} (random)): "
            "nothing to compare with") in capsys.readouterr().err
    assert not fresh.exists()  # refused before the campaign


def test_the_cli_merges_finished_campaigns_into_one_report(
        ci_sample: results.Report, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--merge DIR...``: the CI sample's results split into two directories give the
    sample's own table; a third directory holding two cases of other seeds over the
    limit makes the merge unsafe, each named with its own seed; a case in two directories,
    a directory given twice or without results, and a flag that would run something are
    each refused with exit 2."""
    out = Path(ci_sample.worst_case_path).parent
    lines = (out / results.RESULTS_FILE).read_text(encoding="utf-8").splitlines()
    parts = {"a": lines[:25], "b": lines[25:]}
    for name, part in parts.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / results.RESULTS_FILE).write_text("\n".join(part) + "\n",
                                                             encoding="utf-8")
    a, b = tmp_path / "a", tmp_path / "b"
    assert fuzz_cli.main(["--merge", str(a), str(b), "--json"]) == 0
    text = capsys.readouterr().out
    assert f"merged: 25 results from {a}" in text and f"merged: 35 results from {b}" in text
    # the text named no seed nor family, only the plots did
    assert f"merged: seed {CI_SEED} (random), merged: each table row counts them together" \
        in text
    figures = json.loads(text.strip().splitlines()[-1])
    assert figures["merged"] == {str(a): 25, str(b): 35}
    assert figures["scenarios"] == CI_SAMPLE and figures["by_kind"] == ci_sample.by_kind()
    assert figures["f_true_z_max_n"] == ci_sample.f_true_z_max_n

    over = [json.loads(lines[0]) for _ in range(2)]  # each named with its own seed,
    # not the worst case's
    over[0].update(seed=CI_SEED + 1, f_mine_side_max_n=FORCE_LIMIT_N + 30.0)
    over[1].update(seed=CI_SEED + 2, f_mine_side_max_n=FORCE_LIMIT_N + 10.0)
    c = tmp_path / "c"
    c.mkdir()
    (c / results.RESULTS_FILE).write_text("".join(json.dumps(r) + "\n" for r in over),
                                          encoding="utf-8")
    assert fuzz_cli.main(["--merge", str(a), str(b), str(c)]) == 1
    text = capsys.readouterr().out
    for r in over:
        assert f"unsafe: {r['seed']}/{r['index']} {r['kind']} ground " in text
    assert f"{CI_SAMPLE + 2} scenarios" in text

    first = json.loads(lines[0])
    assert fuzz_cli.main(["--merge", str(out), str(a)]) == 2
    assert f"--merge: case {CI_SEED}/{first['index']} (random) is in both {out} and {a}" \
        in capsys.readouterr().err
    assert fuzz_cli.main(["--merge", str(a), str(a)]) == 2
    assert f"--merge: {a} is given twice" in capsys.readouterr().err
    assert fuzz_cli.main(["--merge", str(a), str(tmp_path / "nothing")]) == 2
    assert f"--merge: {tmp_path / 'nothing'}: no campaign results there" in \
        capsys.readouterr().err
    for half in (["--out", str(tmp_path / "d")], ["--plot"]):  # only together
        assert fuzz_cli.main(["--merge", str(a), *half]) == 2
        assert "--merge takes --plot and --out together" in capsys.readouterr().err
    assert fuzz_cli.main(["--merge", str(a), "--seed", "7", "--family", "edge"]) == 2
    assert "runs nothing; --seed, --family cannot go with it" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_the_cli_plots_merged_campaigns_together(
        ci_sample: results.Report, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--merge A B --plot --out DIR``: one figure of both runs, titled with their seeds,
    in a directory made for it; the random family's runs draw no edge plot."""
    out = Path(ci_sample.worst_case_path).parent
    lines = (out / results.RESULTS_FILE).read_text(encoding="utf-8").splitlines()
    moved = [json.dumps({**json.loads(line), "seed": CI_SEED + 1}) for line in lines[:10]]
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / results.RESULTS_FILE).write_text("\n".join(moved) + "\n",
                                                       encoding="utf-8")
    plots = tmp_path / "merged" / "plots"
    assert fuzz_cli.main(["--merge", str(out), str(tmp_path / "b"), "--plot",
                          "--out", str(plots)]) == 0
    captured = capsys.readouterr()
    assert f"plot written to {plots / fuzz_cli.FORCES_PLOT}" in captured.err
    assert png_size(plots / fuzz_cli.FORCES_PLOT) == (990, 1210)
    assert sorted(p.name for p in plots.iterdir()) == [fuzz_cli.FORCES_PLOT]
    assert f"{CI_SAMPLE + 10} scenarios" in captured.out
    runs = [results.result_from_dict(json.loads(line)) for line in [*lines, *moved]]
    assert fuzz_cli.merged_title(runs) == f"seeds {CI_SEED}, {CI_SEED + 1} (random), merged"
    assert fuzz_cli.merged_title(runs[:3]) == f"seed {CI_SEED} (random), merged"
    # into a campaign's own directory: its plots were replaced by the merge's, before
    assert fuzz_cli.main(["--merge", str(out), str(tmp_path / "b"), "--plot",
                          "--out", str(tmp_path / "b")]) == 2
    assert "holds a campaign's results: its plots are that campaign's" in \
        capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == [results.RESULTS_FILE]


def test_the_table_gives_refused_sites_a_column_only_where_there_are_any() -> None:
    row = {"cases": 3, "f_true_z_max_n": 12.34, "f_mine_max_n": 0.0, "f_stone_side_max_n": 5.0,
           "watchdog_trips": 1, "unsafe": 0, "refused": 0}
    assert fuzz_cli.kind_table({"plunge": row})[2] == "| plunge | 3 | 12.3 | 0.0 | 5.0 | 1 | 0 |"
    table = fuzz_cli.kind_table({"plunge": row, "jog": {**row, "refused": 2}})
    assert table[0].endswith("| unsafe | refused |") and table[1] == "|" + "---|" * 8
    assert table[2:] == ["| plunge | 3 | 12.3 | 0.0 | 5.0 | 1 | 0 | 0 |",
                         "| jog | 3 | 12.3 | 0.0 | 5.0 | 1 | 0 | 2 |"]


@pytest.mark.filterwarnings("error")
def test_a_campaign_whose_sites_were_all_refused_still_plots(tmp_path: Path) -> None:
    from rakectl.sim.plot import plot_campaign

    refused = results.CaseResult(1, 0, "plunge", 0.0, 0.0, 0, False, False, 0.0, (), 0, 0,
                                 0, 0, "", declared_site=True, refused="leaves no step")
    plot_campaign(results.Report(1, (refused,), refused, cases.generate(1, 0), 0.0),
                  tmp_path / "forces.png")
    assert (tmp_path / "forces.png").read_bytes()[:4] == b"\x89PNG"


def test_cli_json_last_line_and_exit_status(capsys: pytest.CaptureFixture[str]) -> None:
    assert fuzz_cli.main(["--scenarios", "1", "--seed", "1", "--json"]) == 0  # case 0: a lane
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["scenarios"] == 1 and summary["unsafe_cases"] == 0
    assert summary["ticks_over_limit"] == 0 and summary["mine_activations"] == 0
    assert 0.0 < summary["f_true_z_max_n"] < FORCE_LIMIT_N


def test_cli_rejects_a_file_that_is_not_a_case(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"case": {"seed": 1}}')
    assert fuzz_cli.main(["--replay", str(bad)]) == 2
    assert "not a case file" in capsys.readouterr().err
    assert fuzz_cli.main(["--scenarios", "0"]) == 2


def test_the_clamp_is_what_holds() -> None:
    """A slow position-controlled plunge onto a mine's plate near the robot (0.8 m, where
    θ's torque presses hardest): the joint loops saturate against it. Through the clamp
    the plate sees less than 90 N (measured 23 N); without it, over (96 N, the 80 N
    mine fires). Further out the motors alone cannot reach 90 N with the counterweight."""
    case = plunge_onto(MINE_AT_3_CM, speed_m_per_s=0.02, end_depth_m=0.06, reach_m=0.8)
    clamped = campaign.run_case(case)
    unclamped = campaign.run_case(case, pass_through_clamp())
    assert clamped.f_true_z_max_n < 0.5 * FORCE_LIMIT_N
    assert clamped.safe and 5.0 < clamped.f_mine_plate_max_n < 0.5 * FORCE_LIMIT_N
    assert unclamped.f_true_z_max_n > FORCE_LIMIT_N
    assert unclamped.ticks_over_limit > 100 and unclamped.mine_activated
    assert not unclamped.safe
    # a campaign's report names every unsafe case, not only the worst
    report = results.Report(2, (clamped, unclamped), unclamped, case, 1.0)
    assert report.over_limit() == [
        f"{case.seed}/{case.index} plunge ground {unclamped.f_true_z_max_n:.1f} N, mine "
        f"{unclamped.f_mine_max_n:.1f} N mine fired"]
    assert report.summary()["over_limit"] == report.over_limit()


def test_full_speed_plunge_onto_a_stone_stays_below_the_limit() -> None:
    """0.25 m/s straight down onto a stone: the clamp's dynamic budget brakes the descent
    (the compliant tine mount makes that possible; see rakectl.core.clamp)."""
    stone = BuriedObjects(stones=(StoneParams(1.1, 0.03, 0.1, 0.08),))
    result = campaign.run_case(plunge_onto(stone, speed_m_per_s=0.25, end_depth_m=0.06))
    assert result.ticks_over_limit == 0


def test_faults_are_injected_and_counted() -> None:
    case = plunge_onto(BuriedObjects(), speed_m_per_s=0.1, end_depth_m=0.05,
                       faults=Faults(seed=3, feedback_loss_probability=0.2,
                                     command_loss_probability=0.03, drive_fault_start_s=0.2,
                                     drive_fault_s=0.05, stall_start_s=0.4, stall_s=0.002))
    result = campaign.run_case(case)
    ticks = round(result.duration_s * 1000)
    assert 0.1 * ticks < result.feedback_lost_ticks < 0.3 * ticks
    assert 0.01 * ticks < result.commands_lost_ticks < 0.06 * ticks
    assert result.drive_fault_ticks == 50
    assert result.stalled_ticks == 2 and not result.watchdog_tripped  # under 3 ms
    assert result.faults == ("feedback", "command", "drive", "stall")


@pytest.mark.parametrize(("faults", "tripped"), [
    (Faults(stall_start_s=0.3, stall_s=0.002), False),
    (Faults(stall_start_s=0.3, stall_s=0.003), True),
    (Faults(seed=1, command_loss_probability=1.0), True),
], ids=["stall-2-ms", "stall-3-ms", "commands-lost"])
def test_the_drives_watchdog_counts_every_silent_tick(faults: Faults, tripped: bool) -> None:
    """The drives' 3 ms watchdog (drives.watchdog_timeout_ms) counts the ticks without a
    command reaching them, whether the controller is silent or its commands are lost: the
    longest a command can act is the 4 ms the clamp carries (clamp.reaction_latency_s)."""
    case = plunge_onto(BuriedObjects(), speed_m_per_s=0.1, end_depth_m=0.05, faults=faults)
    result = campaign.run_case(case)
    assert result.watchdog_tripped is tripped
    assert result.safe, result


@pytest.mark.parametrize("fault", [Faults(stall_start_s=0.3, stall_s=0.05),
                                   Faults(kill_at_s=0.3)], ids=["stall", "kill"])
def test_a_silent_controller_trips_the_drives_watchdog_and_the_rake_falls_safely(
        fault: Faults) -> None:
    """No tick for 50 ms, or none at all from 0.3 s on (SIGKILL), while plunging onto a
    mine: the drives hold the last command for their 3 ms watchdog, then 0 V, latched;
    the rake falls onto the mine under its unbalanced weight, through the mount."""
    case = plunge_onto(MINE_AT_3_CM, speed_m_per_s=0.1, end_depth_m=0.06, reach_m=0.8,
                       faults=fault)
    result = campaign.run_case(case)
    assert result.watchdog_tripped and result.stalled_ticks >= 3
    assert result.safe, result
    # the trip 3–5 ms after 0.3 s, then AFTER_FAULT_S at 0 V (the rake falling), then the end
    assert 0.3 + campaign.AFTER_FAULT_S < result.duration_s <= 0.305 + campaign.AFTER_FAULT_S


def test_a_jog_at_full_speed_into_a_mine_side_holds() -> None:
    """The operator jogs the tip at the jog's top speed toward the robot into a mine's side
    40 mm deep, in soil that resists nothing (the mine is all it meets) and for 3 s, long
    after the tip is blocked: the jog waits for the tip, the clamp's every-direction
    budget bounds the push and the impact."""
    air = SoilParams(layers=(SoilLayer(stiffness_n_per_m=1.0, collapse_force_n=1e-3,
                                       cohesion_pa=0.0, unit_weight_n_per_m3=1.0),),
                     surface_slope=0.0, stiffness_rel_std=0.0, strength_rel_std=0.0)
    mine = BuriedObjects(mines=(MineParams(1.0, 0.02, 0.08, 0.05,
                                           activation_force_n=80.0),))
    command = MotionCommand(CommandKind.JOG, 1.15, 1.15, 0.0, 0.0, 0.0, 0.0, -0.04, True,
                            jog_space="task", jog_angle_rad=math.pi / 2, jog_s=3.0)
    case = FuzzCase(0, 0, GroundParams(air, mine), 7, command, Faults(), 4.0)
    result = campaign.run_case(case)
    assert result.f_mine_side_max_n > 5.0  # it met the side
    assert result.safe and result.f_mine_max_n < 0.8 * FORCE_LIMIT_N


def test_the_campaigns_jog_held_by_the_caution_level_ends_by_its_dead_man() -> None:
    """The campaign's jog, as the daemon's: held at the caution level on every tick, it
    stays where it is while the operator's requests (1 s of them, every 0.1 s) and the
    dead-man go on, and ends the dead-man's time after the last request."""
    command = MotionCommand(CommandKind.JOG, 1.15, 1.15, 0.0, 0.0, 0.0, 0.0, 0.05, True,
                            jog_space="task", jog_angle_rad=0.0, jog_s=1.0)
    case = FuzzCase(0, 0, GroundParams(SoilParams()), 7, command, Faults(), 3.0)
    settings = campaign.scenario_of(case)
    ws = workspace_of(settings)
    reference = JogReference(case, settings, ws, *kinematics.inverse(ws, 1.15, 0.05))
    start = (reference.reach_m, reference.depth_m)
    reference.step(held=True)  # its first request
    ticks = 1
    while not reference.done and ticks < 10_000:
        reference.step(held=True)
        ticks += 1
        assert (reference.reach_m, reference.depth_m) == start
    period = round(JOG_COMMAND_PERIOD_S * settings.rate_hz)
    assert ticks == 9 * period + round(settings.jog.deadman_s * settings.rate_hz) + 1


@pytest.mark.slow
@pytest.mark.parametrize("path", REGRESSIONS, ids=[p.stem for p in REGRESSIONS])
def test_regression_cases_hold(path: Path) -> None:
    """Every case a campaign once found over the limit (tests/data/fuzz/, each with why
    it failed and what it must show now)."""
    regression = case_files.load_regression_case(path)
    result = campaign.run_case(regression.case)
    if regression.open:  # a finding not fixed yet: it must still read as found, so that
        assert not result.safe, f"{path.name} is safe now: close it (drop 'open')"
        pytest.xfail(f"open: {regression.open}")  # its fix turns this into a failure
    for key, value in regression.expect.items():
        assert getattr(result, key) == value, f"{path.name}: {key} ({regression.why})"
    assert result.safe, f"{path.name}: {regression.why}"


def test_an_adaptive_lane_is_governed_and_older_case_files_still_load() -> None:
    """Case 7/3 is an adaptive lane: it runs with the governor (not as the same lane at its
    fixed speed would) and safely. A case written before lanes could be adaptive (no
    ``adaptive`` key, no jog or stall fields) loads as a fixed-speed lane."""
    case = case_files.load_regression_case(REGRESSIONS[0].parent / "7-3.json").case
    assert case.command.kind is CommandKind.LANE and case.command.adaptive
    lane = campaign.scenario_of(case).lane
    assert lane.adaptive and lane.max_stroke_speed_m_per_s >= lane.stroke_speed_m_per_s
    assert lane.max_plunge_speed_m_per_s >= lane.plunge_speed_m_per_s
    fixed = dataclasses.replace(case, command=dataclasses.replace(case.command, adaptive=False))
    assert not campaign.scenario_of(fixed).lane.adaptive
    old = case.to_dict()
    for key in ("adaptive", "travel_speed_m_per_s", "jog_space", "jog_angle_rad", "jog_s"):
        del old["command"][key]
    for key in ("stall_start_s", "stall_s", "kill_at_s"):
        del old["faults"][key]
    del old["supervised"]
    assert cases.case_from_dict(old) == fixed
    result, as_fixed = campaign.run_case(case), campaign.run_case(fixed)
    assert (result.kind, as_fixed.kind) == ("lane (adaptive)", "lane")
    assert (result.clamped_ticks, result.f_true_z_max_n) != (as_fixed.clamped_ticks,
                                                              as_fixed.f_true_z_max_n)
    assert result.safe


def test_a_campaign_streams_its_results_and_resumes_where_it_stopped(tmp_path: Path) -> None:
    """Results are appended case by case; a second run into the same directory reads the
    finished cases back and runs only the rest (a line cut short runs again); the report
    is the same as one run's."""
    whole = campaign.campaign(4, seed=3, workers=1)
    first = campaign.campaign(2, seed=3, workers=1, out_dir=tmp_path)
    lines = (tmp_path / campaign.RESULTS_FILE).read_text().splitlines()
    assert len(lines) == 2 and first.resumed == 0
    with open(tmp_path / campaign.RESULTS_FILE, "a") as results:
        results.write(lines[0][: len(lines[0]) // 2])  # an interrupted write
    resumed = campaign.campaign(4, seed=3, workers=1, out_dir=tmp_path)
    assert resumed.resumed == 2
    assert [r.to_dict() for r in resumed.results] == [r.to_dict() for r in whole.results]
    again = campaign.campaign(4, seed=3, workers=1, out_dir=tmp_path)
    assert again.resumed == 4 and again.results == resumed.results
    other_seed = campaign.campaign(1, seed=4, workers=1, out_dir=tmp_path)
    assert other_seed.resumed == 0
    edge = campaign.campaign(1, seed=3, workers=1, out_dir=tmp_path, family=cases.Family.EDGE)
    assert edge.resumed == 0 and edge.results[0].family == "edge"  # not seed 3's random case
    assert campaign.campaign(1, seed=3, workers=1, out_dir=tmp_path,
                             family=cases.Family.EDGE).resumed == 1


def test_a_part_run_into_a_campaigns_directory_keeps_its_worst_case(tmp_path: Path) -> None:
    """A campaign run in parts into one directory: each part wrote the worst of its own
    cases over the directory's worst-case file (a 204 N edge case replaced by a safe one,
    exit 0) and redrew the plots from its cases alone. The file is the worst of all the
    results there, and the report says what the directory holds."""
    from rakectl.cli.fuzz import human
    from rakectl.sim.case_files import read_case_file

    whole = campaign.campaign(4, seed=3, workers=1)
    parts = [campaign.campaign(2, seed=3, workers=1, out_dir=tmp_path, first=first)
             for first in (0, 2)]
    assert parts[0].directory is None  # the directory held its results alone
    last = parts[1]
    assert last.directory is not None and len(last.directory.results) == 4
    _, kept = read_case_file(tmp_path / campaign.WORST_CASE_FILE)
    assert kept is not None and (kept.seed, kept.index) == (whole.worst.seed, whole.worst.index)
    assert "the directory holds 4 results in all" in human(last)
