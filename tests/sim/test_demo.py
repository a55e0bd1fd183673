"""The demo's summary: the ground truth it reports, read from the emulator's CSV."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.records import TRUTH_COLUMNS
from rakectl.sim.demo import truth_figures


def test_truth_figures_report_the_largest_forces_on_the_ground_and_on_a_mine(
        tmp_path: Path) -> None:
    rows = [  # force_down_n, mine_activated, mine_plate_max_n, mine_side_max_n
        ("12.5", "0", "0.0", "0.0"),
        ("30.0", "0", "4.0", "17.5"),
        ("8.0", "0", "21.0", "17.5"),
    ]
    lines = [",".join(TRUTH_COLUMNS)]
    for force, activated, plate, side in rows:
        row = dict.fromkeys(TRUTH_COLUMNS, "0")
        row.update(force_down_n=force, mine_activated=activated, mine_plate_max_n=plate,
                   mine_side_max_n=side)
        lines.append(",".join(row[c] for c in TRUTH_COLUMNS))
    csv = tmp_path / "truth.csv"
    csv.write_text("\n".join(lines) + "\n")
    figures = truth_figures(csv)
    assert figures["f_true_z_max_n"] == pytest.approx(30.0)
    assert figures["f_mine_plate_max_n"] == pytest.approx(21.0)
    assert figures["f_mine_side_max_n"] == pytest.approx(17.5)
    assert figures["mine_activated"] is False and figures["truth_rows"] == 3
