"""Where the daemon writes (rakectl.daemon.places): refused before the bus, naming the
setting; the last runs' bus traces kept across a restart; and systemd's start timeout
extended for bring-up, on a real `rakectl run`."""

from __future__ import annotations

import dataclasses
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from rakectl.config.service import BusSettings
from rakectl.config.settings import Settings
from rakectl.daemon.inputs import sidecar_path
from rakectl.daemon.places import check_places, keep_earlier_traces, make_dump_dir
from rakectl.errors import ConfigError
from tests.cli_run import ROOT, run_rakectl


def _settings(trace: Path | str = "", keep: int = 3, dump_dir: Path | str = "") -> Settings:
    s = Settings()
    return dataclasses.replace(
        s, bus=BusSettings(trace_path=str(trace), trace_keep=keep),
        daemon=dataclasses.replace(s.daemon, dump_dir=str(dump_dir)))


def _run(trace: Path) -> tuple[str, str]:
    """A run's trace and inputs, written as the daemon leaves them."""
    text = f"{trace.name} of run {len(list(trace.parent.glob('*')))}\n"
    trace.write_text(text)
    sidecar_path(trace).write_text("inputs " + text)
    return text, "inputs " + text


def test_each_start_keeps_the_last_runs_traces_up_to_trace_keep(tmp_path: Path) -> None:
    trace = tmp_path / "logs" / "trace.log"
    settings = _settings(trace, keep=2)
    assert keep_earlier_traces(settings) == []  # nothing yet: its directory made
    assert trace.parent.is_dir()
    runs = []
    for _ in range(3):
        runs.append(_run(trace))
        moved = keep_earlier_traces(settings)
        assert not trace.exists() and not sidecar_path(trace).exists()
        assert moved[0] == Path(f"{trace}.1")
    assert sorted(p.name for p in trace.parent.iterdir()) == [
        "trace.log.1", "trace.log.1.inputs.jsonl", "trace.log.2", "trace.log.2.inputs.jsonl"]
    for n, (text, inputs) in ((1, runs[2]), (2, runs[1])):  # the oldest run gone
        assert Path(f"{trace}.{n}").read_text() == text
        assert sidecar_path(f"{trace}.{n}").read_text() == inputs
    for _ in range(3):  # starts that failed before their loop ran (no start entry), as
        trace.write_text("bring-up frames\n")  # systemd's restarts after an incident:
        sidecar_path(trace).write_text("")  # overwritten, the incident's trace kept
        assert keep_earlier_traces(settings) == []
    assert Path(f"{trace}.1").read_text() == runs[2][0]
    _run(trace)
    assert keep_earlier_traces(_settings(trace, keep=1)) == [Path(f"{trace}.1")]
    assert sorted(p.name for p in trace.parent.iterdir()) == [  # trace_keep lowered
        "trace.log.1", "trace.log.1.inputs.jsonl"]
    _run(trace)
    assert keep_earlier_traces(_settings(trace, keep=0)) == []
    assert sorted(p.name for p in trace.parent.iterdir()) == [  # overwritten at start
        "trace.log", "trace.log.inputs.jsonl"]


def test_places_the_daemon_cannot_write_are_named_before_anything(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for settings, message in (
            (_settings(dump_dir=blocker / "dumps"),
             f"daemon.dump_dir: {blocker / 'dumps'}: {blocker} is not a directory"),
            (_settings(trace=tmp_path, dump_dir=tmp_path),
             f"bus.trace_path: {tmp_path} is a directory"),
            (_settings(trace=blocker / "trace.log", dump_dir=tmp_path),
             f"bus.trace_path: {blocker}: {blocker} is not a directory")):
        with pytest.raises(ConfigError) as refused:
            check_places(settings)
        assert str(refused.value) == message
    with pytest.raises(ConfigError, match=r"^daemon\.dump_dir: "):
        make_dump_dir(_settings(dump_dir=blocker / "dumps"))
    assert check_places(_settings(trace=tmp_path / "new" / "trace.log",
                                  dump_dir=tmp_path / "d")) == [
        f"dumps to {tmp_path / 'd'}",
        f"bus trace {tmp_path / 'new' / 'trace.log'}, the last 3 runs' kept"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]  # nothing made
    # empty, outside systemd: the service's StateDirectory, not this working directory
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    assert check_places(_settings()) == [
        "dumps to the service's StateDirectory (not checked here: daemon.dump_dir is empty)"]


def test_a_bad_dump_dir_is_refused_by_check_and_by_the_daemon_before_the_bus(
        tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    setting = f"daemon.dump_dir={blocker / 'dumps'}"
    expected = f"rakectl: error: daemon.dump_dir: {blocker / 'dumps'}: {blocker} is not a directory"
    check = run_rakectl("run", "--check", "--set", setting)
    assert (check.returncode, check.stderr.strip()) == (2, expected)
    done = run_rakectl("run", "--set", setting, "--set",
                       f"daemon.socket_path={tmp_path / 'rakectl.sock'}",
                       "--set", "daemon.startup_cyclictest_s=0")
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1] == expected
    assert "timing_reference" not in done.stderr  # refused before the bus and bring-up


def test_a_restart_keeps_the_trace_and_bring_up_extends_the_start_timeout(
        tmp_path: Path) -> None:
    """`rakectl run` with no drive on its bus and a trace from a run before: the earlier
    trace moves to TRACE.1 before the bus opens; systemd's start timeout is extended
    for the bring-up by its 9 waits of a boot timeout and 30 s (here 1.8 + 30 s), and the
    bring-up's failure is the daemon's own word, exit 1."""
    trace = tmp_path / "trace.log"
    before, inputs_before = _run(trace)
    systemd = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    address = str(tmp_path / "notify")
    systemd.bind(address)
    systemd.settimeout(5.0)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "rakectl", "run", "--set", f"bus.trace_path={trace}",
             "--set", f"daemon.socket_path={tmp_path / 'rakectl.sock'}",
             "--set", f"daemon.dump_dir={tmp_path}", "--set", "daemon.startup_cyclictest_s=0",
             "--set", "daemon.boot_timeout_s=0.2", "--set", f"bus.channel=places-{tmp_path.name}"],
            capture_output=True, text=True, timeout=120, cwd=ROOT,
            env={**os.environ, "NOTIFY_SOCKET": address})
        messages = []
        systemd.setblocking(False)
        while True:
            try:
                messages.append(systemd.recv(4096).decode())
            except BlockingIOError:
                break
    finally:
        systemd.close()
    assert done.returncode == 1, done.stderr
    assert "no heartbeat or boot-up within 0.2 s" in done.stderr.strip().splitlines()[-1]
    assert Path(f"{trace}.1").read_text() == before
    assert sidecar_path(f"{trace}.1").read_text() == inputs_before
    assert "trace_kept" in done.stderr
    assert "EXTEND_TIMEOUT_USEC=31800000\nSTATUS=bringing up the drives" in messages, messages
