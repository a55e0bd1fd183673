"""The safety campaign's speed per core: how many cases a core runs a minute, and how
many simulated seconds a second of its time, over a fixed run of the campaign's cases.

One process, the cases one after another, each timed on this process's CPU clock
(``time.process_time``), so the figure is per core and a busy machine lengthens the
wall time more than it changes the figure. A case's simulated time is its own plus
the second the arm settles at its start pose before it (rakectl.sim.rake_plant).
The cases are the campaign's own (rakectl.sim.cases.generate), deterministic from
(seed, index): the same run on another version of the simulated chain measures its
speed-up case for case. Pure computation: the caller prints and writes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from rakectl.bench.sections import markers
from rakectl.sim.campaign import run_case
from rakectl.sim.cases import generate
from rakectl.sim.rake_plant import SETTLE_S

SEED, FIRST, CASES = 20261127, 9702, 60  # the CI sample (tests/sim/test_fuzz.py)


@dataclass
class KindFigures:
    cases: int = 0
    simulated_s: float = 0.0
    cpu_s: float = 0.0


@dataclass
class Throughput:
    seed: int
    first: int
    cases: int
    wall_s: float
    cpu_s: float
    simulated_s: float
    by_kind: dict[str, KindFigures] = field(default_factory=dict)

    @property
    def cases_per_core_minute(self) -> float:
        return 60.0 * self.cases / self.cpu_s

    @property
    def simulated_per_cpu_s(self) -> float:
        """Simulated seconds per second of one core."""
        return self.simulated_s / self.cpu_s


def measure_throughput(seed: int = SEED, first: int = FIRST, cases: int = CASES,
                       progress: Callable[[str], None] | None = None) -> Throughput:
    """Run cases ``first`` … ``first + cases − 1`` of ``seed`` here, one after another."""
    if cases < 1:
        raise ValueError("cases must be >= 1")
    figures = Throughput(seed, first, cases, 0.0, 0.0, 0.0)
    wall_start = time.perf_counter()
    for index in range(first, first + cases):
        case = generate(seed, index)
        cpu_start = time.process_time()
        result = run_case(case)
        cpu_s = time.process_time() - cpu_start
        kind = figures.by_kind.setdefault(result.kind.split()[0], KindFigures())
        kind.cases += 1
        simulated_s = SETTLE_S + result.duration_s  # the arm settles at its start pose first
        kind.simulated_s += simulated_s
        kind.cpu_s += cpu_s
        figures.cpu_s += cpu_s
        figures.simulated_s += simulated_s
        if progress is not None:
            progress(f"case {seed}/{index} ({result.kind}): {simulated_s:.1f} s "
                     f"simulated in {cpu_s:.1f} s of CPU")
    figures.wall_s = time.perf_counter() - wall_start
    return figures


def format_throughput(t: Throughput) -> str:
    lines = [f"campaign cases {t.seed}/{t.first}–{t.first + t.cases - 1} on one process: "
             f"{t.cases_per_core_minute:.1f} cases per core-minute, "
             f"{t.simulated_per_cpu_s:.2f} simulated s per CPU s "
             f"({t.simulated_s:.0f} s simulated in {t.cpu_s:.0f} s of CPU, "
             f"{t.wall_s:.0f} s of wall time)"]
    for name, k in sorted(t.by_kind.items()):
        lines.append(f"  {name}: {k.cases} case{'' if k.cases == 1 else 's'}, "
                     f"{k.simulated_s / k.cases:.1f} s simulated "
                     f"and {k.cpu_s / k.cases:.1f} s of CPU each "
                     f"({k.simulated_s / k.cpu_s:.2f} simulated s per CPU s)")
    return "\n".join(lines)


# --------------------------------------------------------------------------- its report

THROUGHPUT_START, THROUGHPUT_END = markers("campaign-speed", "rakectl bench --campaign")


def throughput_section(command: str, started: str, tree: str, t: Throughput) -> list[str]:
    """Section (f) of BENCHMARKS.md: the campaign's speed per core."""
    rows = [(name, str(k.cases), f"{k.simulated_s / k.cases:.1f}", f"{k.cpu_s / k.cases:.1f}",
             f"{k.simulated_s / k.cpu_s:.2f}") for name, k in sorted(t.by_kind.items())]
    rows.append(("**all**", str(t.cases), f"{t.simulated_s / t.cases:.1f}",
                 f"{t.cpu_s / t.cases:.1f}", f"{t.simulated_per_cpu_s:.2f}"))
    return [THROUGHPUT_START, "## (f) The safety campaign's speed, per core", "",
            f"`{command}` on {started}, tree {tree}. Cases {t.seed}/{t.first}–"
            f"{t.first + t.cases - 1} of the campaign (`rakectl fuzz`: the full simulated "
            "chain, faults included), one after another on one process, each timed on the "
            f"process's CPU clock: **{t.cases_per_core_minute:.1f} cases per core-minute, "
            f"{t.simulated_per_cpu_s:.2f} simulated seconds per CPU second** "
            f"({t.wall_s:.0f} s of wall time; a case's simulated time includes the "
            f"{SETTLE_S:g} s the arm settles at its start pose before it). A campaign of N "
            "cases takes about "
            "N / (that × cores) minutes; the same cases on another version of the chain "
            "give its speed-up.", "",
            "| command | cases | simulated s per case | CPU s per case | simulated s per CPU s |",
            "|---|---|---|---|---|", *("| " + " | ".join(row) + " |" for row in rows), "",
            THROUGHPUT_END, ""]
