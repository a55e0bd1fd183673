"""The operator's ``dump`` request: a dump never replaces a file, names what is wrong
with a path in one reply, and does not queue without bound."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rakectl.bench.tick import LockstepRig
from rakectl.daemon.handlers import MAX_PENDING_DUMPS
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from tests.rig_commands import command


def _dump(rig: LockstepRig, path: str) -> dict[str, object]:
    return command(rig, json.dumps({"cmd": "dump", "path": path}).encode())


def test_a_dump_path_that_cannot_take_a_new_file_is_refused_naming_why(tmp_path: Path) -> None:
    rig = LockstepRig(tmp_path)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        victim = tmp_path / "notes.txt"
        victim.write_text("kept")
        (tmp_path / "link.csv").symlink_to(tmp_path / "nowhere.csv")
        for path, why in (
                (str(victim), "a file is already there (a dump never replaces one)"),
                (str(tmp_path / "link.csv"), "a file is already there (a dump never "
                 "replaces one)"),
                ("/", "it names a directory, not a file"),
                (f"{tmp_path}/..", "it names a directory, not a file"),
                (str(tmp_path / "no" / "x.csv"), f"no directory '{tmp_path / 'no'}'"),
                ("/tmp/\ud800.csv", "the path cannot be encoded as a file name")):
            with pytest.raises(CommandRejected) as refused:
                _dump(rig, path)
            assert str(refused.value) == f"cannot dump to {path!r}: {why}"
        assert victim.read_text() == "kept" and rig.daemon.pending_dumps() == []
        assert sorted(p.name for p in tmp_path.iterdir()
                      if p.suffix in (".csv", ".partial")) == ["link.csv"]

        for i in range(MAX_PENDING_DUMPS):  # each holds a snapshot until the slack writes it
            assert _dump(rig, str(tmp_path / f"{i}.csv"))["pending"] is True
        with pytest.raises(CommandRejected, match=f"cannot dump: {MAX_PENDING_DUMPS} dumps "
                           "are still being written"):
            _dump(rig, str(tmp_path / "one-more.csv"))
        while rig.daemon.pending_dumps():
            rig.daemon._work_on_dump(1.0)
        assert _dump(rig, str(tmp_path / "one-more.csv"))["pending"] is True
        assert list(rig.daemon.dump_failures) == []
    finally:
        rig.close()


def test_two_dumps_asked_between_two_ticks_are_two_files(tmp_path: Path) -> None:
    """Two dump requests without a path between two ticks were named alike (the time,
    the tick, the reason): both replies named one file and the second dump failed. The
    second gets a number."""
    rig = LockstepRig(tmp_path)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        first = command(rig, b'{"cmd": "dump"}')["path"]
        second = command(rig, b'{"cmd": "dump"}')["path"]
        assert isinstance(first, str) and isinstance(second, str)
        assert second == first.removesuffix(".csv") + "-2.csv"
        while rig.daemon.pending_dumps():
            rig.daemon._work_on_dump(1.0)  # what the slack does between ticks
        assert Path(first).is_file() and Path(second).is_file()
        assert command(rig, b'{"cmd": "status"}')["dumps"] == {"pending": [], "failed": []}
    finally:
        rig.close()
