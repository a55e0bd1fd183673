"""Two runs of the same campaign cases compared case by case: what a change to the
simulated chain moved (``rakectl fuzz --compare DIR``).

A change to the emulator, the controller or the runner is judged by running the
campaign again (docs/safety.md, "Results"); what the safety case then states about
the change is this: how many results differ, which outcomes changed, and the largest
moves of each force. Results are matched by seed, index, family and whether the site
was declared; a result is the same only if every field is but the code that ran it
(the runs are deterministic, so an unchanged chain gives each case's result to the
bit). Which versions of the code ran each side is said (:mod:`rakectl.sim.chain`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rakectl.sim import chain
from rakectl.sim.results import RESULTS_FILE, CaseResult
from rakectl.sim.results import read_results as results_in

# each case's largest forces, and what the campaign's tables call them
FORCES = {"f_true_z_max_n": "ground", "f_mine_plate_max_n": "mine plate",
          "f_mine_side_max_n": "mine side", "f_stone_side_max_n": "stone side",
          "f_root_side_max_n": "root side"}
# what a case's result says happened, beside its forces
OUTCOMES = ("safe", "mine_activated", "object_found", "watchdog_tripped", "controller_fault",
            "refused")
LARGEST_MOVES = 3  # per force, the moves :func:`describe` names

Key = tuple[int, int, str, bool]


def key(result: CaseResult) -> Key:
    """What makes two results the same case's."""
    return result.seed, result.index, result.family, result.declared_site


def read_results(out_dir: Path) -> list[CaseResult]:
    """The results in ``out_dir``'s results file (:func:`rakectl.sim.results.read_results`);
    :class:`OSError` if there is none."""
    return results_in(out_dir / RESULTS_FILE)


@dataclass(frozen=True)
class Move:
    """One case's force in the other run (``before_n``) and in this one (``after_n``)."""

    index: int
    force: str  # a key of FORCES
    before_n: float
    after_n: float

    @property
    def change_n(self) -> float:
        return self.after_n - self.before_n


@dataclass(frozen=True)
class OutcomeChange:
    index: int
    outcome: str  # one of OUTCOMES
    before: Any
    after: Any


@dataclass(frozen=True)
class Comparison:
    cases: int  # this run's cases
    missing: tuple[int, ...]  # indices of this run's cases the other run does not have
    differ: tuple[int, ...]  # indices of the cases whose results differ in any field
    outcomes: tuple[OutcomeChange, ...]
    largest: dict[str, tuple[Move, ...]]  # per force, the largest moves, by size
    chains: tuple[str, ...] = ()  # the code that ran this run's cases
    other_chains: tuple[str, ...] = ()  # the code that ran the other run's, of those compared

    @property
    def compared(self) -> int:
        return self.cases - len(self.missing)


def compare(results: Iterable[CaseResult], others: Iterable[CaseResult],
            keep: int = LARGEST_MOVES) -> Comparison:
    """``results`` against the same cases in ``others`` (an earlier run's)."""
    before = {key(r): r for r in others}
    ours = sorted(results, key=lambda r: (r.seed, r.index))
    missing, differ, outcomes = [], [], []
    moves: dict[str, list[Move]] = {force: [] for force in FORCES}
    other_chains: set[str] = set()
    for now in ours:
        then = before.get(key(now))
        if then is None:
            missing.append(now.index)
            continue
        other_chains.add(then.chain)
        if now.same_as(then):
            continue
        differ.append(now.index)
        outcomes += [OutcomeChange(now.index, name, getattr(then, name), getattr(now, name))
                     for name in OUTCOMES if getattr(then, name) != getattr(now, name)]
        for force in FORCES:
            b, a = getattr(then, force), getattr(now, force)
            if a != b:
                moves[force].append(Move(now.index, force, b, a))
    largest = {force: tuple(sorted(found, key=lambda m: -abs(m.change_n))[:keep])
               for force, found in moves.items()}
    return Comparison(len(ours), tuple(missing), tuple(differ), tuple(outcomes), largest,
                      tuple(sorted({r.chain for r in ours})), tuple(sorted(other_chains)))


def describe(comparison: Comparison, other: str) -> list[str]:
    """The comparison as lines for a person: counts, outcome changes, largest moves."""
    c = comparison
    lines = [f"against {other}: {c.compared} of {c.cases} cases there, {len(c.differ)} "
             f"differ, {c.compared - len(c.differ)} the same to the bit"
             + (f"; {len(c.missing)} not there" if c.missing else "")]
    ran = ", ".join(map(chain.name, c.chains))
    if c.other_chains:  # (of the cases compared)
        lines.append(f"code: the same ({ran})" if c.other_chains == c.chains else
                     f"code: this run {ran}, there " + ", ".join(map(chain.name,
                                                                     c.other_chains)))
    lines.append("outcomes changed: " + (", ".join(
        f"{o.index} {o.outcome} {o.before!r} -> {o.after!r}" for o in c.outcomes)
        if c.outcomes else "none"))
    for force, found in c.largest.items():
        if found:
            lines.append(f"largest moves, {FORCES[force]}: " + ", ".join(
                f"{m.index} {m.before_n:.1f} -> {m.after_n:.1f} N" for m in found))
    return lines


def summary(comparison: Comparison) -> dict[str, Any]:
    """The comparison as plain data (``--json``)."""
    c = comparison
    return {"cases": c.cases, "compared": c.compared, "missing": list(c.missing),
            "chains": list(c.chains), "other_chains": list(c.other_chains),
            "differ": len(c.differ), "differ_indices": list(c.differ),
            "outcomes_changed": [dataclasses.asdict(o) for o in c.outcomes],
            "largest_moves": {force: [dataclasses.asdict(m) for m in found]
                              for force, found in c.largest.items()}}
