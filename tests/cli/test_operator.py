"""The operator's commands as an operator runs them (processes), against a daemon on a
real Unix socket: how a lane ended and the exit status that says it, the rake stopped
on Ctrl-C, SIGTERM and SIGHUP, a daemon lost while a lane is followed, the next step
after a refusal, and the command line's usage and help."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rakectl.api.replies import excavation_outcome, next_step
from rakectl.config.settings import JogSettings, Settings
from tests.cli.daemons import AnsweringDaemon, in_process_daemon
from tests.cli_run import ROOT, run_rakectl

LANE = ("--reach-far", "1.25", "--reach-near", "1.15", "--depth", "0.005", "--step", "0.005")
TIP = {"reach_m": 1.2, "depth_m": 0.004, "tines_height_max_m": -0.004}


# The signals a terminal's command takes at their defaults (a test run under nohup, or in a
# shell's background, has its children ignore some), then rakectl in the same process.
_FROM_A_TERMINAL = ("import os, signal, sys\n"
                    "for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):\n"
                    "    signal.signal(signum, signal.SIG_DFL)\n"
                    "os.execv(sys.executable, [sys.executable, '-m', 'rakectl', *sys.argv[1:]])")


def _start(*args: str) -> subprocess.Popen[str]:
    """``rakectl ARGS…`` started as an operator starts it, its output captured."""
    return subprocess.Popen([sys.executable, "-c", _FROM_A_TERMINAL, *args], cwd=ROOT,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline_s = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline_s:
            raise AssertionError(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.02)


def _status(state: str, **excavation: Any) -> dict[str, Any]:
    """A status reply with the fields the daemon's carries (rakectl.daemon.handlers)."""
    lane = {"phase": "done", "cycle": 3, "depth_m": 0.04, "target_depth_m": 0.04,
            "done": True, "stopped_by_force": False, "held_by_descent": False,
            "object_found": None} | excavation
    return {"state": state, "fault": None, "pid": 100, "tip": TIP,
            "force": {"f_hat_n": 1.0, "f_hat_max_n": 17.9}, "excavation": lane}


# --------------------------------------------------------------------------- how a lane ends


@pytest.mark.parametrize(("reply", "completed", "line"), [
    (_status("hold"), True, "excavate: done, target depth reached (cycle 3, depth 40/40 mm, "
     "F̂ max 17.9 N)"),
    (_status("hold", depth_m=0.02, held_by_descent=True), True,
     "excavate: done as deep as the descent limit allows (cycle 3, depth 20/40 mm"),
    (_status("hold", object_found={"reach_m": 1.118, "depth_m": 0.04}), True,
     "excavate: OBJECT FOUND at reach 1.118 m, depth 40 mm"),
    (_status("hold", stopped_by_force=True, depth_m=0.01), False,
     "excavate: STOPPED BY THE FORCE LIMIT (cycle 3, depth 10/40 mm, F̂ max 17.9 N): the "
     "lane is not finished"),
    (_status("hold", done=False, phase="stroke", depth_m=0.01), False,
     "excavate: STOPPED by an operator's `rakectl stop` (cycle 3, depth 10/40 mm, F̂ max "
     "17.9 N): the lane is not finished"),
    (_status("fault", done=False) | {"fault": "drive theta: no feedback for 20 cycles"}, False,
     "excavate: FAULT: drive theta: no feedback for 20 cycles (cycle 3, depth 40/40 mm, F̂ max "
     "17.9 N): the lane is not finished; `rakectl reset`, then `rakectl arm`"),
    (_status("estop", done=False) | {"fault": "operator e-stop"}, False,
     "excavate: EMERGENCY STOP: operator e-stop (cycle 3"),
    (_status("disarmed", done=False), False, "excavate: DISARMED (`rakectl disarm`)"),
])
def test_how_a_lane_ended_and_whether_it_completed(
        tmp_path: Path, reply: dict[str, Any], completed: bool, line: str) -> None:
    """`rakectl excavate` follows the lane to its end: exit status 0 only when it
    completed (its depth, the descent limit's hold, an object), else 1 with one line
    saying how it ended; the line is the status's, field by field."""
    assert excavation_outcome(reply)[0] is completed
    path = tmp_path / "rakectl.sock"
    replies = iter([_status("excavate", done=False, phase="approach"), reply])

    def answer(request: dict[str, Any]) -> dict[str, Any]:
        return {"state": "excavate"} if request["cmd"] == "excavate" else next(replies)

    with AnsweringDaemon(path, answer):
        done = run_rakectl("excavate", "--socket", str(path), *LANE)
    assert done.returncode == (0 if completed else 1), done.stderr
    assert done.stdout.startswith(line), done.stdout
    assert len(done.stdout.splitlines()) == 1


