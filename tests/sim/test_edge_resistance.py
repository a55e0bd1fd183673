"""The soil's resistance at an edge case's object (rakectl.sim.edge.edge_resistance_n),
against the cutting resistances docs/safety.md prints ("Not covered"), and the edge
family's plot of side forces against it (``rakectl fuzz --family edge --plot``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from drivers.ground_params import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.cli import fuzz as fuzz_cli
from rakectl.sim import cases, edge, results
from tests.png import png_size

# The soils of config/scenarios/excavate-{loam,sand}.yaml, whose H docs/safety.md tables
# ("Not covered"; the 0.15 m rake, a mean cell): loam 22.5, 45.6, 69.5 N at 10, 20,
# 30 mm; sand 2.5, 5.8 N at 10, 20 mm
LOAM = SoilLayer(cohesion_pa=6e3, friction_angle_rad=0.4887, tool_friction_angle_rad=0.3142,
                 unit_weight_n_per_m3=17e3)
SAND = SoilLayer(cohesion_pa=500.0, friction_angle_rad=0.5585, tool_friction_angle_rad=0.3665,
                 unit_weight_n_per_m3=15.5e3)


def _beside(body: MineParams | StoneParams | RootParams, *layers: SoilLayer) -> cases.FuzzCase:
    """An edge case's plunge, on flat ground of ``layers``, beside ``body`` alone."""
    case = cases.generate(5, 0, cases.Family.EDGE)
    objects = BuriedObjects(mines=(body,) if isinstance(body, MineParams) else (),
                            stones=(body,) if isinstance(body, StoneParams) else (),
                            roots=(body,) if isinstance(body, RootParams) else ())
    return dataclasses.replace(case, ground=GroundParams(SoilParams(layers=layers), objects))


@pytest.mark.parametrize(("body", "cut_mm", "h_n"), [
    (MineParams(depth_m=0.007, edge_radius_m=0.003), 10.0, 22.5),
    (StoneParams(depth_m=0.015, edge_radius_m=0.005), 20.0, 45.6),
    (RootParams(depth_m=0.025, thickness_m=0.01), 30.0, 69.5),  # its round side: r = 5 mm
    (MineParams(depth_m=-0.02), 0.0, 0.0),  # standing out of the soil
])
def test_the_resistance_at_an_edge_is_the_documented_cutting_resistance(
        body: MineParams | StoneParams | RootParams, cut_mm: float, h_n: float) -> None:
    case = _beside(body, LOAM)
    assert edge.edge_cut_m(case) * 1e3 == pytest.approx(cut_mm, abs=1e-9)
    assert edge.edge_resistance_n(case) == pytest.approx(h_n, abs=0.05)


def test_the_resistance_is_the_strongest_layer_the_cut_reaches() -> None:
    shallow = MineParams(depth_m=0.007, edge_radius_m=0.003)  # its edge 10 mm down
    deep = MineParams(depth_m=0.017, edge_radius_m=0.003)  # 20 mm
    loam_below = dataclasses.replace(LOAM, from_depth_m=0.015)
    assert edge.edge_resistance_n(_beside(shallow, SAND, loam_below)) == pytest.approx(
        2.5, abs=0.05)  # the loam 5 mm under the edge: sand's
    assert edge.edge_resistance_n(_beside(deep, SAND, loam_below)) == pytest.approx(
        45.6, abs=0.05)  # loam's at 20 mm, not sand's 5.8 N
    assert edge.edge_resistance_n(_beside(deep, LOAM, dataclasses.replace(
        SAND, from_depth_m=0.015))) == pytest.approx(45.6, abs=0.05)  # the stronger above


def test_the_edge_family_plots_its_side_forces_against_the_resistance(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Four edge cases (two mines, a stone, a root) run, tabled and plotted; the plot's
    readings are the results' side forces on each case's own object, beside the
    resistance of its case drawn again."""
    argv = ["--family", "edge", "--scenarios", "4", "--seed", "3", "--out", str(tmp_path),
            "--json"]
    assert fuzz_cli.main([*argv, "--plot"]) in (0, 1)
    captured = capsys.readouterr()
    assert json.loads(captured.out.strip().splitlines()[-1])["scenarios"] == 4
    plot = tmp_path / fuzz_cli.EDGE_PLOT
    assert f"plot written to {plot}" in captured.err
    assert png_size(plot) == (990, 715)  # 9 × 6.5 in at 110 dpi
    run = list(results.finished_results(tmp_path / results.RESULTS_FILE, 3, range(4),
                                        cases.Family.EDGE).values())
    readings = {r.index: r for r in edge.edge_readings(run)}
    assert [readings[i].body for i in range(4)] == ["mine", "mine", "stone", "root"]
    for r in run:
        side_n = {"mine": r.f_mine_side_max_n, "stone": r.f_stone_side_max_n,
                  "root": r.f_root_side_max_n}[readings[r.index].body]
        case = cases.generate(3, r.index, cases.Family.EDGE)
        assert (readings[r.index].side_n, readings[r.index].resistance_n) == (
            side_n, edge.edge_resistance_n(case))
    random_results = [dataclasses.replace(r, family=str(cases.Family.RANDOM)) for r in run]
    assert edge.edge_readings(random_results) == []  # another family's cases: left out
