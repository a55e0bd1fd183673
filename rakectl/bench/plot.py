"""The excavation benchmark's plot: one per soil, every controller (matplotlib on demand)."""

from __future__ import annotations

from pathlib import Path

from rakectl.bench.excavation import Controller, ExcavationReport
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.plot import pyplot


def plot_excavation(report: ExcavationReport, soil: str, path: Path) -> None:
    """One soil of the excavation benchmark: depth raked and true vertical force against
    time, for each controller."""
    plt = pyplot()
    styles = {Controller.ADAPTIVE: ("tab:green", "-", 3.0),  # drawn first, widest: lines
              Controller.POSITION: ("tab:purple", "--", 1.6),  # that coincide stay visible
              Controller.FIXED_SAFE: ("tab:blue", ":", 1.6)}
    fig, (ax_d, ax_f) = plt.subplots(2, 1, figsize=(9, 8), sharex=True)
    for controller, (colour, style, width) in styles.items():
        r = report.result(soil, controller)
        s = r.series
        if s is None:
            continue
        done = f"{r.time_s:.0f} s" if r.reached else "not reached"
        label = f"{controller} ({done})"
        ax_d.plot(s.t_s, 1e3 * s.tip_depth_m, color=colour, lw=0.4, alpha=0.35)
        ax_d.plot(s.t_s, 1e3 * s.floor_m, color=colour, ls=style, lw=width, label=label)
        ax_f.plot(s.t_s, s.f_true_z_n, color=colour, lw=0.6, alpha=0.8,
                  label=f"{controller}: max {r.f_true_z_max_n:.0f} N")
    ax_d.invert_yaxis()
    ax_d.set_ylabel("depth [mm]")
    ax_d.set_title(f"(a) {soil}: depth raked (thick) and tip depth (thin) against time")
    ax_d.legend(loc="lower left")
    ax_f.axhline(FORCE_LIMIT_N, color="tab:red", ls="--", lw=1, label=f"{FORCE_LIMIT_N:g} N limit")
    ax_f.set_ylabel("true vertical force on the ground [N]")
    ax_f.set_xlabel("time [s]")
    ax_f.set_title("(b) the tip's true vertical force (peak per 10 ms)")
    ax_f.legend(loc="upper right", fontsize="small")
    for ax in (ax_d, ax_f):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