def test_a_lane_stopped_by_another_operator_is_not_a_success(tmp_path: Path) -> None:
    """The daemon itself: a second operator's `rakectl stop` during the lane ends the
    first one's `rakectl excavate` with exit status 1, naming the stop (it said the lane's
    progress and exit status 0 before)."""
    with in_process_daemon(tmp_path) as daemon:
        excavating = _start("excavate", "--socket", str(daemon.path), *LANE)
        try:
            daemon.wait_for("excavate", 30.0)
            daemon.request("stop")
            out, err = excavating.communicate(timeout=60.0)
        finally:
            excavating.kill()
            excavating.wait()
        status = daemon.request("status")
    assert status["state"] == "hold" and not status["excavation"]["done"]
    assert excavating.returncode == 1, err
    assert out.startswith("excavate: STOPPED by an operator's `rakectl stop` (cycle 1, "), out
    assert out.strip().endswith("the lane is not finished")


# --------------------------------------------------------------------------- signals


def _signalled(daemon: Any, args: tuple[str, ...], state: str, signum: int
               ) -> tuple[subprocess.Popen[str], str, str, dict[str, Any]]:
    """The command started, ``signum`` sent once the daemon is in ``state``; its output
    and the daemon's status right after it ended."""
    process = _start(*args, "--socket", str(daemon.path))
    try:
        daemon.wait_for(state, 30.0)
        time.sleep(0.3)  # a few of its requests
        process.send_signal(signum)
        out, err = process.communicate(timeout=30.0)
    finally:
        process.kill()
        process.wait()
    return process, out, err, daemon.request("status")


def test_ctrl_c_sigterm_and_sighup_stop_the_lane_and_say_where_the_tip_is(
        tmp_path: Path) -> None:
    """Before, Ctrl-C left the lane raking with only `rakectl: interrupted`, and SIGTERM
    or SIGHUP (the terminal closed) without a word: now each stops it, says so and where
    the tip is, and exits 128 + the signal's number."""
    with in_process_daemon(tmp_path) as daemon:
        for signum, name in ((signal.SIGINT, "Ctrl-C (SIGINT)"), (signal.SIGTERM, "SIGTERM"),
                             (signal.SIGHUP, "SIGHUP (the terminal closed)")):
            process, _, err, status = _signalled(daemon, ("excavate", *LANE), "excavate",
                                                 signum)
            assert process.returncode == 128 + signum, err
            assert status["state"] == "hold" and not status["excavation"]["done"], status
            line = err.strip().splitlines()[-1]
            assert line.startswith(f"excavate: {name}: lane stopped (cycle 1, "), err
            assert "not finished); tip at reach " in line and line.endswith(" mm")
            assert "Traceback" not in err


def test_jog_stops_on_sigterm_and_sighup_and_ends_as_asked_on_ctrl_c(tmp_path: Path) -> None:
    """The daemon's dead-man (2 s here) would stop a jog left alone; the command stops it
    at once and says where the tip is: Ctrl-C without --duration is its way to end (exit
    status 0), SIGTERM and SIGHUP exit 143 and 129 (before, SIGTERM ended the process
    without a word and the jog went on until the dead-man)."""
    settings = dataclasses.replace(Settings(), jog=JogSettings(deadman_s=2.0))
    jog = ("jog", "--height", "0.01")
    with in_process_daemon(tmp_path, settings) as daemon:
        process, out, err, status = _signalled(daemon, jog, "jog", signal.SIGINT)
        assert process.returncode == 0, err
        assert status["state"] == "hold"
        assert out.startswith("jogged ") and "s; tip at reach " in out
        for signum, name in ((signal.SIGTERM, "SIGTERM"),
                             (signal.SIGHUP, "SIGHUP (the terminal closed)")):
            process, out, err, status = _signalled(daemon, jog, "jog", signum)
            assert process.returncode == 128 + signum, err
            assert status["state"] == "hold", status
            assert err.strip().splitlines()[-1].startswith(f"jog: {name}: stopped after ")
            assert "tip at reach " in err and out == ""


