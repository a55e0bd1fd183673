"""Plots of simulation telemetry (matplotlib, imported only when a plot is asked for)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rakectl.errors import RakeError
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.cases import FAULT_KINDS
from rakectl.sim.edge import EdgeReading
from rakectl.sim.results import CaseResult, Report
from rakectl.sim.simulate import SimulationResult


def pyplot(option: str | None = "--plot") -> Any:
    """matplotlib.pyplot on the Agg backend, or a RakeError saying how to install it (and
    which ``option`` asked for the plots, where one did)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise RakeError("plotting needs matplotlib: pip install 'rakectl[plot]'"
                        + (f" (or drop {option})" if option else "")) from None
    return plt


def plot_paper_panels(result: SimulationResult, path: Path, title: str = "") -> None:
    """The seed paper's Fig. 5: position, position error and estimated force against time."""
    plt = pyplot()
    t = result.column("t_s")
    x_d_mm = 1e3 * result.column("x_d_m")
    x_mm = 1e3 * result.column("x_m")
    fig, (ax_x, ax_e, ax_f) = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ax_x.plot(t, x_d_mm, "--", label="desired $x_d$")
    ax_x.plot(t, x_mm, label="actual $x$")
    ax_x.plot(t, 1e3 * result.column("x_e_hat_m"), ":", label=r"soil estimate $\hat{x}_e$")
    ax_x.set_ylabel("position [mm]")
    ax_x.legend(loc="upper left")
    ax_x.set_title("(a) actual position x(t)")
    if title:
        fig.suptitle(title)
    ax_e.plot(t, x_d_mm - x_mm, color="tab:red")
    ax_e.set_ylabel("error $x_d - x$ [mm]")
    ax_e.set_title("(b) position error")
    f_hat = result.column("f_hat_n")
    ax_f.plot(t, f_hat, color="tab:green", label=r"estimated $\hat{F}_e$")
    if "f_true_z_n" in result.columns:
        ax_f.plot(t, result.column("f_true_z_n"), color="0.5", lw=0.6, label="true $F_z$")
    ax_f.axhline(f_hat[-1], color="0.6", lw=0.8, ls=":")
    ax_f.annotate(f"{f_hat[-1]:.2f} N", (t[-1], f_hat[-1]), ha="right", va="bottom")
    ax_f.set_ylabel("force [N]")
    ax_f.set_xlabel("time [s]")
    ax_f.set_title("(c) estimated interaction force")
    ax_f.legend(loc="lower right")
    for ax in (ax_x, ax_e, ax_f):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _tip_path(plt: Any, ax: Any, reach_m: Any, depth_m: Any,
              mines: list[tuple[float, float, float, float]], label: str, title: str) -> None:
    """The tip's path in the vertical plane, with the ground level and the mines drawn."""
    ax.plot(reach_m, 1e3 * depth_m, lw=0.8, label=label)
    ax.axhline(0.0, color="saddlebrown", lw=1, label="ground level")
    for reach, depth, width, thickness in mines:
        ax.add_patch(plt.Rectangle((reach - width / 2, 1e3 * depth), width, 1e3 * thickness,
                                   color="tab:red", alpha=0.4, label="mine"))
    ax.invert_yaxis()
    ax.set_xlabel("reach from the pivot [m]")
    ax.set_ylabel("depth below ground [mm]")
    ax.set_title(title)
    ax.legend(loc="lower left")


