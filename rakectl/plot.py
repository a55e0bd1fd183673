"""Plots of simulation telemetry (matplotlib, imported only when a plot is asked for)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rakectl.errors import RakeError
from rakectl.simulate import SimulationResult


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, or a RakeError saying how to install it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise RakeError(
            "plotting needs matplotlib: pip install 'rakectl[plot]' (or drop --plot)"
        ) from None
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
