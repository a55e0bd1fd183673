"""A campaign's results: each case's (:class:`CaseResult`, one line of
:data:`RESULTS_FILE` as it finishes) and the whole run's (:class:`Report`, with its
table by command kind, fault kind and supervision)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.cases import Family, FuzzCase, from_plain

WORST_CASE_FILE = "worst-case.json"
RESULTS_FILE = "results.jsonl"  # one case's result a line, appended as cases finish


@dataclass(frozen=True)
class CaseResult:
    seed: int
    index: int
    kind: str
    f_true_z_max_n: float  # largest per-tick peak of the true vertical force
    f_true_z_max_t_s: float
    ticks_over_limit: int  # ticks whose true vertical force peak exceeds 90 N
    mine_activated: bool
    object_found: bool
    duration_s: float
    faults: tuple[str, ...]
    feedback_lost_ticks: int
    commands_lost_ticks: int
    drive_fault_ticks: int
    clamped_ticks: int
    controller_fault: str
    f_mine_plate_max_n: float = 0.0
    f_mine_side_max_n: float = 0.0
    f_stone_side_max_n: float = 0.0
    f_root_side_max_n: float = 0.0
    supervised: bool = False
    stalled_ticks: int = 0  # ticks the controller did not run (stall, kill)
    watchdog_tripped: bool = False
    family: str = str(Family.RANDOM)  # how the case was drawn (rakectl.sim.cases.Family)
    declared_site: bool = False  # its site declared, the descent limiter on (sim.site)
    refused: str = ""  # why the daemon would refuse that declaration at load: nothing ran
    chain: str = ""  # the code that ran it (rakectl.sim.chain.digest); "" if not recorded

    @property
    def safe(self) -> bool:
        """No vertical force over 90 N, none on a mine from any side, no mine fired."""
        return (self.ticks_over_limit == 0 and not self.mine_activated
                and max(self.f_mine_plate_max_n, self.f_mine_side_max_n) <= FORCE_LIMIT_N)

    @property
    def f_mine_max_n(self) -> float:
        return max(self.f_mine_plate_max_n, self.f_mine_side_max_n)

    def same_as(self, other: CaseResult) -> bool:
        """Whether ``other`` is this result to the bit in every field but the code that
        ran it (an unchanged chain gives each case's result to the bit)."""
        return dataclasses.replace(other, chain=self.chain) == self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def result_from_dict(data: dict[str, Any]) -> CaseResult:
    result: CaseResult = from_plain(CaseResult, data)
    return result


@dataclass(frozen=True)
class Report:
    scenarios: int
    results: tuple[CaseResult, ...]
    worst: CaseResult  # the largest force on the ground or a mine
    worst_case: FuzzCase
    wall_time_s: float
    worst_case_path: str = ""
    resumed: int = 0  # cases read back from an earlier run's results, not run again
    # all the results in the run's directory, where it holds more than this run's (a
    # campaign run in parts): their worst is the worst-case file's, their plots the plots
    directory: Report | None = None

    @property
    def f_true_z_max_n(self) -> float:
        return max(r.f_true_z_max_n for r in self.results)

    @property
    def f_mine_max_n(self) -> float:
        return max(r.f_mine_max_n for r in self.results)

    @property
    def ticks_over_limit(self) -> int:
        return sum(r.ticks_over_limit for r in self.results)

    @property
    def mine_activations(self) -> int:
        return sum(r.mine_activated for r in self.results)

    @property
    def refused(self) -> int:
        """Cases whose declared site the daemon would refuse at load (nothing ran)."""
        return sum(bool(r.refused) for r in self.results)

    @property
    def unsafe(self) -> tuple[CaseResult, ...]:
        return tuple(r for r in self.results if not r.safe)

    @property
    def safe(self) -> bool:
        return not self.unsafe

    def by_kind(self) -> dict[str, dict[str, float | int]]:
        """Per command kind, fault kind and supervision: cases, worst forces, the drives'
        watchdog trips, unsafe cases, refused sites."""
        out: dict[str, dict[str, float | int]] = {}
        for r in self.results:
            groups = [r.kind, *(f"fault: {f}" for f in r.faults or ("none",)),
                      "supervision on" if r.supervised else "supervision off"]
            for group in groups:
                k = out.setdefault(group, {"cases": 0, "f_true_z_max_n": 0.0,
                                           "f_mine_max_n": 0.0, "f_stone_side_max_n": 0.0,
                                           "watchdog_trips": 0, "unsafe": 0, "refused": 0})
                k["cases"] += 1
                k["watchdog_trips"] += r.watchdog_tripped
                k["refused"] += bool(r.refused)
                k["f_true_z_max_n"] = max(k["f_true_z_max_n"], r.f_true_z_max_n)
                k["f_mine_max_n"] = max(k["f_mine_max_n"], r.f_mine_max_n)
                k["f_stone_side_max_n"] = max(k["f_stone_side_max_n"], r.f_stone_side_max_n)
                k["unsafe"] += not r.safe
        return dict(sorted(out.items(), key=lambda item: (item[0].startswith(("fault", "super")),
                                                          item[0])))

    def over_limit(self) -> list[str]:
        """Every unsafe case: 'seed/index kind ground F N, mine F N [mine fired]'."""
        return [f"{r.seed}/{r.index} {r.kind} ground {r.f_true_z_max_n:.1f} N, "
                f"mine {r.f_mine_max_n:.1f} N" + (" mine fired" if r.mine_activated else "")
                for r in self.unsafe]

    def summary(self) -> dict[str, Any]:
        results = self.results
        return {"scenarios": self.scenarios, "f_true_z_max_n": self.f_true_z_max_n,
                "f_mine_max_n": self.f_mine_max_n,
                "f_mine_side_max_n": max(r.f_mine_side_max_n for r in results),
                "f_mine_plate_max_n": max(r.f_mine_plate_max_n for r in results),
                "f_stone_side_max_n": max(r.f_stone_side_max_n for r in results),
                "f_root_side_max_n": max(r.f_root_side_max_n for r in results),
                "ticks_over_limit": self.ticks_over_limit,
                "unsafe_cases": len(self.unsafe), "over_limit": self.over_limit(),
                "mine_activations": self.mine_activations, "refused_sites": self.refused,
                "controller_faults": sum(bool(r.controller_fault) for r in results),
                "watchdog_trips": sum(r.watchdog_tripped for r in results),
                "by_kind": self.by_kind(),
                "worst": self.worst.to_dict(), "worst_case": self.worst_case.describe(),
                "worst_case_path": self.worst_case_path, "wall_time_s": self.wall_time_s,
                "chains": sorted({r.chain for r in results}),  # the code that ran them
                "resumed": self.resumed,  # read back, not run: the rate counts the others
                "scenarios_per_min": 60.0 * (self.scenarios - self.resumed)
                / max(self.wall_time_s, 1e-9)}


# --------------------------------------------------------------------------- results file


def read_results(path: Path) -> list[CaseResult]:
    """Every result in the results file ``path`` (a line cut short by an interruption,
    or one that is not a result, is left out); :class:`OSError` if it cannot be read,
    or is not UTF-8 text."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:  # an OSError's kind of failure: not a results file
        raise OSError(f"{path} is not UTF-8 text ({error.reason} at byte {error.start})") \
            from None
    found = []
    for line in text.splitlines():
        try:
            found.append(result_from_dict(json.loads(line)))
        except (ValueError, TypeError, KeyError):
            continue
    return found


def finished_results(path: Path, seed: int, wanted: range, family: Family = Family.RANDOM,
                     declared_site: bool = False) -> dict[int, CaseResult]:
    """The results already in ``path`` for these cases of ``family``, run with their site
    declared or not (a line cut short by an interruption is ignored: that case runs
    again)."""
    return finished_among(read_results(path) if path.is_file() else [], seed, wanted,
                          family, declared_site)


def finished_among(results: Iterable[CaseResult], seed: int, wanted: range,
                   family: Family = Family.RANDOM, declared_site: bool = False
                   ) -> dict[int, CaseResult]:
    """:func:`finished_results` of results already read."""
    return {r.index: r for r in results
            if r.seed == seed and r.index in wanted and r.family == family
            and r.declared_site == declared_site}


def open_results(out_dir: Path) -> TextIO:
    """The results file, for appending; a line an interruption left unfinished is ended
    first, so that the next result starts a line of its own."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / RESULTS_FILE
    unfinished = path.is_file() and path.stat().st_size > 0 and \
        path.read_bytes()[-1:] != b"\n"
    sink = open(path, "a", encoding="utf-8")  # noqa: SIM115 (closed by the caller)
    if unfinished:
        sink.write("\n")
    return sink
