"""Two runs of the same campaign cases compared (rakectl.sim.compare), on the CI sample's
pinned results: the campaign's own, for cases 9702-9761 of seed 20261127."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from rakectl.sim.compare import FORCES, compare, describe, read_results, summary
from rakectl.sim.results import RESULTS_FILE, CaseResult

PINNED = Path(__file__).resolve().parents[1] / "data" / "pinned" / "fuzz-20261127-9702.jsonl"


@pytest.fixture()
def pinned(tmp_path: Path) -> list[CaseResult]:
    """The pinned results read as a run's --out directory (its first line, which says on
    which chain they were run, is not a result and is left out)."""
    shutil.copy(PINNED, tmp_path / RESULTS_FILE)
    return read_results(tmp_path)


def test_a_run_compared_with_itself_differs_nowhere(pinned: list[CaseResult]) -> None:
    assert len(pinned) == 60
    c = compare(pinned, list(reversed(pinned)))  # matched by case, not by order
    assert (c.cases, c.compared, c.missing, c.differ, c.outcomes) == (60, 60, (), (), ())
    assert all(moves == () for moves in c.largest.values())
    assert describe(c, "DIR") == [
        "against DIR: 60 of 60 cases there, 0 differ, 60 the same to the bit",
        "code: the same (unrecorded)", "outcomes changed: none"]


def test_results_of_other_code_the_same_to_the_bit_are_the_same(pinned: list[CaseResult]
                                                                 ) -> None:
    """What another version of the code ran (rakectl.sim.chain) is compared as the
    figures go; the code of each side is said."""
    ours = [dataclasses.replace(r, chain="0123456789ab") for r in pinned]
    c = compare(ours, pinned)
    assert (c.compared, c.differ, c.chains, c.other_chains) == (60, (), ("0123456789ab",), ("",))
    assert describe(c, "DIR")[1] == "code: this run 0123456789ab, there unrecorded"
    assert (summary(c)["chains"], summary(c)["other_chains"]) == (["0123456789ab"], [""])


def test_moves_changed_outcomes_and_missing_cases_are_named(pinned: list[CaseResult]) -> None:
    by_index = {r.index: r for r in pinned}
    a, b, c, gone = (by_index[i] for i in (9703, 9710, 9720, 9730))
    earlier = {**by_index,
               # the earlier run read 9703's ground 95 N: unsafe there, as it is now safe
               9703: dataclasses.replace(a, f_true_z_max_n=95.0, ticks_over_limit=3),
               # 9710's stone side 12.5 N lower, and its watchdog the other way
               9710: dataclasses.replace(b, f_stone_side_max_n=b.f_stone_side_max_n - 12.5,
                                         watchdog_tripped=not b.watchdog_tripped),
               # 9720's mine side by a last bit only: a difference all the same
               9720: dataclasses.replace(c, f_mine_side_max_n=c.f_mine_side_max_n + 1e-12)}
    del earlier[9730]
    assert a.safe and a.f_true_z_max_n < 95.0
    found = compare(pinned, earlier.values(), keep=2)
    assert (found.cases, found.compared, found.missing) == (60, 59, (gone.index,))
    assert found.differ == (9703, 9710, 9720)
    assert [(o.index, o.outcome, o.before, o.after) for o in found.outcomes] == [
        (9703, "safe", False, True),
        (9710, "watchdog_tripped", not b.watchdog_tripped, b.watchdog_tripped)]
    ground = found.largest["f_true_z_max_n"]
    assert [(m.index, m.before_n, m.after_n) for m in ground] == [(9703, 95.0, a.f_true_z_max_n)]
    stone = found.largest["f_stone_side_max_n"]
    assert stone[0].index == 9710 and stone[0].change_n == pytest.approx(12.5)
    assert [m.index for m in found.largest["f_mine_side_max_n"]] == [9720]
    lines = describe(found, "DIR")
    assert lines[0] == "against DIR: 59 of 60 cases there, 3 differ, 56 the same to the bit; " \
        "1 not there"
    assert lines[2] == (f"outcomes changed: 9703 safe False -> True, 9710 watchdog_tripped "
                        f"{not b.watchdog_tripped!r} -> {b.watchdog_tripped!r}")
    assert f"largest moves, ground: 9703 95.0 -> {a.f_true_z_max_n:.1f} N" in lines
    figures = summary(found)
    assert (figures["differ"], figures["missing"]) == (3, [9730])
    assert set(figures["largest_moves"]) == set(FORCES)
    assert figures["outcomes_changed"][0] == {"index": 9703, "outcome": "safe",
                                              "before": False, "after": True}


def test_the_largest_moves_are_the_largest_either_way(pinned: list[CaseResult]) -> None:
    """``keep`` moves per force, by size whether the force rose or fell."""
    shifts = {9702: 3.0, 9705: -7.0, 9706: 5.0, 9707: -1.0}
    earlier = [dataclasses.replace(r, f_true_z_max_n=r.f_true_z_max_n - shifts[r.index])
               if r.index in shifts else r for r in pinned]
    moves = compare(pinned, earlier, keep=3).largest["f_true_z_max_n"]
    assert [m.index for m in moves] == [9705, 9706, 9702]
    assert [m.change_n for m in moves] == pytest.approx([-7.0, 5.0, 3.0])


def test_a_results_file_cut_short_is_read_without_its_last_line(tmp_path: Path) -> None:
    text = PINNED.read_text(encoding="utf-8")
    (tmp_path / RESULTS_FILE).write_text(text[:-40], encoding="utf-8")  # an interrupted run
    assert len(read_results(tmp_path)) == 59
    with pytest.raises(OSError):
        read_results(tmp_path / "nothing-here")
