"""The safety campaign's speed per core: how many cases a core runs a minute, and how
many simulated seconds a second of its time, over a fixed run of the campaign's cases,
with the emulator's physics as Python and compiled (drivers.compiled) in the same run.

One process, the cases one after another, each timed on this process's CPU clock
(``time.process_time``), so the figure is per core and a busy machine lengthens the
wall time more than it changes the figure. A case's simulated time is its own plus
the second the arm settles at its start pose before it (rakectl.sim.rake_plant).
The cases are the campaign's own (rakectl.sim.cases.generate), deterministic from
(seed, index): the same run on another version of the simulated chain measures its
speed-up case for case. :func:`compare_physics` runs them once per physics, each in
a fresh process (which physics runs is decided when a process imports the drivers),
and compares the results case by case. No printing: the caller prints and writes.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from drivers import compiled
from rakectl.bench.sections import markdown_table, markers, write_section
from rakectl.errors import RakeError
from rakectl.sim.campaign import run_case
from rakectl.sim.cases import generate
from rakectl.sim.rake_plant import SETTLE_S
from rakectl.sim.results import CaseResult

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
    physics: str = ""  # drivers.compiled.status() of the process that ran them
    physics_kind: str = ""  # drivers.compiled.running(): "python", "compiled" or "mixed"
    results: list[CaseResult] = field(default_factory=list, repr=False)

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
    figures = Throughput(seed, first, cases, 0.0, 0.0, 0.0, physics=compiled.status(),
                         physics_kind=compiled.running())
    wall_start = time.perf_counter()
    for index in range(first, first + cases):
        case = generate(seed, index)
        cpu_start = time.process_time()
        result = run_case(case)
        cpu_s = time.process_time() - cpu_start
        figures.results.append(result)
        kind = figures.by_kind.setdefault(result.kind.split()[0], KindFigures())
        kind.cases += 1
        simulated_s = SETTLE_S + result.duration_s  # the arm settles at its start pose first
        kind.simulated_s += simulated_s
        kind.cpu_s += cpu_s
        figures.cpu_s += cpu_s
        figures.simulated_s += simulated_s
        if progress is not None:
            progress(f"case {index - first + 1} of {cases}, {seed}/{index} ({result.kind}): "
                     f"{simulated_s:.1f} s simulated in {cpu_s:.1f} s of CPU")
    figures.wall_s = time.perf_counter() - wall_start
    return figures


@dataclass
class Comparison:
    """The same cases run with the physics as Python and compiled."""

    python: Throughput
    compiled: Throughput

    @property
    def speedup(self) -> float:
        """How many times fewer CPU seconds the compiled physics takes."""
        return self.python.cpu_s / self.compiled.cpu_s

    @property
    def identical(self) -> int:
        """Cases whose results (every field: peak forces, outcomes) are equal, exactly."""
        return sum(a == b for a, b in zip(self.python.results, self.compiled.results,
                                          strict=True))


def _echo(label: str, line: str) -> None:
    print(f"  [{label}] {line}", file=sys.stderr, flush=True)


def _measure_with(physics: str, seed: int, first: int, cases: int) -> Throughput:
    """measure_throughput in a fresh process whose drivers import under
    RAKECTL_PHYSICS=physics (inherited from this one's environment)."""
    saved = os.environ.get(compiled.MODE_ENV)
    os.environ[compiled.MODE_ENV] = physics
    try:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            return pool.submit(measure_throughput, seed, first, cases,
                               functools.partial(_echo, physics)).result()
    finally:
        if saved is None:
            del os.environ[compiled.MODE_ENV]
        else:
            os.environ[compiled.MODE_ENV] = saved


def compare_physics(seed: int = SEED, first: int = FIRST, cases: int = CASES,
                    progress: Callable[[str], None] | None = None) -> Comparison:
    """The cases with the Python physics, then compiled (built first if it is not:
    drivers.compiled.build), one process each, one after the other."""
    if cases < 1:
        raise ValueError("cases must be >= 1")
    compiled.build(progress=progress or (lambda line: None))
    comparison = Comparison(_measure_with("pure", seed, first, cases),
                            _measure_with("compiled", seed, first, cases))
    if (comparison.python.physics_kind, comparison.compiled.physics_kind) != ("python",
                                                                              "compiled"):
        raise RakeError("bench: the runs did not use the physics asked for: "
                        f"{comparison.python.physics!r}, {comparison.compiled.physics!r}")
    return comparison


def format_throughput(t: Throughput) -> str:
    lines = [f"campaign cases {t.seed}/{t.first}–{t.first + t.cases - 1} on one process, "
             f"{t.physics}: {t.cases_per_core_minute:.1f} cases per core-minute, "
             f"{t.simulated_per_cpu_s:.2f} simulated s per CPU s "
             f"({t.simulated_s:.0f} s simulated in {t.cpu_s:.0f} s of CPU, "
             f"{t.wall_s:.0f} s of wall time)"]
    for name, k in sorted(t.by_kind.items()):
        lines.append(f"  {name}: {k.cases} case{'' if k.cases == 1 else 's'}, "
                     f"{k.simulated_s / k.cases:.1f} s simulated "
                     f"and {k.cpu_s / k.cases:.1f} s of CPU each "
                     f"({k.simulated_s / k.cpu_s:.2f} simulated s per CPU s)")
    return "\n".join(lines)


def format_comparison(c: Comparison) -> str:
    return "\n".join([format_throughput(c.python), format_throughput(c.compiled),
                      f"compiled physics: {c.speedup:.2f}x fewer CPU seconds; results "
                      f"identical in {c.identical} of {c.python.cases} cases"])


# --------------------------------------------------------------------------- its report

THROUGHPUT_START, THROUGHPUT_END = markers("campaign-speed", "rakectl bench --campaign")


def throughput_section(command: str, started: str, tree: str, c: Comparison) -> list[str]:
    """Section (f) of BENCHMARKS.md: the campaign's speed per core, both physics."""
    py, cc = c.python, c.compiled
    rows = []
    for name in sorted(py.by_kind):
        p, k = py.by_kind[name], cc.by_kind[name]
        rows.append((name, str(p.cases), f"{p.simulated_s / p.cases:.1f}",
                     f"{p.cpu_s / p.cases:.1f}", f"{k.cpu_s / k.cases:.1f}",
                     f"{p.simulated_s / p.cpu_s:.2f}", f"{k.simulated_s / k.cpu_s:.2f}",
                     f"{p.cpu_s / k.cpu_s:.2f}×"))
    rows.append(("**all**", str(py.cases), f"{py.simulated_s / py.cases:.1f}",
                 f"{py.cpu_s / py.cases:.1f}", f"{cc.cpu_s / cc.cases:.1f}",
                 f"{py.simulated_per_cpu_s:.2f}", f"{cc.simulated_per_cpu_s:.2f}",
                 f"**{c.speedup:.2f}×**"))
    return [THROUGHPUT_START, "## (f) The safety campaign's speed, per core", "",
            f"`{command}` on {started}, tree {tree}. Cases {py.seed}/{py.first}–"
            f"{py.first + py.cases - 1} of the campaign (`rakectl fuzz`: the full simulated "
            "chain, faults included), one after another on one process, each timed on the "
            "process's CPU clock, once with the emulator's physics as Python and once "
            "compiled with mypyc (`rakectl compile`, drivers/compiled.py), each in a fresh "
            f"process. Python: **{py.cases_per_core_minute:.1f} cases per core-minute, "
            f"{py.simulated_per_cpu_s:.2f} simulated seconds per CPU second**; compiled: "
            f"**{cc.cases_per_core_minute:.1f} cases per core-minute, "
            f"{cc.simulated_per_cpu_s:.2f} simulated seconds per CPU second**, "
            f"**{c.speedup:.2f}× faster per core**, and the results of "
            f"**{c.identical} of {py.cases} cases identical** (every field, compared "
            f"exactly). Wall time {py.wall_s:.0f} s and {cc.wall_s:.0f} s. A case's "
            f"simulated time includes the {SETTLE_S:g} s the arm settles at its start pose "
            "before it. A campaign of N cases takes about N / (cases per core-minute × "
            "cores) minutes.", "",
            *markdown_table(("command", "cases", "simulated s per case", "CPU s per case, Python",
                             "CPU s per case, compiled", "simulated s per CPU s, Python",
                             "simulated s per CPU s, compiled", "speed-up"), rows), "",
            THROUGHPUT_END, ""]


def write_throughput_section(path: Path, command: str, started: str, tree: str,
                             c: Comparison) -> None:
    write_section(path, THROUGHPUT_START, THROUGHPUT_END,
                  throughput_section(command, started, tree, c))
