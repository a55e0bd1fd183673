"""Where the daemon writes (rakectl.daemon.places): refused before the bus, naming the
setting; the last runs' bus traces kept across a restart; and systemd's start timeout
extended for bring-up, on a real `rakectl run`."""

from __future__ import annotations

import dataclasses
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from rakectl.config.service import BusSettings
from rakectl.config.settings import Settings
from rakectl.daemon.inputs import sidecar_path
from rakectl.daemon.places import (
    check_places,
    judged_as,
    keep_earlier_traces,
    make_dump_dir,
    service_user,
)
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


def _user(name: str) -> pwd.struct_passwd | None:
    try:
        return pwd.getpwnam(name)
    except KeyError:
        return None


NOBODY = _user("nobody")  # an unprivileged user every Debian has, standing for rakectl
as_root = pytest.mark.skipif(os.geteuid() != 0 or NOBODY is None,
                             reason="judging as another user takes root and a user nobody")


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A directory any user can reach (pytest's own are root's alone): ``closed`` (root's,
    0755), ``open`` (0777), ``private`` (0700), a configuration ``root-only.yaml`` (0600)."""
    base = Path(tempfile.mkdtemp(prefix="rakectl-places-", dir="/tmp"))
    try:
        base.chmod(0o755)
        for name, mode in (("closed", 0o755), ("open", 0o777), ("private", 0o700)):
            (base / name).mkdir()
            (base / name).chmod(mode)
        (base / "root-only.yaml").write_text("clamp:\n  force_limit_n: 90\n")
        (base / "root-only.yaml").chmod(0o600)
        yield base
    finally:
        shutil.rmtree(base)


@as_root
def test_run_check_judges_as_the_services_user_what_root_could_write(shared_dir: Path) -> None:
    """Root may write anywhere: run as root, `run --check` passed places the service's
    user could not write, and the service refused them at its start. Now it judges as that
    user (`--user`; by default rakectl where it exists): a child process with the user's
    uid and groups asks the kernel. Each refusal names the setting and the user."""
    closed, private = shared_dir / "closed", shared_dir / "private"
    nobody = "nobody (uid 65534)"
    for settings, expected in (
            ([f"daemon.dump_dir={closed / 'dumps'}"],
             f"daemon.dump_dir: cannot make {closed / 'dumps'} in {closed} (not writable by "
             f"{nobody})"),
            ([f"bus.trace_path={private / 'logs' / 'bus.log'}"],
             f"bus.trace_path: {private / 'logs' / 'bus.log'}: {private} is not searchable "
             f"by {nobody}"),
            (["--config", str(shared_dir / "root-only.yaml")],
             f"--config: cannot read {shared_dir / 'root-only.yaml'} (not readable by "
             f"{nobody})")):
        args = (settings if settings[0] == "--config" else ["--set", settings[0]])
        refused = run_rakectl("run", "--check", "--user", "nobody", *args)
        assert (refused.returncode, refused.stderr.strip()) == (2, f"rakectl: error: {expected}")
        as_root_itself = run_rakectl("run", "--check", "--user", "root", *args)
        assert as_root_itself.returncode == 0, as_root_itself.stderr
        assert "judged as user root (uid 0)" in as_root_itself.stdout
    opened = shared_dir / "open"
    passed = run_rakectl("run", "--check", "--user", "nobody", "--set",
                         f"daemon.dump_dir={opened / 'dumps'}", "--set",
                         f"bus.trace_path={opened / 'bus.log'}")
    assert passed.returncode == 0, passed.stderr
    assert passed.stdout.splitlines()[-1].startswith(  # then what of the unit's sandbox
        f"  dumps to {opened / 'dumps'}; bus trace {opened / 'bus.log'}, the last 3 runs' "
        "kept; judged as user nobody (uid 65534), rakectl.service's sandbox ")
    assert sorted(p.name for p in opened.iterdir()) == []  # nothing made
    if _user("rakectl") is None:  # the default, as root on a machine without the service
        default = run_rakectl("run", "--check")
        assert default.returncode == 0, default.stderr
        assert ("judged as this process (uid 0), not the service's user (no user rakectl "
                "here)") in default.stdout


@as_root
def test_a_place_behind_a_directory_it_cannot_search_is_refused_not_raised(
        shared_dir: Path) -> None:
    """The daemon's own check, as an unprivileged service user, met a directory it cannot
    search: Path.exists() raised PermissionError instead of a refusal naming the setting."""
    assert NOBODY is not None
    hidden = shared_dir / "private" / "dumps"
    with pytest.raises(ConfigError) as refused:
        judged_as(NOBODY, lambda: check_places(_settings(dump_dir=hidden)))
    assert str(refused.value) == (f"daemon.dump_dir: {hidden}: {shared_dir / 'private'} is "
                                  "not searchable by nobody (uid 65534)")
    assert judged_as(NOBODY, lambda: check_places(_settings(
        dump_dir=shared_dir / "open"))) == [f"dumps to {shared_dir / 'open'}"]


def test_user_names_what_it_cannot_judge_as() -> None:
    for args, expected in (
            (("--check", "--user", "no-such-user-here"),
             "run --check --user: no user 'no-such-user-here' on this machine"),
            (("--user", "nobody"),
             "run --user: only with --check (the service's user is its unit's User=)")):
        done = run_rakectl("run", *args)
        assert (done.returncode, done.stderr.strip()) == (2, f"rakectl: error: {expected}")


def test_a_way_that_cannot_be_followed_is_refused_naming_the_setting(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A symbolic link's loop on the way raised a bare OSError (exit 1) from the check and
    from the daemon's own making of its dump directory; a dump directory that is a link to
    nowhere passed the check and the daemon could not make it (a trace file that is one
    is judged by its target: opened, the link makes it); a relative place is judged from the working
    directory, as the daemon would make it, and named whole."""
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    expected = f"daemon.dump_dir: {loop / 'dumps'}: Too many levels of symbolic links"
    for judge in (check_places, make_dump_dir):
        with pytest.raises(ConfigError) as refused:
            judge(_settings(dump_dir=loop / "dumps"))
        assert str(refused.value) == expected
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "gone")
    for judge in (check_places, make_dump_dir):  # passed, then the daemon's mkdir failed
        with pytest.raises(ConfigError) as refused:
            judge(_settings(dump_dir=dangling))
        assert str(refused.value) == (f"daemon.dump_dir: {dangling}: {dangling} is a symbolic "
                                      f"link to {tmp_path / 'gone'}, which does not exist")
    assert check_places(_settings(trace=dangling, keep=0, dump_dir=tmp_path)) == [
        f"dumps to {tmp_path}", f"bus trace {dangling}, the last 0 runs' kept"]  # a file:
    # opened, the link makes its target
    (tmp_path / "a-file").write_text("")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError) as relative:
        check_places(_settings(trace="a-file/bus.log", dump_dir=tmp_path))
    assert str(relative.value) == (f"bus.trace_path: {tmp_path / 'a-file'}: "
                                   f"{tmp_path / 'a-file'} is not a directory")


