"""The excavation benchmark's figures in words: the lane, the table of runs, the sweep
that chose the fixed-safe speed, where the time went, and the goal (printed by
``rakectl bench --excavation`` and written into BENCHMARKS.md by
:mod:`rakectl.bench.report`)."""

from __future__ import annotations

import math

from rakectl.bench.excavation import (
    HARDEST_SOIL,
    SOILS,
    SPEEDUP_GOAL,
    SWEEP_CYCLES,
    Controller,
    ExcavationReport,
    RunResult,
    scenario_path,
    speed_of,
    why,
)
from rakectl.config.loader import load_settings
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.scenario import Scenario


def describe_lane(report: ExcavationReport) -> str:
    lane = load_settings(scenario_path(HARDEST_SOIL), report.shape.overrides(),
                         root=Scenario).lane
    return (f"reach {lane.reach_far_m:g} → {lane.reach_near_m:g} m "
            f"({lane.reach_far_m - lane.reach_near_m:.2g} m) to "
            f"{lane.target_depth_m * 1e3:.0f} mm in {lane.depth_step_m * 1e3:.0f} mm cuts")


def _time(r: RunResult) -> str:
    if r.reached:
        return f"{r.time_s:.1f} s"
    why = ("stalled" if r.object_found else "force stop" if r.stopped_by_force
           else "fault" if r.fault else "timeout")
    return f"— ({why} at {r.depth_reached_m * 1e3:.0f} mm)"


def table_rows(report: ExcavationReport) -> list[tuple[str, ...]]:
    """One row per run: soil, controller, time, the soil's shallowest floor along the lane
    afterwards, mean stroke speed, max true F_z, ticks over 90 N, mines fired, max
    supervised estimate, ticks at caution, speedup vs fixed-safe."""
    rows: list[tuple[str, ...]] = []
    for r in report.results:
        speedup = ""
        if r.job.controller != Controller.FIXED_SAFE and r.reached:
            fixed = report.result(r.job.soil, Controller.FIXED_SAFE)
            speedup = f"{fixed.time_s / r.time_s:.2f}×" if fixed.reached else ""
        rows.append((r.job.soil, str(r.job.controller), _time(r),
                     f"{r.floor_true_m * 1e3:.1f}",
                     f"{r.stroke_speed_mean_m_per_s:.3f}", f"{r.f_true_z_max_n:.1f}",
                     str(r.ticks_over_limit), str(r.mines_activated),
                     f"{r.f_estimate_max_n:.1f}", str(r.caution_ticks), speedup))
    return rows


LIMIT = f"{FORCE_LIMIT_N:g} N"
HEADER = ("soil", "controller", "time to depth", "true floor mm (shallowest)",
          "stroke m/s (mean)", "max true F_z N",
          f"ticks > {LIMIT}", "mines fired", "max estimate N", "ticks ≥ caution",
          "speedup vs fixed-safe")


def sweep_lines(report: ExcavationReport) -> list[str]:
    sweep = report.sweep
    chosen = (f"{sweep.speed_m_per_s:g} m/s" if math.isfinite(sweep.speed_m_per_s) else
              "none of the sweep's speeds was safe; the slowest was used")
    lines = [f"fixed-safe stroke speed: {chosen}: the fastest of a descending sweep in "
             f"{HARDEST_SOIL} ({SWEEP_CYCLES} cycles) whose run reached its depth with no "
             f"stall, no force stop, the estimate under the caution level, 0 ticks > {LIMIT}, "
             "no mine fired"]
    lines += [f"  {speed_of(r.job):g} m/s: {'safe' if r.safe else 'not safe'} ({why(r)})"
              for r in sweep.tried]
    return lines


def time_budget_line(report: ExcavationReport) -> str:
    """Where the fixed-safe runs spent their time, and what faster strokes alone could gain."""
    parts = []
    for soil in SOILS:
        r = report.result(soil, Controller.FIXED_SAFE)
        total = sum(r.phase_s.values()) or math.nan
        shares = ", ".join(f"{name} {100 * t / total:.0f} %" for name, t in r.phase_s.items()
                           if name != "done" and t > 0)
        parts.append(f"{soil}: {shares}; strokes in no time would be "
                     f"{report.stroke_bound(soil):.2f}× faster")
    return "fixed-safe time by phase: " + " | ".join(parts)


def adaptive_phases_line(report: ExcavationReport) -> str:
    """Where the adaptive runs spent their time, in seconds, and in how many cycles."""
    parts = []
    for soil in SOILS:
        r = report.result(soil, Controller.ADAPTIVE)
        seconds = ", ".join(f"{name} {t:.1f} s" for name, t in r.phase_s.items()
                            if name != "done" and t > 0)
        parts.append(f"{soil} ({r.cycles} cycle{'' if r.cycles == 1 else 's'}): {seconds}")
    return "adaptive time by phase: " + " | ".join(parts)


def goal_line(report: ExcavationReport) -> str:
    speedups = ", ".join(f"{soil} {report.speedup(soil):.2f}×" for soil in SOILS)
    over = sum(report.result(soil, Controller.ADAPTIVE).ticks_over_limit for soil in SOILS)
    return (f"adaptive vs fixed-safe: {speedups}; adaptive ticks > {LIMIT} in all soils: {over}. "
            f"Goal (≥ {SPEEDUP_GOAL:g}× in sand and loam, 0 ticks > {LIMIT} everywhere): "
            + ("met" if report.goal_met() else "NOT met"))


def format_excavation(report: ExcavationReport) -> str:
    widths = [max(len(row[i]) for row in [HEADER, *table_rows(report)])
              for i in range(len(HEADER))]
    lines = [f"excavation: lane {describe_lane(report)}; full simulated chain, one run per soil "
             f"and controller ({report.wall_s:.0f} s wall)", *sweep_lines(report),
             "  ".join(h.ljust(w) for h, w in zip(HEADER, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True))
              for row in table_rows(report)]
    lines += [time_budget_line(report), adaptive_phases_line(report), goal_line(report)]
    return "\n".join(lines)
