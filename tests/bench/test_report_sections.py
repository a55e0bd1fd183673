"""Section (e) of BENCHMARKS.md, the drive client's hot path per drive profile, is
rewritten alone by ``rakectl bench --profiles``: the rest of the file stays as
``rakectl bench --all`` wrote it."""

from __future__ import annotations

from pathlib import Path

from rakectl.bench.hot_path import (
    HOT_PATH_END,
    HOT_PATH_START,
    hot_path_section,
    write_hot_path_section,
)
from rakectl.cli.main import main


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