def test_a_relative_place_is_judged_where_the_daemon_would_resolve_it(tmp_path: Path) -> None:
    """The service resolves a relative place from its unit's working directory (/ unless
    the unit sets one), not from where `run --check` is asked: the check took it from its
    own working directory and passed places the service could not write. The places are
    judged from the directory given, and `run --check` names each relative one."""
    service = tmp_path / "service"
    service.mkdir()
    assert check_places(_settings(trace="traces/bus.log", dump_dir="dumps"), base=service) == [
        f"dumps to {service / 'dumps'}",
        f"bus trace {service / 'traces' / 'bus.log'}, the last 3 runs' kept"]
    (service / "dumps").write_text("")  # then one of them is taken: refused where it is
    with pytest.raises(ConfigError) as refused:
        check_places(_settings(dump_dir="dumps"), base=service)
    assert str(refused.value) == (f"daemon.dump_dir: {service / 'dumps'}: "
                                  f"{service / 'dumps'} is not a directory")
    if service_user(None) is not None:  # judged from its unit's directory (tests/service)
        pytest.skip("the service's user is on this machine: run --check judges as it")
    asked = run_rakectl("run", "--check", "--set", "daemon.dump_dir=build/dumps-relative")
    assert asked.returncode == 0, asked.stderr
    assert f"dumps to {ROOT / 'build' / 'dumps-relative'};" in asked.stdout, asked.stdout
    assert ("  warning: daemon.dump_dir: build/dumps-relative is relative: the daemon takes "
            f"it from its working directory (judged from this one, {ROOT}; the service's is "
            "/ unless its unit sets WorkingDirectory=)\n") in asked.stdout, asked.stdout