def plot_lane(result: SimulationResult, path: Path, mines: list[tuple[float, float, float, float]],
              title: str = "") -> None:
    """A raked lane: the tip's path in the vertical plane, depth and forces against time.

    ``mines`` are (reach_m, top_depth_m, width_m, thickness_m) rectangles to draw.
    """
    plt = pyplot()
    t = result.column("t_s")
    fig, (ax_path, ax_depth, ax_f) = plt.subplots(3, 1, figsize=(9, 10))
    _tip_path(plt, ax_path, result.column("tip_reach_m"), result.column("tip_depth_m"), mines,
              "tip path", "(a) tip path (the robot is to the left)")
    ax_depth.plot(t, 1e3 * result.column("x_d_m"), "--", lw=0.8, label="desired depth $x_d$")
    ax_depth.plot(t, 1e3 * result.column("tip_depth_m"), lw=0.8, label="tip depth")
    ax_depth.invert_yaxis()
    ax_depth.set_ylabel("depth [mm]")
    ax_depth.set_title("(b) depth against time")
    ax_depth.legend(loc="lower left")
    ax_f.plot(t, result.column("f_true_x_n"), color="0.6", lw=0.6, label="true drag $F_x$")
    ax_f.plot(t, result.column("f_true_z_n"), color="tab:blue", lw=0.6,
              label="true vertical $F_z$")
    ax_f.plot(t, result.column("f_hat_n"), color="tab:green", lw=0.6,
              label=r"estimated $\hat{F}_e$")
    ax_f.axhline(FORCE_LIMIT_N, color="tab:red", ls="--", lw=1,
                 label=f"{FORCE_LIMIT_N:g} N limit (vertical)")
    ax_f.set_ylabel("force [N]")
    ax_f.set_xlabel("time [s]")
    ax_f.set_title("(c) forces of the tip on the ground")
    ax_f.legend(loc="upper left", fontsize="small")
    for ax in (ax_path, ax_depth, ax_f):
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_bench_run(truth_csv: Path, path: Path,
                   mines: list[tuple[float, float, float, float]]) -> None:
    """A run on the emulated bench from the emulator's ground truth: tip path and forces."""
    import numpy as np

    plt = pyplot()
    data = np.genfromtxt(truth_csv, delimiter=",", names=True, usecols=range(14))
    t, reach, depth = data["t_s"], data["tip_reach_m"], -data["tip_height_m"]
    fig, (ax_path, ax_f) = plt.subplots(2, 1, figsize=(9, 8))
    _tip_path(plt, ax_path, reach, depth, mines, "tip path (true)",
              "(a) the rake's tip (the robot is to the left)")
    ax_f.plot(t, data["force_drag_n"], color="0.6", lw=0.6, label="true drag")
    ax_f.plot(t, data["force_down_n"], color="tab:blue", lw=0.6, label="true vertical")
    ax_f.axhline(FORCE_LIMIT_N, color="tab:red", ls="--", lw=1,
                 label=f"{FORCE_LIMIT_N:g} N limit (vertical)")
    ax_f.set_xlabel("time [s]")
    ax_f.set_ylabel("force of the tip on the ground [N]")
    ax_f.set_title("(b) forces, from the emulator's ground truth")
    ax_f.legend(loc="upper left", fontsize="small")
    for ax in (ax_path, ax_f):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# what carried each case's largest reading (a field of CaseResult), as the campaign plots it
READINGS = (("ground, vertical", "f_true_z_max_n"), ("mine, plate", "f_mine_plate_max_n"),
            ("mine, side", "f_mine_side_max_n"), ("stone, side", "f_stone_side_max_n"),
            ("root, side", "f_root_side_max_n"))
FAULTS = ("none", *FAULT_KINDS)
AXIS_LIMITS = 3.0  # the force axis ends at this many times the limit


def _exceedance(ax: Any, values: list[float], **style: Any) -> None:
    """How many cases read at least F, against F: a step down at each case's reading."""
    import numpy as np

    if not values:
        return
    f = np.sort(np.asarray(values))[::-1]
    ax.step(f, np.arange(1, len(f) + 1), where="post", **style)


def _bounded(r: CaseResult) -> float:
    """A case's largest bounded reading: the ground's vertical force or a mine's."""
    return max(r.f_true_z_max_n, r.f_mine_plate_max_n, r.f_mine_side_max_n)