def test_ctrl_c_while_a_jog_request_is_in_flight_reads_no_reply_twice(tmp_path: Path) -> None:
    """A daemon that answers 0.3 s late, Ctrl-C while a jog's reply is awaited: the stop
    and the status go on connections of their own, so the jog's reply is never read as
    theirs (before: `KeyError: 'tip'`, a traceback)."""
    path = tmp_path / "rakectl.sock"
    replies = {"jog": {"state": "jog"}, "stop": {"state": "hold"},
               "status": {"state": "hold", "tip": TIP}}
    with AnsweringDaemon(path, lambda request: replies[request["cmd"]], delay_s=0.3) as fake:
        jogging = _start("jog", "--socket", str(path), "--height", "0.01")
        try:
            _until(lambda: fake.requests.count("jog") >= 2, 30.0, "two jog requests")
            time.sleep(0.05)  # the second one's reply is 0.25 s away
            assert fake.answered < len(fake.requests)
            jogging.send_signal(signal.SIGINT)
            out, err = jogging.communicate(timeout=30.0)
        finally:
            jogging.kill()
            jogging.wait()
    assert jogging.returncode == 0, err
    assert "Traceback" not in err
    assert out == "jogged " + out.split()[1] + " s; tip at reach 1.200 m, depth 4.0 mm\n"
    assert fake.requests[-2:] == ["stop", "status"]


# --------------------------------------------------------------------------- a lost daemon


def _follow(path: Path, fake_daemon: Callable[[AnsweringDaemon], None],
            answer: Callable[[dict[str, Any]], dict[str, Any] | None]
            ) -> tuple[subprocess.CompletedProcess[str], AnsweringDaemon]:
    """`rakectl excavate` following a lane; after its third status, ``fake_daemon``."""
    with AnsweringDaemon(path, answer) as fake:
        excavating = _start("excavate", "--socket", str(path), *LANE)
        try:
            _until(lambda: fake.requests.count("status") >= 3, 30.0, "three polls")
            fake_daemon(fake)
            out, err = excavating.communicate(timeout=30.0)
        finally:
            excavating.kill()
            excavating.wait()
    return subprocess.CompletedProcess(excavating.args, excavating.returncode, out, err), fake


def _raking(request: dict[str, Any]) -> dict[str, Any]:
    if request["cmd"] == "excavate":
        return {"state": "excavate"}
    return _status("excavate", done=False, phase="stroke")


def test_a_daemon_that_ended_while_a_lane_was_followed(tmp_path: Path) -> None:
    path = tmp_path / "rakectl.sock"
    done, _ = _follow(path, AnsweringDaemon.gone, _raking)
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"rakectl: error: excavate: lost the daemon at {path} while it raked the lane (the "
        "connection failed and it takes no new one): the lane cannot go on without it (its "
        "drives stop on their command watchdog; a daemon that starts again starts "
        "disarmed); check `rakectl status`")


def test_a_daemon_restarted_while_a_lane_was_followed(tmp_path: Path) -> None:
    path = tmp_path / "rakectl.sock"
    restarted = {"state": "disarmed", "pid": 200, "tip": TIP, "excavation": None}
    done, _ = _follow(path, lambda fake: fake.restart(lambda request: restarted), _raking)
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"rakectl: error: excavate: the daemon at {path} restarted while it raked the lane "
        "(pid 100, now pid 200, disarmed): the lane is not resumed; check `rakectl status`")


