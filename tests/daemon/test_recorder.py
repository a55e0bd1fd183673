"""Flight recorder: ring order after wrapping, and a chunked CSV dump that reads back exactly."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rakectl.daemon.recorder import DumpError, DumpWriter, FlightRecorder
from rakectl.errors import ConfigError, RakeError
from tests.memory import assert_no_growth

COLUMNS = ("t_s", "state", "x_d_m", "x_m", "f_hat_n")


def _rows(count: int) -> np.ndarray:
    k = np.arange(count, dtype=np.float64)[:, None]
    return k * 10.0 + np.arange(len(COLUMNS))


@given(st.integers(1, 40), st.integers(0, 130))
def test_snapshot_is_the_last_rows_oldest_first(capacity: int, count: int) -> None:
    recorder = FlightRecorder(COLUMNS, capacity)
    rows = _rows(count)
    for row in rows:
        recorder.record_row(tuple(row))
    np.testing.assert_array_equal(recorder.snapshot(), rows[max(0, count - capacity) :])


def test_snapshot_is_a_copy() -> None:
    recorder = FlightRecorder(COLUMNS, 3)
    recorder.record_row((1.0, 2.0, 3.0, 4.0, 5.0))
    snapshot = recorder.snapshot()
    snapshot[0, 0] = -1.0
    assert recorder.snapshot()[0, 0] == 1.0


def test_record_row_takes_any_sequence_of_numbers() -> None:
    recorder = FlightRecorder(("a", "b", "c"), 2)
    recorder.record_row([1, True, np.float64(2.5)])
    assert recorder.snapshot().tolist() == [[1.0, 1.0, 2.5]]


@pytest.mark.parametrize("columns", [(), ("a", "a"), ("a,b",), ("",), ('q"',)])
def test_bad_columns_are_refused(columns: tuple[str, ...]) -> None:
    with pytest.raises(ConfigError):
        FlightRecorder(columns, 10)


def test_record_row_keeps_no_memory_per_call() -> None:
    recorder = FlightRecorder(COLUMNS, 2000)
    values = (0.1, 2.0, 0.3, 0.31, 12.5)

    def run(calls: int) -> None:
        for _ in range(calls):
            recorder.record_row(values)

    assert_no_growth(run)


class StepClock:
    """Each read is one second later: a budget of 1 s allows exactly one batch per call."""

    def __init__(self) -> None:
        self.reads = itertools.count()

    def __call__(self) -> float:
        return float(next(self.reads))


def _read_back(path: Path) -> tuple[list[str], np.ndarray]:
    header = path.read_text().splitlines()[0].split(",")
    return header, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_chunked_dump_writes_exactly_the_snapshot(tmp_path: Path) -> None:
    recorder = FlightRecorder(COLUMNS, 100)
    rng = np.random.default_rng(1)
    for row in rng.normal(scale=1e3, size=(250, len(COLUMNS))):
        recorder.record_row(tuple(row))
    recorder.record_row((np.nan, -0.0, np.inf, 1e-310, 3.0))
    snapshot = recorder.snapshot()
    path = tmp_path / "dump.csv"
    writer = DumpWriter(snapshot, COLUMNS, path, clock_s=StepClock(), rows_per_check=3)
    calls = 0
    while not writer.work(budget_s=1.0):
        calls += 1
        assert not path.exists() and writer.partial_path.exists()
    assert calls >= 100 // 3 and writer.done and writer.work(1.0)
    assert not writer.partial_path.exists()
    header, data = _read_back(path)
    assert tuple(header) == COLUMNS
    np.testing.assert_array_equal(data, snapshot)  # bit for bit, NaN and -0.0 included
    assert np.signbit(data[-1, 1])


def test_dump_with_a_large_budget_finishes_in_one_call(tmp_path: Path) -> None:
    recorder = FlightRecorder(COLUMNS, 10)
    for row in _rows(4):
        recorder.record_row(tuple(row))
    writer = recorder.start_dump(tmp_path / "a.csv", durable=True)
    assert writer.work(budget_s=10.0)
    np.testing.assert_array_equal(_read_back(tmp_path / "a.csv")[1], _rows(4))


def test_empty_dump_is_the_header(tmp_path: Path) -> None:
    writer = FlightRecorder(COLUMNS, 10).start_dump(tmp_path / "e.csv")
    while not writer.work(1.0):
        pass
    assert (tmp_path / "e.csv").read_text() == ",".join(COLUMNS) + "\n"


def test_abort_leaves_no_file(tmp_path: Path) -> None:
    recorder = FlightRecorder(COLUMNS, 100)
    for row in _rows(100):
        recorder.record_row(tuple(row))
    path = tmp_path / "b.csv"
    writer = DumpWriter(recorder.snapshot(), COLUMNS, path, clock_s=StepClock())
    writer.work(1.0)
    writer.abort()
    assert list(tmp_path.iterdir()) == []


def test_unwritable_dump_raises_a_named_error(tmp_path: Path) -> None:
    writer = FlightRecorder(COLUMNS, 10).start_dump(tmp_path / "missing" / "c.csv")
    with pytest.raises(DumpError, match=r"missing/c\.csv\.partial") as caught:
        writer.work(1.0)
    assert isinstance(caught.value, RakeError) and isinstance(caught.value, OSError)


def test_a_dump_never_replaces_a_file_it_did_not_write(tmp_path: Path) -> None:
    """Neither a file at the final name that appeared while the dump was written nor one
    at its partial name: each is kept, and the error names the dump."""
    recorder = FlightRecorder(COLUMNS, 10)
    late = tmp_path / "late.csv"
    writer = recorder.start_dump(late)
    writer.open_now()
    late.write_text("kept")
    with pytest.raises(DumpError, match=r"late\.csv: a file appeared there"):
        writer.work(1.0)
    assert late.read_text() == "kept" and not writer.partial_path.exists()
    partial = tmp_path / "busy.csv.partial"
    partial.write_text("kept too")
    with pytest.raises(DumpError, match=r"busy\.csv: cannot create busy\.csv\.partial: "
                       "File exists"):
        recorder.start_dump(tmp_path / "busy.csv").open_now()
    assert partial.read_text() == "kept too" and not (tmp_path / "busy.csv").exists()


def test_rows_must_fit_the_columns(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        DumpWriter(np.zeros((3, 2)), COLUMNS, tmp_path / "d.csv")
