"""Sections of BENCHMARKS.md rewritten alone: (e), the drive client's hot path per drive
profile, by ``rakectl bench --profiles``; (f), the campaign's speed per core, by
``rakectl bench --campaign``; the rest of the file stays as ``rakectl bench --all``
wrote it. Section (d) alone: tests/bench/test_bench.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from rakectl.bench.hot_path import (
    HOT_PATH_END,
    HOT_PATH_START,
    hot_path_section,
    write_hot_path_section,
)
from rakectl.bench.throughput import THROUGHPUT_END, THROUGHPUT_START, measure_throughput
from rakectl.cli.main import main
from rakectl.sim.rake_plant import SETTLE_S

PINNED = Path(__file__).resolve().parents[1] / "data" / "pinned" / "fuzz-20261127-9702.jsonl"


def test_the_section_is_appended_once_then_replaced_in_place(tmp_path: Path) -> None:
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\n## (d) Excavation\n\nrows\n")
    write_hot_path_section(path, hot_path_section("rakectl bench --profiles", "then", "abc", "old"))
    write_hot_path_section(path, hot_path_section("rakectl bench --profiles", "now", "abc", "new"))
    text = path.read_text()
    assert text.startswith("# Benchmarks\n\n## (d) Excavation\n\nrows\n\n")
    assert text.count(HOT_PATH_START) == text.count(HOT_PATH_END) == 1
    assert "new" in text and "old" not in text and "on now" in text


def test_rakectl_bench_profiles_prints_both_profiles_and_writes_its_section(
        tmp_path: Path, capsys: object) -> None:
    assert main(["bench", "--profiles", "--ticks", "10000", "--report", str(tmp_path)]) == 0
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert " drives.profile cia402:" in text and " drives.profile roboteq:" in text
    assert text.count("tick = receive + send + sync") == 2


def test_the_campaign_speed_counts_the_cases_it_ran() -> None:
    """Two short cases of the CI sample (a stroke and a jog): their simulated time is the
    campaign's own for them plus the settling before each, and the rates are that over
    the CPU time measured."""
    pinned = {r["index"]: r for r in map(json.loads, PINNED.read_text().splitlines()[1:])}
    t = measure_throughput(20261127, 9730, 2)
    assert (t.cases, sorted(t.by_kind)) == (2, ["jog", "stroke"])
    assert t.simulated_s == pytest.approx(2 * SETTLE_S + pinned[9730]["duration_s"]
                                          + pinned[9731]["duration_s"])
    assert t.cpu_s == pytest.approx(sum(k.cpu_s for k in t.by_kind.values())) and t.cpu_s > 0
    assert t.cases_per_core_minute == pytest.approx(120.0 / t.cpu_s)
    assert t.simulated_per_cpu_s == pytest.approx(t.simulated_s / t.cpu_s)
    with pytest.raises(ValueError, match="cases"):
        measure_throughput(cases=0)


@pytest.mark.slow
def test_rakectl_bench_campaign_writes_its_section_alone(
        tmp_path: Path, physics_build: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The case with the physics as Python and compiled (the build there already: not
    built again), compared; the section states both and that they agree."""
    monkeypatch.setenv("RAKECTL_PHYSICS_CACHE", str(physics_build))
    path = tmp_path / "BENCHMARKS.md"
    write_hot_path_section(path, hot_path_section("rakectl bench --profiles", "then", "abc", "e"))
    before = path.read_text()
    assert main(["bench", "--campaign", "--cases", "1", "--report", str(tmp_path)]) == 0
    text = path.read_text()
    assert text.startswith(before) and text.count(THROUGHPUT_START) == 1
    section = text.split(THROUGHPUT_START)[1].split(THROUGHPUT_END)[0]
    assert "## (f) The safety campaign's speed, per core" in section
    assert "Cases 20261127/9702–9702" in section and "cases per core-minute" in section
    assert "**1 of 1 cases identical**" in section
    assert "| **all** | 1 |" in section and "faster per core" in section


def test_a_bad_case_count_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "rakectl", "bench", "--campaign", "--cases",
                           "0", "--report", str(tmp_path)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "rakectl: error: bench: --cases must be in [1, 100000]"]
    assert not (tmp_path / "BENCHMARKS.md").exists()