def test_a_daemon_frozen_while_a_lane_was_followed_is_left_a_stop(tmp_path: Path) -> None:
    """No answer for 2 s, none on a new connection either: the lane may go on if the
    daemon resumes, so a stop is left for it to read then (it reads a closed connection's
    requests and answers them)."""
    path = tmp_path / "rakectl.sock"
    frozen: list[bool] = []

    def answer(request: dict[str, Any]) -> dict[str, Any] | None:
        return None if frozen else _raking(request)

    started_s = time.monotonic()
    done, fake = _follow(path, lambda fake: frozen.append(True), answer)
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"rakectl: error: excavate: the daemon at {path} stopped answering while it raked "
        "the lane: while it is frozen its drives stop on their command watchdog, but the lane "
        "may go on if it resumes; a stop waits for it there; check `rakectl status`")
    assert fake.requests[-1] == "stop"
    assert time.monotonic() - started_s < 15.0


def test_the_same_daemon_closing_the_connection_is_followed_on_a_new_one(
        tmp_path: Path) -> None:
    """Its pid unchanged: the lane goes on, and so does the command, to the lane's end."""
    path = tmp_path / "rakectl.sock"
    polls_after: list[int] = []

    def answer(request: dict[str, Any]) -> dict[str, Any]:
        if polls_after and request["cmd"] == "status":
            polls_after.append(1)
            if len(polls_after) > 3:
                return _status("hold")
        return _raking(request)

    def drop(fake: AnsweringDaemon) -> None:
        polls_after.append(0)
        fake.drop_connections()

    done, _ = _follow(path, drop, answer)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("excavate: done, target depth reached")
    assert len(polls_after) > 3


# --------------------------------------------------------------------------- refusals


@pytest.mark.parametrize(("error", "state", "expected"), [
    ("cannot jog while estop (operator e-stop)", "estop",
     "cannot jog while estop (operator e-stop); next: `rakectl reset`, then `rakectl arm`"),
    ("cannot arm while fault (drive r: EMCY 0x2310)", "fault",
     "cannot arm while fault (drive r: EMCY 0x2310); next: `rakectl reset`, then "
     "`rakectl arm`"),
    ("cannot excavate while disarmed", "disarmed",
     "cannot excavate while disarmed; next: `rakectl arm`"),
    # the daemon's sentence names them already: said once
    ("cannot jog while estop (operator e-stop): reset clears it, then arm", "estop",
     "cannot jog while estop (operator e-stop): reset clears it, then arm"),
    ("cannot jog while disarmed: arm first", "disarmed", "cannot jog while disarmed: arm first"),
    ("the lane leaves the workspace: reach 3 m", "armed",
     "the lane leaves the workspace: reach 3 m"),
])
def test_a_refusal_names_the_next_step_by_the_daemons_state(
        tmp_path: Path, error: str, state: str, expected: str) -> None:
    """Keyed on the state the daemon reports (a status asked after the refusal, when the
    refusal does not carry it), not on the sentence."""
    path = tmp_path / "rakectl.sock"

    def answer(request: dict[str, Any]) -> dict[str, Any]:
        if request["cmd"] == "status":
            return {"state": state, "tip": TIP}
        return {"ok": False, "error": error}

    command = error.split()[1] if error.startswith("cannot") else "excavate"
    args = {"jog": ("--height", "0.01"), "arm": (), "excavate": LANE}[command]
    with AnsweringDaemon(path, answer) as fake:
        done = run_rakectl(command, "--socket", str(path), *args)
    assert done.returncode == 1
    assert done.stderr.strip() == f"rakectl: error: {expected}"
    assert fake.requests == [command, "status"]


def test_shutdown_says_the_daemon_ends_not_only_the_state_it_was_in(tmp_path: Path) -> None:
    """The reply carries the state the daemon was in when it took the request (hold):
    printed alone, it read as if the daemon went on holding."""
    path = tmp_path / "rakectl.sock"
    with AnsweringDaemon(path, lambda request: {"ok": True, "state": "hold",
                                               "stopping": True}) as fake:
        done = run_rakectl("shutdown", "--socket", str(path))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == ("shutdown: the daemon stops the rake, disarms and ends (it "
                                   "was hold)")
    assert fake.requests == ["shutdown"]


def test_a_refusal_that_carries_the_state_needs_no_status(tmp_path: Path) -> None:
    path = tmp_path / "rakectl.sock"
    with AnsweringDaemon(path, lambda request: {"ok": False, "state": "estop",
                                               "error": "cannot jog while estop"}) as fake:
        done = run_rakectl("jog", "--socket", str(path), "--height", "0.01")
    assert done.stderr.strip() == ("rakectl: error: cannot jog while estop; next: "
                                   "`rakectl reset`, then `rakectl arm`")
    assert fake.requests == ["jog"]


