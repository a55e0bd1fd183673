"""The rakectl command run as a real process, as an operator would run it."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.cli_run import run_rakectl
from tests.scripted_daemon import ScriptedDaemon

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "config" / "scenarios" / "paper-fig5.yaml"


def test_simulate_again_into_a_directory_leaves_no_earlier_plot_beside_it(
        tmp_path: Path) -> None:
    """A run into a directory of an earlier one left that run's plot (and MCAP) beside the
    new telemetry, as if they were its."""
    assert run_rakectl("simulate", str(PAPER), "--out", str(tmp_path), "--plot").returncode == 0
    assert (tmp_path / "plot.png").exists()
    assert run_rakectl("simulate", str(PAPER), "--out", str(tmp_path)).returncode == 0
    assert not (tmp_path / "plot.png").exists()
    assert (tmp_path / "telemetry.csv").exists() and (tmp_path / "summary.json").exists()


def test_simulate_the_paper_writes_telemetry_summary_and_plot(tmp_path: Path) -> None:
    done = run_rakectl("simulate", str(PAPER), "--out", str(tmp_path), "--plot", "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["f_hat_final_n"] == pytest.approx(14.00, abs=0.05)
    assert summary["tracking_error_final_m"] == pytest.approx(2.80e-3, abs=0.02e-3)
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    with open(tmp_path / "telemetry.csv") as f:
        reader = csv.reader(f)
        header = next(reader)
        rows = sum(1 for _ in reader)
    assert {"t_s", "x_d_m", "x_m", "x_e_hat_m", "f_hat_n"} <= set(header)
    assert rows == summary["ticks"] == 20_000
    png = (tmp_path / "plot.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 20_000


def test_set_changes_the_result(tmp_path: Path) -> None:
    done = run_rakectl("simulate", str(PAPER), "--out", str(tmp_path), "--json",
                       "--set", "estimator.delay_s=0.02", "--set", "duration_s=10")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.splitlines()[-1])
    assert summary["f_hat_final_n"] == pytest.approx(28.0, abs=0.1)  # K_e v α
    assert summary["ticks"] == 10_000


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--set", "impedance.damping_ns_per_m=-3"),
         "rakectl: error: --set impedance.damping_ns_per_m=-3: "
         "impedance.damping_ns_per_m must be > 0, got -3"),
        (("--set", "trajectory.sped_m_per_s=1"), "did you mean speed_m_per_s?"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(
    tmp_path: Path, args: tuple[str, ...], expected: str
) -> None:
    out = tmp_path / "out"
    done = run_rakectl("simulate", str(PAPER), "--out", str(out), *args)
    assert done.returncode == 2
    assert done.stderr.strip() == expected or expected in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_scenario_file_names_file_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("impedance:\n  mass_kg: 1\n  damping_ns_per_m: -3\n")
    done = run_rakectl("simulate", str(bad), "--out", str(tmp_path / "o"))
    assert done.returncode == 2
    assert done.stderr.strip() == (
        f"rakectl: error: {bad}:3: impedance.damping_ns_per_m must be > 0, got -3"
    )


def test_usage_errors_are_one_line() -> None:
    done = run_rakectl("simulate")
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1
    assert "required" in done.stderr


def test_config_docs_and_bench_print_figures() -> None:
    docs = run_rakectl("config-docs")
    assert docs.returncode == 0 and "impedance.mass_kg" in docs.stdout
    bench = run_rakectl("bench", "--ticks", "20000")
    assert bench.returncode == 0, bench.stderr
    assert "median" in bench.stdout and "µs" in bench.stdout


@pytest.mark.parametrize("mode", [(), ("--tick",), ("--profiles",)])
def test_bench_refuses_too_few_ticks_in_every_mode_that_times_them(
        mode: tuple[str, ...], tmp_path: Path) -> None:
    done = run_rakectl("bench", *mode, "--ticks", "0", "--report", str(tmp_path))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip() == "rakectl: error: bench: --ticks must be >= 1000"
    assert not list(tmp_path.iterdir())  # nothing timed, nothing written


@pytest.mark.parametrize("command", ["emulator", "fuzz"])
def test_pass_through_commands_read_their_own_options(command: str) -> None:
    done = run_rakectl(command, "--help")
    assert done.returncode == 0, done.stderr
    assert f"usage: rakectl {command} " in done.stdout


@pytest.mark.parametrize(("argv", "expected"), [
    (("status", "--bogus"), "unrecognized arguments: --bogus"),
    (("fuzz", "--bogus"), "rakectl: error: fuzz: unrecognized arguments: --bogus"),
    (("fuzz", "--scenarios", "x"),
     "rakectl: error: fuzz: argument --scenarios: invalid int value"),
    (("fuzz", "--scenarios", "0"), "rakectl: error: fuzz: --scenarios must be >= 1, got 0"),
    (("fuzz", "--workers", "0"), "rakectl: error: fuzz: --workers must be >= 1, got 0"),
    (("fuzz", "--first", "-3"), "rakectl: error: fuzz: --first must be >= 0, got -3"),
    (("fuzz", "--plot"), "rakectl: error: fuzz: --plot needs --out DIR"),
    (("fuzz", "--replay", "case.json", "--out", "x", "--plot"),  # ignored before
     "rakectl: error: fuzz: --replay runs one case; --out, --plot cannot go with it"),
    (("fuzz", "--trace", "3", "--compare", "x"),
     "rakectl: error: fuzz: --trace runs one case; --compare cannot go with it"),
    (("fuzz", "--seed", "-1", "--scenarios", "2"),  # numpy's traceback before
     "rakectl: error: fuzz: --seed must be >= 0, got -1"),
    (("emulator", "--interface", "foo"),
     "rakectl emulator: error: argument --interface: invalid choice: 'foo'"),
    # read as the current directory before, which the daemon refused as "a file is there"
    (("dump", "--path", ""), "rakectl: error: dump: argument --path: an empty path names "
     "no file"),
    # "[Errno 17] File exists" and "[Errno 21] Is a directory", exit 1, before
    (("fuzz", "--scenarios", "1", "--out", "/etc/passwd"),
     "rakectl: error: fuzz: --out /etc/passwd is not a directory"),
    (("view", "--write-layout", "/tmp"),
     "rakectl: error: view: --write-layout /tmp is a directory, not a file"),
    # a raw errno, exit 1, before (simulate's after the whole run)
    (("files", "--copy", "/etc/passwd"), "rakectl: error: files: --copy /etc/passwd is not a "
     "directory"),
    (("simulate", str(PAPER), "--out", "/etc/passwd"), "rakectl: error: simulate: --out "
     "/etc/passwd is not a directory"),
])
def test_unknown_options_elsewhere_are_one_line_errors(argv: tuple[str, ...],
                                                      expected: str) -> None:
    """The commands whose own parser reads their options too (fuzz, emulator): the error
    alone, not argparse's usage block before it."""
    done = run_rakectl(*argv)
    assert done.returncode == 2
    assert expected in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(("args", "expected"), [
    (("--space", "task", "--theta", "0.1"), "jog: --theta does not apply in task space"),
    (("--space", "joint", "--reach", "0.1", "--height", "0.1"),
     "jog: --reach and --height do not apply in joint space"),
    (("--duration", "-5"), "jog: --duration must be in (0, 600] s, got -5.0"),
    (("--duration", "nan"), "jog: --duration must be in (0, 600] s, got nan"),
    (("--height", "inf"), "jog: --height must be a finite speed, got inf"),
])
def test_jog_arguments_are_checked_before_anything_is_sent(tmp_path: Path,
                                                           args: tuple[str, ...],
                                                           expected: str) -> None:
    """No daemon listens on this socket: a checked argument fails first, in one line, as
    argparse's own usage errors do (exit status 2)."""
    done = run_rakectl("jog", "--socket", str(tmp_path / "none.sock"), *args)
    assert done.returncode == 2
    assert done.stderr.startswith(f"rakectl: error: {expected}")
    assert len(done.stderr.strip().splitlines()) == 1


