"""Case files: one :class:`~rakectl.sim.cases.FuzzCase` as JSON, with the result it gave.

A campaign writes its worst case as one (``worst-case.json``); the regression cases of
tests/data/fuzz/ are such files with why each is kept and what it must show. A case
holds everything its run depends on, so its file rebuilds the exact run
(``rakectl fuzz --replay``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rakectl.sim.cases import FuzzCase, case_from_dict
from rakectl.sim.results import CaseResult, result_from_dict


def write_case(path: Path, case: FuzzCase, result: CaseResult) -> Path:
    """Write ``case`` and the ``result`` it gave to ``path`` (its directory made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"case": case.to_dict(), "result": result.to_dict()},
                               indent=2) + "\n")
    return path


def read_case_file(path: Path) -> tuple[FuzzCase, CaseResult | None]:
    """The case a case file holds, and the result recorded with it, if any."""
    data = json.loads(Path(path).read_text())
    recorded = result_from_dict(data["result"]) if "result" in data else None
    return case_from_dict(data["case"]), recorded


@dataclass(frozen=True)
class RegressionCase:
    """A case file of tests/data/fuzz/: the case, why it is kept, what it must show."""

    path: Path
    case: FuzzCase
    why: str
    expect: dict[str, Any]
    open: str = ""  # non-empty: still over the limit, not yet fixed (why, what it needs)


def load_regression_case(path: Path) -> RegressionCase:
    data = json.loads(Path(path).read_text())
    return RegressionCase(Path(path), case_from_dict(data["case"]), str(data["why"]),
                          dict(data["expect"]), str(data.get("open", "")))
