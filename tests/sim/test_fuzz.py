"""The closed-loop safety campaign: generation, running, replay, and what the clamp holds."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from drivers.objects import BuriedObjects, GroundParams, MineParams, StoneParams
from drivers.soil import SoilParams
from rakectl.core.clamp import VoltageClamp
from rakectl.sim import fuzz
from rakectl.sim.fuzz import Command, CommandKind, Faults, FuzzCase
from rakectl.sim.scenario import Scenario


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


def plunge_onto(objects: BuriedObjects, speed_m_per_s: float, end_depth_m: float) -> FuzzCase:
    """Pure position control (no impedance) straight down at reach 1.1 m onto ``objects``."""
    command = Command(CommandKind.PLUNGE, 1.1, 1.1, end_depth_m, end_depth_m, speed_m_per_s,
                      0.0, 0.01, False)
    return FuzzCase(0, 0, GroundParams(SoilParams(), objects), 7, command, Faults(),
                    (0.01 + end_depth_m) / speed_m_per_s + 1.0)


MINE_AT_3_CM = BuriedObjects(mines=(MineParams(1.1, 0.03, 0.08, 0.05,
                                               activation_force_n=80.0),))


def test_generation_is_deterministic_and_serializable() -> None:
    case = fuzz.generate(5, 3)
    assert case == fuzz.generate(5, 3)
    assert case != fuzz.generate(5, 4)
    assert case != fuzz.generate(6, 3)
    assert fuzz.case_from_dict(json.loads(json.dumps(case.to_dict()))) == case


def test_generation_spans_soils_commands_and_faults() -> None:
    cases = [fuzz.generate(2, i) for i in range(48)]
    stiffness = [la.stiffness_n_per_m for c in cases for la in c.ground.soil.layers]
    assert max(stiffness) / min(stiffness) > 20.0
    assert {c.command.kind for c in cases} == set(CommandKind)
    assert {c.command.adaptive for c in cases if c.command.kind is CommandKind.LANE} == {
        False, True}
    assert not any(c.command.adaptive for c in cases if c.command.kind is not CommandKind.LANE)
    assert {k for c in cases for k in c.faults.kinds()} == {"feedback", "command", "drive"}
    mines = [m for c in cases for m in c.ground.objects.mines]
    assert mines and all(80.0 <= m.activation_force_n <= 100.0 for m in mines)


def test_small_campaign_is_safe_and_the_worst_case_replays(tmp_path: Path) -> None:
    """The campaign's CI sample: 24 cases, each command kind (the hostile ones included)
    twice with no fault and with each fault kind, lanes fixed and adaptive. None may press
    harder than 90 N on any tick or fire a mine (`rakectl fuzz --scenarios 1000` is the full
    campaign)."""
    report = fuzz.campaign(24, seed=1, workers=2, out_dir=tmp_path)
    assert report.scenarios == len(report.results) == 24
    assert {r.kind for r in report.results} == {*map(str, CommandKind), "lane (adaptive)"}
    assert {k for r in report.results for k in r.faults} == {"feedback", "command", "drive"}
    assert any(r.drive_fault_ticks > 0 for r in report.results)  # a lane may end first
    assert report.safe, report.summary()["by_kind"]
    assert report.ticks_over_limit == report.mine_activations == 0
    assert report.f_true_z_max_n == max(r.f_true_z_max_n for r in report.results)
    now, recorded = fuzz.replay(Path(report.worst_case_path))
    assert now == recorded == report.worst


def test_cli_json_last_line_and_exit_status(capsys: pytest.CaptureFixture[str]) -> None:
    assert fuzz.main(["--scenarios", "1", "--seed", "1", "--json"]) == 0  # case 0: a lane
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["scenarios"] == 1
    assert summary["ticks_over_limit"] == 0 and summary["mine_activations"] == 0
    assert 0.0 < summary["f_true_z_max_n"] < fuzz.FORCE_LIMIT_N


def test_the_clamp_is_what_holds() -> None:
    """A slow position-controlled plunge onto a mine's plate: the joint loops saturate
    against it. Through the clamp the plate sees less than 90 N; without it, well over."""
    case = plunge_onto(MINE_AT_3_CM, speed_m_per_s=0.02, end_depth_m=0.06)
    clamped = fuzz.run_case(case)
    unclamped = fuzz.run_case(case, pass_through_clamp())
    assert clamped.f_true_z_max_n < fuzz.FORCE_LIMIT_N
    assert clamped.ticks_over_limit == 0 and not clamped.mine_activated
    assert unclamped.f_true_z_max_n > 1.3 * fuzz.FORCE_LIMIT_N
    assert unclamped.ticks_over_limit > 1000 and unclamped.mine_activated
    # a campaign's report names every case over the limit, not only the worst
    report = fuzz.Report(2, unclamped.f_true_z_max_n, unclamped.ticks_over_limit, 1, 1, 0,
                         unclamped, case, (clamped, unclamped), 1.0)
    assert report.over_limit() == [
        f"{case.seed}/{case.index} plunge {unclamped.f_true_z_max_n:.1f} N mine fired"]
    assert report.summary()["over_limit"] == report.over_limit()


def test_full_speed_plunge_onto_a_stone_stays_below_the_limit() -> None:
    """0.25 m/s straight down onto a stone: the clamp's dynamic budget brakes the descent
    (the compliant tine mount makes that possible; see rakectl.core.clamp)."""
    stone = BuriedObjects(stones=(StoneParams(1.1, 0.03, 0.1, 0.08),))
    result = fuzz.run_case(plunge_onto(stone, speed_m_per_s=0.25, end_depth_m=0.06))
    assert result.ticks_over_limit == 0


def test_faults_are_injected_and_counted() -> None:
    case = dataclasses.replace(
        plunge_onto(BuriedObjects(), speed_m_per_s=0.1, end_depth_m=0.05),
        faults=Faults(seed=3, feedback_loss_probability=0.2, command_loss_probability=0.2,
                      drive_fault_start_s=0.2, drive_fault_s=0.05))
    result = fuzz.run_case(case)
    ticks = round(result.duration_s * 1000)
    assert 0.1 * ticks < result.feedback_lost_ticks < 0.3 * ticks
    assert 0.1 * ticks < result.commands_lost_ticks < 0.3 * ticks
    assert result.drive_fault_ticks == 50
    assert result.faults == ("feedback", "command", "drive")


@pytest.mark.parametrize(("seed", "index"), [(7, 61), (7, 152), (7, 253), (7, 281), (7, 630),
                                           (8, 289), (8, 904)])
def test_cases_once_over_the_limit_now_hold(seed: int, index: int) -> None:
    """Cases of `rakectl fuzz` that went over 90 N, each time because the emulator's tine
    mount disagreed with the ground it met. Before the fix (up to 357 N): 7/61, a 0.1 m/s
    position-controlled plunge with 770 lost commands; 7/152, a 0.68 m/s stroke with 1861;
    7/253, a plunge through a weak layer onto a strong one, no faults; 7/281, a 0.6 m/s
    stroke with 1740 lost feedbacks: the mount had carried more than the soil's own law,
    then let it go into the ground. 7/630 (274 N for one tick): tines falling onto a lower
    cell's floor were put on it by a rounding below it, where the soil read its damping at
    the speed of the fall. 8/289 (642 N for one tick): tines resting on a stone's top were
    inside a film of soil over it, whose damping at the fall's speed the rest ignored.
    8/904 (700 N, a mine fired), from the first fix of 8/289: the solve left the mine's
    top out of contact, yet its solution ended below it."""
    case = fuzz.generate(seed, index)  # as found, before a lane could be adaptive
    case = dataclasses.replace(case, command=dataclasses.replace(case.command, adaptive=False))
    result = fuzz.run_case(case)
    assert result.ticks_over_limit == 0 and not result.mine_activated
    assert result.f_true_z_max_n < fuzz.FORCE_LIMIT_N


@pytest.mark.parametrize("index", [39, 378, 528, 894, 924])
def test_adaptive_lanes_once_over_the_limit_now_hold(index: int) -> None:
    """Adaptive lanes of seed 7 that went over 90 N when lanes first ran adaptive in the
    campaign, each time at a root's square edge: 39, 378, 528, 894 (111–140 N for a tick or
    two) dragged their tines at about 0.2 m/s into a root 1.3 mm under its top, which was
    pushed sideways until its top face was the nearer one and then read the whole overlap
    upward at once; with roots first made round as an ellipse with upper and lower halves
    apart, 924 (188 N) met the lower half beside it and crossed into the upper half 5 mm
    under the surface. Roots are round now, the force along the normal (drivers.objects):
    the tines ride up them."""
    result = fuzz.run_case(fuzz.generate(7, index))
    assert result.kind == "lane (adaptive)"
    assert result.ticks_over_limit == 0 and not result.mine_activated
    assert result.f_true_z_max_n < fuzz.FORCE_LIMIT_N

@pytest.mark.parametrize("index", [277, 442, 514, 516, 595, 688, 429, 606, 732, 735])
def test_cases_at_rounded_edges_hold(index: int) -> None:
    """Seed 7's cases at stones' and mines' edges. Square, adaptive lane 516 dragged its tine
    into a mine's side 0.5 mm under its plate, and the square rim read that as 106 N on the
    plate (the mine fired). Edges rounded (stones 5 mm, mines 3 mm), the plunges 277, 442,
    514, 595, 688 slid off a top's far edge and read 97–120 N: the law folded the reach
    speed's damping in moving AWAY from the edge too, putting its reference inside the
    object, where the mount rested its tines. Then lanes 429, 606, 732, 735 (91–169 N): a
    rounded edge lifted the tine out of the soil fast, and the mount's solve let the soil
    law's damping pull against the edge's push, which the ground read unrelieved."""
    result = fuzz.run_case(fuzz.generate(7, index))
    assert result.ticks_over_limit == 0 and not result.mine_activated
    assert result.f_true_z_max_n < fuzz.FORCE_LIMIT_N


@pytest.mark.xfail(strict=True, reason="a side blow on a rounded rim: the clamp's gap")
def test_a_fast_stroke_into_a_mines_rim_from_the_side() -> None:
    """Not mended, a real gap: fixed lane 7/183 strokes at 0.39 m/s into a mine's rim 3 mm
    under its plate, the steep bottom of its rounding. The rim drives the tine up its mount
    at v·n_reach/n_up (2 m/s): the mount's damper carries ~100 N onto the plate and the mine
    fires (125 N). The clamp bounds the motors' push and the vertical arrival speed, not the
    vertical part of the force that stops a horizontal motion at an edge. Strict: it fails
    once it holds."""
    result = fuzz.run_case(fuzz.generate(7, 183))
    assert result.ticks_over_limit == 0 and not result.mine_activated


def test_an_adaptive_lane_is_governed_and_older_case_files_still_load() -> None:
    """Case 7/0 is an adaptive lane: it runs with the governor (not as the same lane at its
    fixed speed would) and safely. A case written before lanes could be adaptive (no
    ``adaptive`` key) loads as a fixed-speed lane."""
    case = fuzz.generate(7, 0)
    assert case.command.kind is CommandKind.LANE and case.command.adaptive
    lane = fuzz.scenario_of(case).lane
    assert lane.adaptive and lane.max_stroke_speed_m_per_s >= lane.stroke_speed_m_per_s
    assert lane.max_plunge_speed_m_per_s >= lane.plunge_speed_m_per_s
    fixed = dataclasses.replace(case, command=dataclasses.replace(case.command, adaptive=False))
    assert not fuzz.scenario_of(fixed).lane.adaptive
    old = case.to_dict()
    del old["command"]["adaptive"]
    assert fuzz.case_from_dict(old) == fixed
    result, as_fixed = fuzz.run_case(case), fuzz.run_case(fixed)
    assert (result.kind, as_fixed.kind) == ("lane (adaptive)", "lane")
    assert (result.clamped_ticks, result.f_true_z_max_n) != (as_fixed.clamped_ticks,
                                                              as_fixed.f_true_z_max_n)
    assert result.ticks_over_limit == 0 and not result.mine_activated