def test_a_jog_without_a_daemon_is_one_line_and_never_says_moving(tmp_path: Path) -> None:
    done = run_rakectl("jog", "--socket", str(tmp_path / "none.sock"), "--height", "-0.01")
    assert done.returncode == 3  # the daemon cannot be reached
    assert done.stderr.startswith("rakectl: error: cannot reach the rakectl daemon")
    assert len(done.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(("args", "expected"), [
    (("--reach-far", "nan", "--reach-near", "0.5", "--depth", "0.1"),
     "excavate: --reach-far must be finite, got nan"),
    (("--reach-far", "1.2", "--reach-near", "0.5", "--depth", "-5"),
     "excavate: --depth must be > 0, got -5"),
    (("--reach-far", "1.2", "--reach-near", "0.5", "--depth", "0.05", "--speed", "inf"),
     "excavate: --speed must be finite, got inf"),
    (("--reach-far", "1.2", "--reach-near", "0.5", "--depth", "0.05", "--step", "0"),
     "excavate: --step must be > 0, got 0"),
    (("--reach-far", "1.0", "--reach-near", "1.2", "--depth", "0.05"),
     "excavate: --reach-far must be > --reach-near (1.2), got 1"),
])
def test_excavate_arguments_are_checked_before_anything_is_sent(
        tmp_path: Path, args: tuple[str, ...], expected: str) -> None:
    """The API's bounds, named by the flag that gave the value; no daemon listens here."""
    done = run_rakectl("excavate", "--socket", str(tmp_path / "none.sock"), *args)
    assert done.returncode == 2
    assert done.stderr.strip() == f"rakectl: error: {expected}"


def test_the_progress_line_clears_what_a_longer_line_left() -> None:
    from rakectl.api.motion import CLEAR_TO_END, progress_line

    assert progress_line("cycle 2, F̂ max 21.7 N", tty=True, finished=False) == (
        "\rcycle 2, F̂ max 21.7 N" + CLEAR_TO_END)
    assert progress_line("done", tty=True, finished=True) == "\rdone" + CLEAR_TO_END + "\n"
    assert progress_line("cycle 2", tty=False, finished=False) == "cycle 2\n"


_W_RUNNING = {"passed": None, "message": "running"}
_W_PASSED = {"passed": True, "message": "weight check: unbalanced weight 19.9 N measured "
                                        "matches 19.6 N configured"}
_M_AFTER = {"passed": None, "message": "after the weight check"}
_M_RUNNING = {"passed": None, "message": "running"}
_M_FAILED = {"passed": False, "message": "tine-mount check: stiffness 63153 N/m measured "
                                         "does not match 5000 N/m configured"}
_M_PASSED = {"passed": True, "message": "tine-mount check: stiffness 5057 N/m measured "
                                        "matches 5000 N/m configured"}


@pytest.mark.parametrize(("replies", "lines", "status"), [
    ([{"state": "checking"},
      {"state": "checking", "weight_check": _W_RUNNING, "mount_check": _M_AFTER},
      {"state": "checking", "weight_check": _W_PASSED, "mount_check": _M_RUNNING},
      {"state": "armed", "weight_check": _W_PASSED, "mount_check": _M_PASSED}],
     ["arm: weight check: lifting the tip and lowering it back", _W_PASSED["message"],
      "arm: tine-mount check: pressing the tines on the anvil", _M_PASSED["message"]], 0),
    ([{"state": "checking"},  # armed again after a failed tine-mount check and a reset
      {"state": "checking", "weight_check": _W_PASSED, "mount_check": _M_RUNNING},
      {"state": "fault", "fault": _M_FAILED["message"], "weight_check": _W_PASSED,
       "mount_check": _M_FAILED}],
     ["arm: tine-mount check: pressing the tines on the anvil", _M_FAILED["message"]], 1),
])
def test_arm_prints_each_check_as_it_starts_and_its_verdict(
        tmp_path: Path, replies: list[dict[str, object]], lines: list[str], status: int) -> None:
    """`rakectl arm` against a scripted daemon on a real socket: the checks this arming
    runs, each announced once and followed by its verdict; a check that passed before
    (the weight, after a reset) is not announced again."""
    path = tmp_path / "rakectl.sock"
    daemon = ScriptedDaemon(path, replies)
    try:
        done = run_rakectl("arm", "--socket", str(path))
    finally:
        daemon.close()
    assert done.returncode == status, done.stderr
    assert done.stderr.splitlines() == lines
    assert done.stdout.startswith(f"arm: {replies[-1]['state']}")
    assert daemon.requests == ["arm"] + ["status"] * (len(replies) - 1)


def test_the_demo_without_its_extra_names_the_extra_and_what_is_missing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Without msgpack (python-can's udp_multicast needs it) the demo's emulator used to
    die at start-up, and the demo said only that the bench stopped."""
    from rakectl.cli.main import main

    monkeypatch.setitem(sys.modules, "msgpack", None)  # find_spec: not installed
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 1
    err = capsys.readouterr().err
    assert "the demo needs the [demo] extra: pip install 'rakectl[demo]' (missing: msgpack)" in (
        err)
    assert not (tmp_path / "demo").exists()  # nothing started


def test_a_view_whose_truth_file_never_appeared_says_so(tmp_path: Path) -> None:
    """--truth follows a file a running emulator writes; a path nothing wrote (mistyped, or
    a bench elsewhere) used to end with "0 rows served" and nothing else."""
    missing = tmp_path / "out" / "truth.csv"
    done = run_rakectl("view", "--socket", str(tmp_path / "none.sock"), "--port", "0",
                       "--truth", str(missing), "--seconds", "1")
    assert done.returncode == 0, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert f"truth: 0 rows served, 0 skipped ({missing} never appeared: is the emulator " in last


def test_run_check_loads_the_configuration_as_the_daemon_does() -> None:
    """`rakectl run --check`: what a field engineer runs after editing the service's
    configuration, before restarting it. The file's socket group (rakectl, which the
    installation creates) is one this machine has: root."""
    done = run_rakectl("run", "--config", str(ROOT / "config" / "rakectl.yaml"), "--check",
                       "--set", "daemon.socket_group=root")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].endswith("config/rakectl.yaml: the configuration loads")
    assert "bus socketcan:can0 at 1000000 bit/s; drives cia402, r node 1, θ node 2, " in lines[1]
    assert lines[2].startswith("  link: ")  # can0's rate (not checked here: no can0)
    assert "checks before arming: weight check and tine-mount check" in lines[3]
    assert not any("warning" in line for line in lines)  # the robot's clamp carries 3 ms
    slow = run_rakectl("run", "--config", str(ROOT / "config" / "rakectl.yaml"), "--check",
                       "--set", "daemon.socket_group=root", "--set",
                       "drives.watchdog_timeout_ms=20")
    assert slow.returncode == 0, slow.stderr
    assert ("warning: clamp.reaction_latency_s (4 ms) does not cover the command the drives "
            "hold") in slow.stdout and "(arming is refused)" in slow.stdout


@pytest.mark.parametrize(("setting", "expected"), [
    ("daemon.socket_group=no-such-group-here", "rakectl: error: daemon.socket_group: the "
     "command socket's group 'no-such-group-here' does not exist (create it with "
     "systemd-sysusers or groupadd)"),
    ("daemon.socket_path=/run/" + "s" * 110, "rakectl: error: daemon.socket_path: the command "
     "socket's path /run/" + "s" * 110 + " is 115 bytes long; AF_UNIX takes at most 107"),
])
def test_a_command_socket_the_daemon_cannot_make_is_refused_before_the_bus(
        tmp_path: Path, setting: str, expected: str) -> None:
    """Both passed --check, and `rakectl run` brought the drives up (reset, configured,
    OPERATIONAL) before it refused them; now --check refuses them, and so does the daemon
    before it opens the bus (over the same interface and channel, no emulator: nothing
    answers, so a bring-up would have timed out instead)."""
    check = run_rakectl("run", "--check", "--set", setting)
    assert check.returncode == 2 and check.stderr.strip() == expected  # a setting's problem
    done = run_rakectl("run", "--set", setting, "--set", f"daemon.dump_dir={tmp_path}",
                       "--set", "daemon.startup_cyclictest_s=0")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == expected


def test_run_check_names_a_bad_key_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "rakectl.yaml"
    bad.write_text("drives:\n  watchdog_timout_ms: 3\n")
    done = run_rakectl("run", "--config", str(bad), "--check")
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr.strip().startswith(f"rakectl: error: {bad}:2: drives.watchdog_timout_ms")
    assert len(done.stderr.strip().splitlines()) == 1


def test_run_check_refuses_what_bring_up_would_refuse_before_sending() -> None:
    """A value each option allows that the drive's EDS does not (40 A is 40 000 mA, beyond
    the 0x2002 object's 32 767): `rakectl run` refuses it at bring-up, so --check does."""
    done = run_rakectl("run", "--config", str(ROOT / "config" / "rakectl.yaml"), "--check",
                       "--set", "motors.r.current_limit_a=40")
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr.strip() == (
        "rakectl: error: motors.r.current_limit_a: r drive (node 1) 0x2002 current limit = "
        "40000 mA is outside 1..32767 of dc_servo_drive.eds")


def test_a_daemon_started_while_another_starts_is_refused_before_the_bus(
        tmp_path: Path) -> None:
    """Two `rakectl run` on one socket, moments apart: the second passed the check of the
    socket (which the first binds only once its bring-up has ended), reset the first one's
    drives in its own bring-up, and left the first faulted for good ("rebooted: bring-up
    needed"). The first now holds a lock next to the socket from before it opens the bus,
    and the second is refused at once, naming it. Here no drive answers, so the first
    waits in its bring-up."""
    sock = tmp_path / "rakectl.sock"
    settings = ["--set", f"daemon.socket_path={sock}", "--set", f"daemon.dump_dir={tmp_path}",
                "--set", "daemon.startup_cyclictest_s=0", "--set", "daemon.boot_timeout_s=5",
                "--set", f"bus.channel=claim-{tmp_path.name}"]
    first = subprocess.Popen([sys.executable, "-m", "rakectl", "run", *settings], cwd=ROOT,
                             stderr=subprocess.PIPE, text=True)
    try:
        assert first.stderr is not None
        for line in first.stderr:  # its log: the claim is taken before this line
            if "timing_reference" in line:
                break
        started_s = time.monotonic()
        second = run_rakectl("run", *settings, timeout_s=60.0)
        assert second.returncode == 1
        assert second.stderr.strip().splitlines()[-1] == (
            f"rakectl: error: another daemon is starting or running with the command socket "
            f"{sock} (it holds {sock}.lock)")
        assert "timing_reference" not in second.stderr  # it went no further
        assert time.monotonic() - started_s < 5.0  # not after a bring-up of its own
        dry_run = run_rakectl("drives", *settings[:-6], *settings[-2:], timeout_s=60.0)
        assert dry_run.returncode == 1  # the dry run's bring-up would reset them as well
        assert dry_run.stderr.strip().splitlines()[-1] == second.stderr.strip().splitlines()[-1]
        assert first.poll() is None  # the first one still in its bring-up
    finally:
        first.kill()
        first.wait(10.0)


def test_a_stop_during_the_drives_bring_up_ends_it_with_status_0(tmp_path: Path) -> None:
    """SIGTERM while the bring-up waited for drives that do not answer (`systemctl stop`
    with the drives off) was held until the bring-up timed out, then the daemon exited 1
    ('no heartbeat or boot-up'), past systemd's 5 s stop timeout with two drives. The
    start-up ends at the signal, status 0; nothing was enabled."""
    settings = ["--set", f"daemon.socket_path={tmp_path / 'rakectl.sock'}",
                "--set", f"daemon.dump_dir={tmp_path}", "--set", "daemon.startup_cyclictest_s=0",
                "--set", "daemon.boot_timeout_s=20", "--set", f"bus.channel=stop-{tmp_path.name}"]
    daemon = subprocess.Popen([sys.executable, "-m", "rakectl", "run", *settings], cwd=ROOT,
                              stderr=subprocess.PIPE, text=True)
    try:
        assert daemon.stderr is not None
        for line in daemon.stderr:
            if "timing_reference" in line:
                break
        time.sleep(0.5)  # into the bring-up's waits
        daemon.send_signal(signal.SIGTERM)
        started_s = time.monotonic()
        assert daemon.wait(10.0) == 0
        assert time.monotonic() - started_s < 5.0  # not the 20 s of the bring-up's timeout
        assert '"during": "start-up"' in daemon.stderr.read()
    finally:
        daemon.kill()
        daemon.wait(10.0)