def plot_campaign(report: Report, path: Path, title: str = "") -> None:
    """A campaign's margins at a glance: for each force (what carried it, the fault
    injected, the command), how many cases read at least F, on a log scale, against the
    limit. A case counts once per reading; refused sites ran nothing and are left out."""
    plt = pyplot()
    ran = [r for r in report.results if not r.refused]
    fig, (ax_body, ax_fault, ax_kind) = plt.subplots(3, 1, figsize=(9, 11), sharex=True)
    for label, field in READINGS:
        values = [getattr(r, field) for r in ran if getattr(r, field) > 0.0]
        _exceedance(ax_body, values, label=f"{label} ({len(values)} cases, largest "
                    f"{max(values, default=0.0):.1f} N)")
    ax_body.set_title("(a) each case's largest force, by what carried it")
    for fault in FAULTS:
        values = [_bounded(r) for r in ran if fault in (r.faults or ("none",))]
        _exceedance(ax_fault, values, label=f"{fault} ({len(values)})")
    for supervised, style in ((False, ":"), (True, "--")):
        values = [_bounded(r) for r in ran if r.supervised is supervised]
        _exceedance(ax_fault, values, color="0.3", ls=style,
                    label=f"supervision {'on' if supervised else 'off'} ({len(values)})")
    ax_fault.set_title("(b) the largest on the ground or a mine, by the fault injected")
    for kind in sorted({r.kind for r in ran}):
        values = [_bounded(r) for r in ran if r.kind == kind]
        _exceedance(ax_kind, values, label=f"{kind} ({len(values)})")
    ax_kind.set_title("(c) the largest on the ground or a mine, by command")
    ax_kind.set_xlabel("force [N]")
    readings = [max(_bounded(r), r.f_stone_side_max_n, r.f_root_side_max_n) for r in ran]
    cap_n = AXIS_LIMITS * FORCE_LIMIT_N  # beyond it the margins below the limit would not show
    beyond = [f for f in readings if f > cap_n]
    if beyond:
        ax_body.set_title(f"(a) each case's largest force, by what carried it ({len(beyond)} "
                          f"case(s) beyond the axis, up to {max(beyond):.0f} N)")
    for ax in (ax_body, ax_fault, ax_kind):
        ax.axvline(FORCE_LIMIT_N, color="k", lw=1.5,
                   label=f"{FORCE_LIMIT_N:g} N limit (ground, mines)")
        ax.set_yscale("log")
        ax.set_ylabel("cases reading ≥ F")
        ax.set_xlim(0.0, 1.05 * max(FORCE_LIMIT_N, min(max(readings, default=0.0), cap_n)))
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    fig.suptitle(f"{title}{': ' if title else ''}{len(ran)} cases run, "
                 f"{len(report.unsafe)} over the limit, {report.mine_activations} mines fired",
                 fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


EDGE_BODIES = (("mine", "tab:red"), ("stone", "0.45"), ("root", "tab:green"))
RESISTANCE_FLOOR_N = 0.1  # the log axis's least: an object whose edge stands out of the soil


def plot_edge_resistance(readings: list[EdgeReading], path: Path, budget_n: float,
                         title: str = "") -> None:
    """The edge family's gap at a glance: each case's largest side force on its object
    against the soil's cutting resistance H at the object's edge (docs/safety.md, "Not
    covered"), with the 90 N limit, the line side = H, and the budget the descent limiter
    keeps H under (``budget_n``: 90 N less the clamp's F_L). Cases whose tines never
    touched their object are counted, not drawn."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 6.5))
    touched = [r for r in readings if r.side_n > 0.0]
    for body, color in EDGE_BODIES:
        group = [r for r in touched if r.body == body]
        cases = sum(r.body == body for r in readings)
        over = sum(not r.safe for r in readings if r.body == body)
        if not cases:
            continue
        ax.scatter([max(r.resistance_n, RESISTANCE_FLOOR_N) for r in group],
                   [r.side_n for r in group], s=7, alpha=0.6, color=color, linewidths=0,
                   label=f"{body}s: {len(group)} of {cases} cases touched"
                   + (f", {over} over the limit" if body == "mine" else ""))
    h = [max(r.resistance_n, RESISTANCE_FLOOR_N) for r in readings] or [budget_n]
    h_span = [min(min(h), budget_n) / 1.5, 1.5 * max(max(h), FORCE_LIMIT_N)]
    ax.plot(h_span, h_span, color="k", lw=0.8, ls=":", label="side force = H")
    ax.axhline(FORCE_LIMIT_N, color="k", lw=1.5, label=f"{FORCE_LIMIT_N:g} N limit (mines)")
    ax.axvline(budget_n, color="tab:blue", lw=1.2, ls="--",
               label=f"H = {budget_n:g} N: the descent budget (90 N less F_L)")
    ax.set_xscale("log")
    ax.set_xlim(*h_span)
    ax.set_ylim(0.0, 1.05 * max(FORCE_LIMIT_N, *(r.side_n for r in readings)))
    ax.set_xlabel("the soil's cutting resistance H at the object's edge, a mean cell [N]"
                  + (f" (≤ {RESISTANCE_FLOOR_N:g}: the edge above the soil)"
                     if min(h) <= RESISTANCE_FLOOR_N else ""))
    ax.set_ylabel("largest side force on the object [N]")
    excess = max((r.side_n - r.resistance_n for r in touched), default=0.0)
    below = [r.side_n for r in readings if r.resistance_n <= budget_n]
    heading = f"{title}\n" if title else ""  # a merged run's title takes a line of its own
    ax.set_title(f"{heading}side force at most H + {excess:.1f} N; "
                 f"where H ≤ {budget_n:g} N at most {max(below, default=0.0):.1f} N "
                 f"({len(below)} cases)", fontsize="medium")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