def test_the_next_step_is_not_the_refused_command() -> None:
    assert next_step("cannot arm while estop (operator e-stop)", "estop") == (
        "`rakectl reset`, then `rakectl arm`")
    assert next_step("cannot arm while estop: reset, then arm", "estop") == ""
    assert next_step("cannot jog while checking", "checking") == ""
    assert next_step("cannot jog while estop", None) == ""


# --------------------------------------------------------------------------- usage, help


@pytest.mark.parametrize(("args", "expected"), [
    (("jog", "--r", "0.1"), "jog: --r does not apply in task space"),
    (("jog", "--duration", "0"), "jog: --duration must be in (0, 600] s, got 0.0"),
    (("jog", "--height", "nan"), "jog: --height must be a finite speed, got nan"),
    (("jog", "--height", "5"), "jog: --height must be <= 0.25, got 5 (m/s)"),
    (("jog", "--space", "joint", "--theta", "-0.6"),
     "jog: --theta must be >= -0.5, got -0.6 (rad/s)"),
    (("jog", "--height", "x"), "jog: argument --height: invalid float value: 'x'"),
    (("excavate", "--reach-far", "1.0", "--reach-near", "1.2", "--depth", "0.05"),
     "excavate: --reach-far must be > --reach-near (1.2), got 1"),
    (("excavate", "--reach-far", "1.3", "--reach-near", "1.2", "--depth", "0.9"),
     "excavate: --depth must be <= 0.5, got 0.9"),
    (("status", "--bogus"), "status: unrecognized arguments: --bogus"),
])
def test_a_bad_value_or_usage_is_exit_status_2_naming_the_flag(
        tmp_path: Path, args: tuple[str, ...], expected: str) -> None:
    """Caught by argparse or after it, the same: one line, exit status 2, nothing sent
    (no daemon listens here; that would be 3)."""
    done = run_rakectl(*args, "--socket", str(tmp_path / "none.sock"))
    assert done.returncode == 2
    assert done.stderr.startswith(f"rakectl: error: {expected}"), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_no_daemon_is_exit_status_3(tmp_path: Path) -> None:
    done = run_rakectl("status", "--socket", str(tmp_path / "none.sock"))
    assert done.returncode == 3
    assert done.stderr.startswith("rakectl: error: cannot reach the rakectl daemon at ")


@pytest.mark.parametrize(("said", "flags", "expected"), [
    (None, ("--height", "-0.25"), "jog: --height -0.25 m/s is faster than "
     "jog.max_tip_speed_m_per_s, the daemon's cap (0.1 m/s unless configured otherwise): "
     "it moves at the cap"),
    ({"max_tip_speed_m_per_s": 0.02, "max_r_speed_m_per_s": 0.1,
      "max_theta_speed_rad_per_s": 0.15}, ("--height", "-0.05"), "jog: --height -0.05 m/s "
     "is faster than jog.max_tip_speed_m_per_s, the daemon's cap (0.02 m/s): it moves at "
     "the cap")])
def test_a_speed_above_the_daemons_cap_is_said(tmp_path: Path, said: dict[str, float] | None,
                                                flags: tuple[str, str], expected: str) -> None:
    """The cap as the daemon's reply to the jog says it (a daemon configured slower than
    the default: a speed under the default is said too), the default from one that does
    not say it."""
    path = tmp_path / "rakectl.sock"
    replies = {"jog": {"state": "jog"} | ({"jog": said} if said else {}),
               "stop": {"state": "hold"}, "status": {"state": "hold", "tip": TIP}}
    with AnsweringDaemon(path, lambda request: replies[request["cmd"]]):
        done = run_rakectl("jog", "--socket", str(path), *flags, "--duration", "0.2")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [expected]


