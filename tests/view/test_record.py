"""Recordings as MCAP, read back with the mcap package topic by topic (tier 1: files only)."""

from __future__ import annotations

import csv
import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from rakectl.cli.main import main
from rakectl.daemon.loop import RECORDER_COLUMNS
from rakectl.daemon.states import DaemonState
from rakectl.view.record import recording
from rakectl.view.stream import log_status
from rakectl.view.topics import JSON_SCHEMAS, TOPICS, Box, schema_name

CONFIG = Path(__file__).resolve().parents[2] / "config"


def _read(path: Path) -> dict[str, list[tuple[str, int, bytes]]]:
    """topic → [(schema name, log time, data)] in file order."""
    out: dict[str, list[tuple[str, int, bytes]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(
                (schema.name if schema else "", message.log_time, message.data))
    return out


def _dump(path: Path, rows: int) -> list[dict[str, float]]:
    """A flight-recorder dump as the daemon writes it: the tip on a slow arc."""
    written = []
    with path.open("w") as f:
        f.write(",".join(RECORDER_COLUMNS) + "\n")
        for k in range(rows):
            r_m, theta_rad = 1.2, 0.45 + 1e-4 * k
            row = dict.fromkeys(RECORDER_COLUMNS, 0.0) | {
                "t_s": 10.0 + k * 1e-3, "state": float(DaemonState.EXCAVATE.value),
                "r_m": r_m, "theta_rad": theta_rad, "reach_m": r_m * math.cos(theta_rad),
                "depth_m": -(0.6 - r_m * math.sin(theta_rad)), "f_hat_n": 0.1 * k,
                "voltage_r_req_v": 5.0, "voltage_r_v": 2.5, "f_current_n": 3.0,
                "clamp_worst_case_n": 30.0, "force_level": 1.0}
            f.write(",".join(repr(row[c]) for c in RECORDER_COLUMNS) + "\n")
            written.append(row)
    return written


def test_a_dump_as_mcap_has_every_topic_row_by_row(tmp_path: Path) -> None:
    rows = _dump(tmp_path / "dump.csv", 50)
    assert main(["mcap", str(tmp_path / "dump.csv"), "--emulator-config",
                 str(CONFIG / "emulator-demo.yaml")]) == 0
    topics = _read(tmp_path / "dump.mcap")
    assert set(topics) == {"/rake", "/ground", "/force", "/voltage", "/state"}
    assert [len(topics[t]) for t in ("/rake", "/force", "/voltage", "/state")] == [50] * 4
    assert topics["/force"][0][0] == schema_name("/force") == "rakectl.Force"
    assert topics["/rake"][0][0] == "foxglove.SceneUpdate"
    for row, (_, t_ns, data) in zip(rows, topics["/force"], strict=True):
        assert t_ns == round(row["t_s"] * 1e9)
        assert json.loads(data)["f_hat_n"] == pytest.approx(row["f_hat_n"])
    voltage = json.loads(topics["/voltage"][7][2])
    assert (voltage["requested_r_v"], voltage["applied_r_v"]) == (5.0, 2.5)
    assert json.loads(topics["/state"][0][2]) == {"state": "excavate", "level": "caution"}
    # the tip's reach is in the rake's line (protobuf doubles, little-endian)
    assert struct.pack("<d", rows[3]["reach_m"]) in topics["/rake"][3][2]
    # the demo's mine is drawn: its width in the ground's scene
    assert struct.pack("<d", 0.08) in topics["/ground"][0][2]


def test_a_file_that_is_neither_a_dump_nor_a_truth_is_refused(tmp_path: Path,
                                                               capsys: Any) -> None:
    bad = tmp_path / "other.csv"
    bad.write_text("a,b\n1,2\n")
    assert main(["mcap", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "not a flight-recorder dump, an emulator truth file" in err and "t_s" in err
    assert not (tmp_path / "other.mcap").exists() or (tmp_path / "other.mcap").stat().st_size
    assert main(["mcap", str(tmp_path / "missing.csv")]) == 2  # an input file: as bad as a bad one
    assert "cannot read" in capsys.readouterr().err


def test_an_output_that_would_replace_what_is_not_a_recording_is_refused(
        tmp_path: Path, capsys: Any) -> None:
    """`mcap X.csv -o X.csv` replaced the CSV with the MCAP (exit 0); `-o DIR` gave a
    traceback or left a `.partial`; `view --record` replaced an earlier recording. Each
    is one line now, exit 2, the file untouched; an MCAP made from the CSV before is made
    again."""
    _dump(tmp_path / "dump.csv", 5)
    source = (tmp_path / "dump.csv").read_bytes()
    notes = tmp_path / "notes.txt"
    notes.write_text("kept")
    for out, why in ((tmp_path / "dump.csv", "is the file it reads: it would be replaced"),
                     (tmp_path, "is a directory, not a file"),
                     (notes, "exists and is not an MCAP file: it is never replaced")):
        assert main(["mcap", str(tmp_path / "dump.csv"), "-o", str(out)]) == 2
        assert f"rakectl: error: mcap: -o {out} {why}" in capsys.readouterr().err
    assert (tmp_path / "dump.csv").read_bytes() == source and notes.read_text() == "kept"
    assert not list(tmp_path.glob("*.partial"))
    assert main(["mcap", str(tmp_path / "dump.csv")]) == 0
    assert main(["mcap", str(tmp_path / "dump.csv")]) == 0  # made again from the CSV
    assert main(["view", "--record", str(tmp_path / "dump.mcap"), "--seconds", "1"]) == 2
    assert ("rakectl: error: view: --record " + str(tmp_path / "dump.mcap") + " exists: it is "
            "never replaced; choose another name") in capsys.readouterr().err
    assert main(["view", "--write-layout", str(notes)]) == 2  # replaced any file before
    assert "exists and is not a layout" in capsys.readouterr().err and notes.read_text() == "kept"
    assert main(["view", "--write-layout", str(tmp_path / "layout.json")]) == 0
    assert main(["view", "--write-layout", str(tmp_path / "layout.json")]) == 0  # a layout


STATUS: dict[str, Any] = {
    "state": "excavate", "fault": None, "ticks": 12345,
    "joints": {"r_m": 1.2, "theta_rad": 0.5, "current_r_a": 0.1, "current_theta_a": 0.2},
    "tip": {"reach_m": 1.2 * math.cos(0.5), "depth_m": 1.2 * math.sin(0.5) - 0.6},
    "force": {"f_hat_n": 12.5, "f_current_n": 11.0, "level": "ok", "clamp_worst_case_n": 30.1,
              "clamp_budget_n": 34.6, "clamp_limit_n": 72.0},
    "voltages": {"requested_r_v": 1.0, "requested_theta_v": -2.0, "applied_r_v": 0.5,
                 "applied_theta_v": -1.5},
    "timing": {"latency_ns": {"p50": 20_000, "p99": 50_000, "max": 900_000}, "overruns": 3},
    "excavation": {"phase": "stroke", "cycle": 2, "depth_m": 0.03,
                   "object_found": {"reach_m": 1.05, "depth_m": 0.031}},
}


def test_a_status_reply_is_every_topic_with_its_values(tmp_path: Path) -> None:
    with recording(tmp_path / "s.mcap") as pub:
        log_status(pub, STATUS, 5 * 10**9, [Box(1.08, 0.025, 0.08, 0.05)], (0.92, 1.25))
        log_status(pub, STATUS | {"state": "fault", "fault": "the drive r faulted"},
                   6 * 10**9)
    topics = _read(tmp_path / "s.mcap")
    assert set(topics) == set(TOPICS) - {"/truth"}
    assert set(JSON_SCHEMAS) - {"/truth"} <= set(topics)
    force = json.loads(topics["/force"][0][2])
    assert force == {"f_hat_n": 12.5, "f_current_n": 11.0, "clamp_worst_case_n": 30.1,
                     "clamp_budget_n": 34.6, "clamp_limit_n": 72.0}
    assert json.loads(topics["/voltage"][0][2])["applied_theta_v"] == -1.5
    assert json.loads(topics["/state"][1][2])["fault"] == "the drive r faulted"
    timing = json.loads(topics["/timing"][0][2])
    assert (timing["latency_p99_us"], timing["late_ticks"]) == (50.0, 3.0)
    # the pivot, worked back from the tip and the joints: 0.6 m, as configured
    assert struct.pack("<d", -STATUS["tip"]["depth_m"] + 1.2 * math.sin(0.5)) in \
        topics["/rake"][0][2]
    assert -STATUS["tip"]["depth_m"] + 1.2 * math.sin(0.5) == pytest.approx(0.6, abs=1e-12)
    # the object found is drawn, at its depth
    assert struct.pack("<d", -0.031) in topics["/ground"][0][2]
    assert [t for _, t, _ in topics["/state"]] == [5 * 10**9, 6 * 10**9]


def test_the_lane_a_status_names_is_drawn_without_lane(tmp_path: Path) -> None:
    """A status whose excavation names its lane (its number, its reach span): the depth
    reached is drawn over that span without ``--lane``, and /state says the lane's number;
    ``--lane`` still rules where given."""
    lane = {"number": 3, "reach_far_m": 1.21, "reach_near_m": 0.93}
    status = STATUS | {"excavation": STATUS["excavation"] | {"lane": lane}}
    with recording(tmp_path / "s.mcap") as pub:
        log_status(pub, status, 5 * 10**9)
        log_status(pub, status, 6 * 10**9, lane_m=(0.95, 1.3))
    topics = _read(tmp_path / "s.mcap")
    first, second = (data for _, _, data in topics["/ground"])
    assert struct.pack("<d", 0.93) in first and struct.pack("<d", 1.21) in first
    assert struct.pack("<d", 1.3) in second and struct.pack("<d", 1.21) not in second
    assert [json.loads(d)["lane"] for _, _, d in topics["/state"]] == [3, 3]


def test_a_status_with_missing_or_non_finite_values_is_logged_as_nulls(tmp_path: Path
                                                                       ) -> None:
    with recording(tmp_path / "s.mcap") as pub:
        log_status(pub, {"state": "init", "tip": {"reach_m": None, "depth_m": None},
                         "force": {"f_hat_n": math.nan}}, 10**9)
    topics = _read(tmp_path / "s.mcap")
    assert "/rake" not in topics  # no pose to draw
    assert json.loads(topics["/force"][0][2])["f_hat_n"] is None
    assert json.loads(topics["/state"][0][2])["state"] == "init"


def test_the_shipped_layout_is_the_one_built_from_the_topics() -> None:
    from rakectl.view.layout import build

    shipped = json.loads((Path(__file__).resolve().parents[2] / "docs"
                          / "foxglove-layout.json").read_text())
    assert shipped == json.loads(build()), "re-run: rakectl view --write-layout"
    text = json.dumps(shipped)
    for topic in TOPICS:
        if topic != "/ground":
            assert topic in text


@pytest.mark.parametrize(("argv", "named"), [
    (["--port", "70000"], "--port"), (["--rate-hz", "0"], "--rate-hz"),
    (["--lane", "1.2", "0.9"], "--lane"), (["--seconds", "-1"], "--seconds"),
    (["--emulator-config", "/nonexistent.yaml"], "nonexistent.yaml")])
def test_bad_view_options_are_refused_before_anything_starts(
        argv: list[str], named: str, capsys: Any) -> None:
    assert main(["view", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("error") == 1 and named in err


def test_a_viewer_without_a_daemon_keeps_trying_and_says_so(tmp_path: Path,
                                                             capsys: Any) -> None:
    """No daemon at the socket: the viewer serves, retries, and stops cleanly, counting
    the failed requests (a real server on a free port, a real missing socket)."""
    assert main(["view", "--socket", str(tmp_path / "none.sock"), "--port", "0",
                 "--rate-hz", "20", "--seconds", "0.5",
                 "--record", str(tmp_path / "r.mcap")]) == 0
    err = capsys.readouterr().err
    assert "ws://127.0.0.1:" in err
    failed = int(err.split("status replies, ")[1].split(" failed")[0])
    assert failed >= 3 and "none.sock" in err
    assert (tmp_path / "r.mcap").stat().st_size > 0  # a valid, empty recording


def test_a_simulated_lane_is_recorded_with_its_mine(tmp_path: Path) -> None:
    """rakectl simulate --mcap on the lane over a mine, shortened: every tick on every
    topic, the true force from the telemetry, the mine drawn; the paper's first-order
    plant has no pose and is refused before the work."""
    assert main(["simulate", str(CONFIG / "scenarios" / "rake-lane-mine.yaml"), "--out",
                 str(tmp_path), "--set", "duration_s=0.3", "--mcap"]) == 0
    topics = _read(tmp_path / "telemetry.mcap")
    assert [len(topics[t]) for t in ("/rake", "/force", "/voltage", "/state", "/truth")] == [
        300] * 5
    with (tmp_path / "telemetry.csv").open() as f:
        last = list(csv.DictReader(f))[-1]
    assert topics["/truth"][-1][1] == round(float(last["t_s"]) * 1e9)
    assert json.loads(topics["/truth"][-1][2])["force_down_n"] == pytest.approx(
        float(last["f_true_z_n"]))
    assert struct.pack("<d", 0.08) in topics["/ground"][0][2]  # the scenario's mine width
    assert main(["simulate", str(CONFIG / "scenarios" / "paper-fig5.yaml"), "--out",
                 str(tmp_path / "p"), "--mcap"]) == 2
    assert not (tmp_path / "p" / "telemetry.csv").exists()


def test_a_campaign_case_replayed_is_recorded(tmp_path: Path) -> None:
    """rakectl fuzz --replay CASE --mcap: every tick of the replay on every topic, its
    telemetry next to it, the case's mine drawn; --mcap alone is refused."""
    from rakectl.cli.fuzz import main as fuzz_main

    case = Path(__file__).resolve().parents[1] / "data" / "fuzz" / "20261125-2993.json"
    assert fuzz_main(["--replay", str(case), "--mcap", str(tmp_path / "case.mcap")]) == 0
    with (tmp_path / "case.csv").open() as f:
        telemetry = list(csv.DictReader(f))
    topics = _read(tmp_path / "case.mcap")
    assert len(topics["/rake"]) == len(topics["/truth"]) == len(telemetry) > 1000
    peak = max(json.loads(d)["force_down_n"] for _, _, d in topics["/truth"])
    assert peak == pytest.approx(max(float(r["f_true_z_n"]) for r in telemetry))
    mine = json.loads(case.read_text())["case"]["ground"]["objects"]["mines"][0]
    assert struct.pack("<d", mine["width_m"]) in topics["/ground"][0][2]
    assert fuzz_main(["--mcap", str(tmp_path / "x.mcap")]) == 2


def test_a_bad_csv_replaces_no_recording_and_a_row_cut_short_ends_it(tmp_path: Path,
                                                                       capsys: Any) -> None:
    dump = tmp_path / "dump.csv"
    _dump(dump, 5)
    assert main(["mcap", str(dump), "-o", str(tmp_path / "keep.mcap")]) == 0
    kept = (tmp_path / "keep.mcap").read_bytes()
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert main(["mcap", str(bad), "-o", str(tmp_path / "keep.mcap")]) == 2
    assert (tmp_path / "keep.mcap").read_bytes() == kept  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "dump.csv", "keep.mcap"]
    # a dump still being written: its last row cut short is left out
    with dump.open("a") as f:
        f.write("10.9,4.0,1.1")
    capsys.readouterr()
    assert main(["mcap", str(dump)]) == 0
    assert "5 rows" in capsys.readouterr().out
    # a row with a value that is not a number: refused, naming the line
    lines = dump.read_text().splitlines()[:3]
    fields = lines[2].split(",")
    fields[RECORDER_COLUMNS.index("f_hat_n")] = "x"
    lines[2] = ",".join(fields)
    dump.write_text("\n".join(lines) + "\n")
    assert main(["mcap", str(dump)]) == 2
    assert "line 3" in capsys.readouterr().err
