"""The operator's commands that move the rake: ``jog`` (its requests repeated for the
daemon's dead-man) and ``excavate`` (the lane followed to its end), and the signals that
stop them: SIGINT (Ctrl-C), SIGTERM or SIGHUP (the terminal closed) stop the rake, say
where the tip is and return 128 + the signal's number; a jog without ``--duration`` ends
on Ctrl-C as asked (0).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import signal
import sys
import threading
import time
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TextIO

from rakectl.api.client import CHECK_STATUS, Client, DaemonSilent, call
from rakectl.api.console import (
    POLL_S,
    STATE_TIMEOUT_S,
    STATUS,
    STOP,
    print_reply,
    say,
    socket_of,
)
from rakectl.api.replies import excavation_outcome, lane_text, pose_text, progress_text
from rakectl.api.schema import COMMANDS, DEAD_MAN_PERIOD_S, ApiCommand
from rakectl.config.settings import JogSettings
from rakectl.errors import ApiError, CommandRejected, ConfigError, DaemonUnreachable

CLEAR_TO_END = "\x1b[K"  # ANSI: erase from the cursor to the end of the line
MAX_JOG_S = 600.0
MAX_RESUMES = 3  # connections opened again in a row to the daemon raking a lane
# the signals that stop a motion command, as the operator knows them
STOP_SIGNALS = {signal.SIGINT: "Ctrl-C (SIGINT)", signal.SIGTERM: "SIGTERM",
                signal.SIGHUP: "SIGHUP (the terminal closed)"}


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP recorded, not raised, while an operator's command moves
    the rake: its loop sees the signal between two requests (no reply is left unread in
    the middle of one), stops the motion and ends. Installed from the main thread only
    (elsewhere nothing is recorded), and not over a signal ignored (``nohup``, a shell's
    background job); the previous handlers come back on exit."""

    SLICE_S = 0.05  # how soon a sleep ends once a signal has come

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[signal.Signals, Any] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                if signal.getsignal(signum) is not signal.SIG_IGN:
                    self._previous[signum] = signal.signal(signum, self._record)
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def _record(self, signum: int, frame: types.FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum

    def sleep(self, duration_s: float) -> None:
        """Sleep ``duration_s``, or until a signal has come."""
        end_s = time.monotonic() + duration_s
        while self.signum is None and (left_s := end_s - time.monotonic()) > 0:
            time.sleep(min(left_s, self.SLICE_S))


def _stopped_by_signal(args: argparse.Namespace, what: str, signum: int,
                       describe: Callable[[dict[str, Any], bool], str]) -> int:
    """Stop the motion on a connection of its own (the command's may hold a reply not read
    yet), say on stderr what the status says then (``describe``, told whether the stop was
    carried out) and return 128 + the signal's number."""
    path, name = socket_of(args), STOP_SIGNALS.get(signal.Signals(signum), f"signal {signum}")
    try:
        call(path, STOP)
        stopped = True
    except CommandRejected:  # nothing left to stop (a fault, an e-stop): the status says
        stopped = False
    except DaemonUnreachable as lost:
        say(f"{what}: {name}: the stop did not reach the daemon ({lost}); the rake may "
             "still be moving: `rakectl stop`, or `rakectl estop`")
        return 128 + signum
    try:
        reply = call(path, STATUS)
    except ApiError as error:
        say(f"{what}: {name}: stopped; no status after it ({error})")
        return 128 + signum
    if args.json:
        with contextlib.suppress(OSError):
            print(json.dumps(reply), flush=True)
    say(f"{what}: {name}: {describe(reply, stopped)}")
    return 128 + signum


# jog's flags by the API argument each gives, and the daemon's default cap on each
# (jog.*: a faster request is accepted and moved at the cap)
JOG_FLAGS = {"reach_m_per_s": "--reach", "height_m_per_s": "--height", "r_m_per_s": "--r",
             "theta_rad_per_s": "--theta"}
_JOG = JogSettings()
JOG_CAPS = {"reach_m_per_s": ("max_tip_speed_m_per_s", _JOG.max_tip_speed_m_per_s, "m/s"),
            "height_m_per_s": ("max_tip_speed_m_per_s", _JOG.max_tip_speed_m_per_s, "m/s"),
            "r_m_per_s": ("max_r_speed_m_per_s", _JOG.max_r_speed_m_per_s, "m/s"),
            "theta_rad_per_s": ("max_theta_speed_rad_per_s", _JOG.max_theta_speed_rad_per_s,
                                "rad/s")}


def check_jog(args: argparse.Namespace) -> dict[str, Any]:
    """jog's request from its flags, each checked against the API's bounds and named by its
    flag (ConfigError: nothing is sent)."""
    speeds = {"--reach": args.reach, "--height": args.height, "--r": args.r,
              "--theta": args.theta}
    for flag, value in speeds.items():
        if not math.isfinite(value):
            raise ConfigError(f"jog: {flag} must be a finite speed, got {value}")
    other = ("--r", "--theta") if args.space == "task" else ("--reach", "--height")
    given = [flag for flag in other if speeds[flag]]
    if given:
        raise ConfigError(f"jog: {' and '.join(given)} {'does' if len(given) == 1 else 'do'} "
                          f"not apply in {args.space} space "
                          f"(task: --reach/--height; joint: --r/--theta)")
    if args.duration is not None and not 0.0 < args.duration <= MAX_JOG_S:
        raise ConfigError(f"jog: --duration must be in (0, {MAX_JOG_S:g}] s, "
                          f"got {args.duration}")
    if args.space == "task":
        request = {"cmd": "jog", "space": "task", "reach_m_per_s": args.reach,
                   "height_m_per_s": args.height}
    else:
        request = {"cmd": "jog", "space": "joint", "r_m_per_s": args.r,
                   "theta_rad_per_s": args.theta}
    for arg in COMMANDS[ApiCommand.JOG].args:
        value = request.get(arg.name)
        problem = arg.bounds.violation(value) if isinstance(value, float) else None
        if problem:
            raise ConfigError(f"jog: {JOG_FLAGS[arg.name]} {problem} ({arg.unit})")
    return request


def jog_caps(request: Mapping[str, Any], caps: Mapping[str, Any] | None = None) -> list[str]:
    """A line for each speed above the daemon's cap on it, naming the cap: ``caps`` as its
    status says them (``jog``), the defaults where it does not."""
    lines = []
    for name, (setting, default, unit) in JOG_CAPS.items():
        value = request.get(name)
        said = caps.get(setting) if caps else None
        cap = said if isinstance(said, (int, float)) else default
        if isinstance(value, float) and abs(value) > cap:
            whose = "" if said is not None else " unless configured otherwise"
            lines.append(f"jog: {JOG_FLAGS[name]} {value:g} {unit} is faster than "
                         f"jog.{setting}, the daemon's cap ({cap:g} {unit}{whose}): it moves "
                         "at the cap")
    return lines


def jog(args: argparse.Namespace) -> int:
    """Send the jog every 0.1 s (the daemon's dead-man) while this command runs: for
    ``--duration`` seconds, or until Ctrl-C without it; then stop, on a connection of its
    own. SIGTERM, SIGHUP, or Ctrl-C before ``--duration`` is over, stop it too and return
    128 + the signal's number."""
    request = check_jog(args)
    path = socket_of(args)
    started = time.monotonic()
    end = started + (args.duration if args.duration is not None else math.inf)
    with StopSignals() as signals:
        moving = False
        try:
            with Client(path) as client:
                while time.monotonic() < end and signals.signum is None:
                    reply = client.request(request)
                    if not moving:  # said once the daemon took it, with the caps it says
                        for line in jog_caps(request, reply.get("jog")):
                            say(line)
                        if args.duration is None:
                            say("jog: moving while this runs; Ctrl-C stops")
                    moving = True
                    signals.sleep(DEAD_MAN_PERIOD_S)
        except ApiError:  # the daemon's reason, not that of a stop after it
            if moving:
                with contextlib.suppress(ApiError):
                    call(path, STOP)
            raise
        jogged_s = time.monotonic() - started
        signum = signals.signum
        if signum is not None and (signum != signal.SIGINT or args.duration is not None):
            return _stopped_by_signal(args, "jog", signum, lambda reply, stopped: (
                f"{'stopped' if stopped else 'the daemon is ' + str(reply.get('state'))} "
                f"after {jogged_s:.1f} s; tip at {pose_text(reply)}"))
        if moving:
            call(path, STOP)
        reply = call(path, STATUS)
    print_reply(args, reply, f"jogged {jogged_s:.1f} s; tip at {pose_text(reply)}")
    return 0


def _bar(share: float, width: int = 24) -> str:
    filled = round(max(0.0, min(1.0, share)) * width)
    return "[" + "#" * filled + "-" * (width - filled) + "]"


def progress_line(text: str, tty: bool, finished: bool) -> str:
    """On a terminal: back to the line's start, the text, and clear what a longer line
    left there (a newline only at the end); elsewhere one line each time."""
    if not tty:
        return text + "\n"
    return "\r" + text + CLEAR_TO_END + ("\n" if finished else "")


class _LaneDaemon:
    """The status of the daemon raking the lane, on one connection. A connection lost to
    the same daemon (its pid) is opened again, up to MAX_RESUMES times in a row; a daemon
    lost, silent or restarted raises DaemonUnreachable saying whether the lane can still
    be running."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.pid: Any = None  # the daemon's, from its first status
        self._client: Client | None = None
        self._resumes = 0

    def __enter__(self) -> _LaneDaemon:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def status(self) -> dict[str, Any]:
        try:
            if self._client is None:
                self._client = Client(self.path)
            reply = self._client.request(STATUS)
            self._resumes = 0
        except DaemonUnreachable as lost:
            self.close()
            reply = self._again(lost)
        self.pid = reply.get("pid", self.pid)
        return reply

    def _again(self, lost: DaemonUnreachable) -> dict[str, Any]:
        self._resumes += 1
        try:
            reply = call(self.path, STATUS)
        except DaemonSilent:
            queued = _leave_stop(self.path)
            raise DaemonUnreachable(
                f"excavate: the daemon at {self.path} stopped answering while it raked the "
                "lane: while it is frozen its drives stop on their command watchdog, but the "
                "lane may go on if it resumes" + ("; a stop waits for it there" if queued
                                                  else "") + f"; {CHECK_STATUS}") from lost
        except DaemonUnreachable:
            raise DaemonUnreachable(
                f"excavate: lost the daemon at {self.path} while it raked the lane (the "
                "connection failed and it takes no new one): the lane cannot go on without "
                "it (its drives stop on their command watchdog; a daemon that starts again "
                f"starts disarmed); {CHECK_STATUS}") from lost
        if self.pid is not None and reply.get("pid") != self.pid:
            raise DaemonUnreachable(
                f"excavate: the daemon at {self.path} restarted while it raked the lane (pid "
                f"{self.pid}, now pid {reply.get('pid')}, {reply.get('state')}): the lane is "
                f"not resumed; {CHECK_STATUS}") from lost
        if self._resumes > MAX_RESUMES:
            raise DaemonUnreachable(f"excavate: following the lane, the connection to the "
                                    f"daemon failed {self._resumes} times in a row ({lost})")
        return reply


def _leave_stop(path: Path) -> bool:
    """Send stop to a daemon that does not answer: it carries it out when it reads it (the
    server answers what a closed connection sent). True if it went out."""
    try:
        client = Client(path, STATE_TIMEOUT_S)
    except DaemonUnreachable:
        return False
    with client, contextlib.suppress(ApiError):
        client.request(STOP)
    return True


def follow_excavation(path: Path, out: TextIO, timeout_s: float = 3600.0,
                      signals: StopSignals | None = None) -> dict[str, Any]:
    """Poll until the excavation ends, or a signal came (``signals``; the last status is
    then returned as it is); a progress bar on a terminal, lines elsewhere."""
    tty, last_line, started = out.isatty(), 0.0, time.monotonic()
    sleep = time.sleep if signals is None else signals.sleep
    with _LaneDaemon(path) as daemon:
        while True:
            reply = daemon.status()
            ex = reply.get("excavation") or {}
            finished = reply["state"] != "excavate"
            interrupted = signals is not None and signals.signum is not None
            now = time.monotonic()
            if tty or now - last_line >= 2.0 or finished or interrupted:
                share = ex.get("depth_m", 0.0) / max(ex.get("target_depth_m", 1.0), 1e-9)
                line = f"{_bar(share)} {progress_text(reply)}" if ex else reply["state"]
                with contextlib.suppress(OSError):  # a closed terminal: the lane goes first
                    out.write(progress_line(line, tty, finished or interrupted))
                    out.flush()
                last_line = now
            if finished or interrupted:
                return reply
            if now - started > timeout_s:
                raise TimeoutError(f"excavation still running after {timeout_s:g} s")
            sleep(POLL_S)


# excavate's flags by the API argument each gives
EXCAVATE_FLAGS = {"reach_far_m": "--reach-far", "reach_near_m": "--reach-near",
                  "target_depth_m": "--depth", "depth_step_m": "--step",
                  "stroke_speed_m_per_s": "--speed"}


def check_excavate(request: dict[str, Any]) -> None:
    """The API's bounds on an excavate request, said with the flags that gave each value
    (ConfigError: nothing is sent; the daemon checks them again, naming its arguments)."""
    for arg in COMMANDS[ApiCommand.EXCAVATE].args:
        value = request.get(arg.name)
        problem = arg.bounds.violation(value) if value is not None else None
        if problem:
            raise ConfigError(f"excavate: {EXCAVATE_FLAGS[arg.name]} {problem}")
    if not request["reach_far_m"] > request["reach_near_m"]:
        raise ConfigError(f"excavate: --reach-far must be > --reach-near "
                          f"({request['reach_near_m']:g}), got {request['reach_far_m']:g}")


def excavate(args: argparse.Namespace) -> int:
    """Start the lane and follow it to its end: 0 once it completed or found an object, 1
    otherwise, with one line saying how it ended; SIGINT, SIGTERM and SIGHUP stop it
    (128 + the signal's number)."""
    request: dict[str, Any] = {"cmd": "excavate", "reach_far_m": args.reach_far,
                               "reach_near_m": args.reach_near, "target_depth_m": args.depth}
    if args.step is not None:
        request["depth_step_m"] = args.step
    if args.speed is not None:
        request["stroke_speed_m_per_s"] = args.speed
    check_excavate(request)  # before the daemon is asked
    path = socket_of(args)
    if args.no_wait:
        started = call(path, request)
        number = started.get("lane")
        print_reply(args, started, f"excavate: lane {number} started" if isinstance(number, int)
                    else "excavate: started")
        return 0
    with StopSignals() as signals:  # from before the request: a lane never left unfollowed
        call(path, request)
        reply = follow_excavation(path, sys.stderr, signals=signals)
        if signals.signum is not None:
            return _stopped_by_signal(args, "excavate", signals.signum, _after_stop)
    completed, line = excavation_outcome(reply)
    print_reply(args, reply, line)
    return 0 if completed else 1


def _after_stop(reply: dict[str, Any], stopped: bool) -> str:
    """What the status says after excavate's own stop (``stopped``: carried out)."""
    ex = reply.get("excavation") or {}
    if stopped and reply.get("state") == "hold" and not ex.get("done"):
        return f"lane stopped ({lane_text(reply)}, not finished); tip at {pose_text(reply)}"
    return excavation_outcome(reply)[1].removeprefix("excavate: ") + f"; tip at {pose_text(reply)}"


SIGNALS_HELP = ("SIGTERM and SIGHUP (the terminal closed) stop it too, say where the tip is "
                "and exit 128 + the signal's number (143, 129)")