def test_status_into_a_closed_pipe_is_quiet(tmp_path: Path) -> None:
    """`rakectl status | head -1`: the reader gone, no error and no traceback (141, as a
    Unix tool killed by SIGPIPE)."""
    path = tmp_path / "rakectl.sock"
    reply = _status("hold") | {"drives": [], "weight_check": {"message": "passed"},
                               "mount_check": {"message": "disabled"}}
    reply["force"] |= {"clamp_worst_case_n": 30.0, "clamp_limit_n": 72.0}
    with AnsweringDaemon(path, lambda request: reply):
        status = _start("status", "--socket", str(path))
        assert status.stdout is not None
        status.stdout.close()  # the reader gone before the first line
        _, err = status.communicate(timeout=30.0)
    assert err == ""
    assert status.returncode == 141


def test_status_without_a_pose_says_so(tmp_path: Path) -> None:
    """The daemon bringing its drives up has no pose yet (its tip fields are null)."""
    path = tmp_path / "rakectl.sock"
    reply = _status("init") | {"drives": [{"state": None}], "tip": {
        "reach_m": None, "depth_m": None, "tines_height_max_m": None},
        "weight_check": {"message": "not run"}, "mount_check": {"message": "not run"},
        "excavation": None}
    reply["force"] |= {"clamp_worst_case_n": 30.0, "clamp_limit_n": 72.0}
    with AnsweringDaemon(path, lambda request: reply):
        done = run_rakectl("status", "--socket", str(path))
    assert done.returncode == 0, done.stderr
    assert "tip        no pose (no joint feedback)" in done.stdout.splitlines()


def test_status_says_the_jog_caps_and_which_lane_runs(tmp_path: Path) -> None:
    """`rakectl status` on the daemon itself: the fastest it jogs, as configured, and
    the lane in progress by its number since start-up and its parameters; `excavate
    --no-wait` names the number it started (before, neither was said: two lanes alike in
    progress could not be told apart), with --json as the daemon's reply."""
    settings = dataclasses.replace(Settings(), jog=JogSettings(max_tip_speed_m_per_s=0.05,
                                                               max_theta_speed_rad_per_s=0.12))
    lane = (*LANE, "--speed", "0.04", "--no-wait")
    with in_process_daemon(tmp_path, settings) as daemon:
        socket = ("--socket", str(daemon.path))
        first = run_rakectl("excavate", *socket, *lane)
        daemon.request("stop")
        second = run_rakectl("excavate", *socket, *lane)
        shown = run_rakectl("status", *socket)
        daemon.request("stop")
        third = run_rakectl("excavate", *socket, *lane, "--json")
        daemon.request("stop")
    assert (first.stdout, second.stdout) == ("excavate: lane 1 started\n",
                                             "excavate: lane 2 started\n"), first.stderr
    # --json: the daemon's reply, as every other command gives it (before: the text)
    assert json.loads(third.stdout) == {"ok": True, "state": "excavate", "lane": 3}, third
    assert shown.returncode == 0, shown.stderr
    lines = shown.stdout.splitlines()
    assert "jog caps   reach and height 0.05 m/s each, r 0.1 m/s, θ 0.12 rad/s (faster " \
           "requests move at these)" in lines, lines
    # the lock-step rig's lanes are force-adaptive (rakectl.bench.tick)
    assert "lane       2: reach 1.250 → 1.150 m, target 5 mm, force-adaptive (first step " \
           "5 mm, stroke 0.04 m/s)" in lines, lines
    assert lines[-1].startswith("excavate   cycle 1, depth 0/5 mm, ")


OPERATOR_COMMANDS = ("arm", "reset", "disarm", "stop", "estop", "shutdown", "status", "dump",
                     "jog", "excavate")


def test_the_help_says_what_each_operator_command_does_and_the_exit_statuses() -> None:
    top = run_rakectl("--help")
    assert top.returncode == 0
    assert top.stdout.split("\n\n")[1].startswith("The control of a demining robot's rake.")
    exit_statuses = top.stdout[top.stdout.index("exit status:"):]
    for status in ("0 ", "1 ", "2 ", "3 ", "128+N "):
        assert f"\n  {status}" in exit_statuses
    for command in OPERATOR_COMMANDS:
        page = run_rakectl(command, "--help").stdout
        description = page.split("\n\n")[1]
        assert not description.startswith("options:"), (command, page)
    for command in ("jog", "excavate"):
        page = " ".join(run_rakectl(command, "--help").stdout.split())
        assert "SIGTERM and SIGHUP (the terminal closed) stop it too" in page
