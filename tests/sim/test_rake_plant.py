"""The full rake chain: joint loops → motors → arm → ground → encoders → estimator."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rakectl.config.loader import load_settings
from rakectl.sim.plot import plot_paper_panels
from rakectl.sim.scenario import Scenario
from rakectl.sim.simulate import SimulationResult, run

SCENARIOS = Path(__file__).resolve().parents[2] / "config" / "scenarios"
PAPER_TAU_S = 0.2


def _scenario(name: str, *overrides: str) -> Scenario:
    return load_settings(SCENARIOS / name, overrides, root=Scenario)


def _step_response(result: SimulationResult, start_s: float, amplitude_m: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    t, x = result.column("t_s"), result.column("x_m")
    before = x[t < start_s][-1]
    after = t >= start_s
    return t[after] - start_s, (x[after] - before) / amplitude_m


def test_vertical_step_is_at_least_as_good_as_the_papers_position_loop(tmp_path: Path) -> None:
    """In free space the rake's depth follows a 20 mm step at least as fast as
    P(s) = 1/(0.2 s + 1), through the clamp and the bus's one-tick delay: it is
    ahead of P(s)'s response at every instant after the first 60 ms (measured:
    behind until 53 ms, 63 % at 96 ms; the clamp's dynamic budget holds the
    downward push to about F_limit/2 less the rake's weight, so a descent starts
    gently), overshoots by under 5 % and settles within 2 % by 4τ."""
    settings = _scenario("step-rake.yaml")
    result = run(settings)
    t, y = _step_response(result, settings.trajectory.start_time_s, settings.trajectory.amplitude_m)
    paper = 1.0 - np.exp(-t / PAPER_TAU_S)
    late = t >= 0.06
    assert np.all(y[late] >= np.minimum(paper[late], 0.98))
    assert y.max() <= 1.05
    assert np.all(np.abs(y[t >= 4 * PAPER_TAU_S] - 1.0) <= 0.02)
    plot_paper_panels(result, tmp_path / "step.png", "step")
    assert (tmp_path / "step.png").stat().st_size > 10_000


def test_paper_ramp_through_the_full_rake() -> None:
    """ramp-loam: the estimate stays near the paper's 14 N and bounds the true,
    saw-tooth soil force on at least 99 % of the ticks in contact."""
    summary = run(_scenario("ramp-loam.yaml")).summary()
    assert summary["ticks"] == 20_000
    assert not summary["mine_activated"]
    assert 5.0 < summary["f_true_z_max_n"] < 20.0  # collapse force 10 N, plus damping
    assert summary["f_hat_final_n"] == pytest.approx(14.0, abs=3.0)  # encoder quantum ±2.7 N
    assert summary["contact_ticks"] > 18_000
    assert summary["f_hat_below_true_share"] < 0.01
    assert summary["tracking_error_final_m"] == pytest.approx(1.4e-3, abs=0.3e-3)  # F̂/K_d


def test_true_force_is_a_saw_tooth_in_the_telemetry() -> None:
    result = run(_scenario("ramp-loam.yaml", "duration_s=5"))
    f_true = result.column("f_true_z_n")[2000:]
    drops = np.sum(np.diff(f_true) < -3.0)  # collapses: sudden drops of several N
    assert drops > 100
    assert f_true.max() < 20.0


@pytest.mark.slow
def test_raking_a_lane_finds_the_mine_and_stops() -> None:
    """rake-lane-mine: strokes deepen by 10 mm; once deeper than the mine's top (25 mm)
    the tine meets its far face: the stroke stalls, the planner reports the find where
    the tip is (within 10 mm: the mount gives sideways), lifts clear and ends. The clamp
    caps the push in every direction (the loam's drag takes most of it), so the tine
    rides about 5 mm above each stroke's reference and meets the face one cycle later
    than the plan's 30 mm. Neither the plate nor the side is pressed near the limit."""
    settings = _scenario("rake-lane-mine.yaml")
    result = run(settings)
    summary = result.summary()
    mine = settings.emulator.ground.objects.mines[0]
    assert summary["object_found"]
    assert summary["object_reach_m"] == pytest.approx(mine.reach_m + mine.width_m / 2, abs=0.01)
    assert mine.depth_m < summary["object_depth_m"] < mine.depth_m + mine.thickness_m
    assert summary["cycles"] in (4, 5)
    assert not summary["mine_activated"]
    assert summary["mine_plate_force_max_n"] < mine.activation_force_n
    assert 5.0 < summary["mine_side_force_max_n"] < 90.0  # it really met the side, gently
    depth = result.column("tip_depth_m")
    assert depth.max() < mine.depth_m + mine.thickness_m  # never below the mine's bottom
    assert summary["f_true_z_max_n"] < 90.0
    assert math.isfinite(summary["f_hat_max_n"])


def test_the_currents_read_a_strokes_drag_high_by_the_drives_losses() -> None:
    """A stroke toward the robot at 0.05 m/s, 4 mm below ground level in excavate-loam's
    soil (cells ±20 %): the tine rides above the reference, cutting 2 mm, where the true drag
    is 2.7–5.5 N (the closed form H(2 mm) = 4.5 N, times each cell's strength). Over the
    stroke's steady part (reach 1.28 → 1.16 m) the currents' reach force, low-passed
    (supervision.current_filter_s), reads it high, as nominal loads do while the motors
    drive (gear efficiency, friction): measured +2.9 N in the median, 5–95 % within
    +2.2 … +3.4 N, and it follows the drag from cell to cell (correlation 0.91). Seeds 1–3
    gave +2.9 N, spreads of 1.5–2.2 N and correlations 0.72–0.89. The sign reversed reads
    −11 N; the vertical component in its place spreads 4.0 N and does not follow."""
    near_m = 1.15
    settings = _scenario("excavate-loam.yaml", "lane.reach_far_m=1.3",
                         f"lane.reach_near_m={near_m}", "lane.depth_step_m=0.004",
                         "lane.target_depth_m=0.004", "lane.adaptive=false",
                         "lane.stroke_speed_m_per_s=0.05", "emulator.ground.objects.mines=[]",
                         "duration_s=5.0")
    result = run(settings)
    t, reach_ref = result.column("t_s"), result.column("reach_ref_m")
    steady = ((np.gradient(reach_ref, t) < -0.045) & (reach_ref < settings.lane.reach_far_m - 0.02)
              & (reach_ref > near_m + 0.01))
    assert steady.sum() > 2000  # 2.4 s at 0.05 m/s
    estimate = result.column("f_reach_current_n")[steady]
    truth = result.column("f_true_x_n")[steady]
    assert np.median(truth) > 3.0  # the tine really cuts
    p5, median, p95 = np.percentile(estimate - truth, [5, 50, 95])
    assert -0.5 <= median <= 6.0
    assert p95 - p5 <= 2.5
    assert np.corrcoef(estimate, truth)[0, 1] > 0.6
