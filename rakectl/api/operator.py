"""The operator's commands that do not move the rake (arm, reset, status, dump and the
one-word ones) and the operator's sub-commands (:func:`add_parsers`, with
:mod:`rakectl.api.motion`'s jog and excavate): talk to the running daemon over its socket.

Each prints a short human answer, or with ``--json`` the daemon's reply as
one JSON object on the last line of stdout. Errors are one line (the CLI
chooses the exit status); a bad option value is a ConfigError, said before
anything is sent.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Any

from rakectl.api.client import Client, Refused, call
from rakectl.api.console import (
    POLL_S,
    STATE_TIMEOUT_S,
    STATUS,
    Ops,
    print_reply,
    socket_of,
)
from rakectl.api.motion import SIGNALS_HELP, excavate, jog
from rakectl.api.replies import (
    jog_caps_text,
    lane_identity_text,
    next_step,
    pose_text,
    progress_text,
)
from rakectl.errors import ApiError, CommandRejected

CHECK_TIMEOUT_S = 120.0  # the weight check takes about 3 s, the press up to a minute
CHECKS = (("weight_check", "weight check: lifting the tip and lowering it back"),
          ("mount_check", "tine-mount check: pressing the tines on the anvil"))
RESET_TIMEOUT_S = 2.0  # the daemon gives the drives 1 s to clear
DUMP_TIMEOUT_S = 30.0


def simple(cmd: str) -> Ops:
    """status-less commands: disarm, stop, estop, shutdown."""

    def op(args: argparse.Namespace) -> int:
        reply = call(socket_of(args), {"cmd": cmd})
        state = reply.get("state", "ok")
        print_reply(args, reply, f"{cmd}: the daemon stops the rake, disarms and ends (it was "
                    f"{state})" if reply.get("stopping") else f"{cmd}: {state}")
        return 0

    return op


def with_next_step(op: Ops) -> Ops:
    """``op``, whose refusals end with the next step when the daemon's state calls for one:
    the state from the refusal, else from a status asked at once."""

    def run(args: argparse.Namespace) -> int:
        try:
            return op(args)
        except CommandRejected as refused:
            state = refused.state if isinstance(refused, Refused) else None
            if state is None:
                with contextlib.suppress(ApiError):
                    state = call(socket_of(args), STATUS, STATE_TIMEOUT_S).get("state")
            step = next_step(str(refused), state if isinstance(state, str) else None)
            if not step:
                raise
            raise CommandRejected(f"{refused}; next: {step}") from refused

    return run


def arm(args: argparse.Namespace) -> int:
    """Arm; the first time after start-up, wait for the checks, printing each as it starts
    and its verdict (a check that faults is named in the final line too)."""
    path = socket_of(args)
    reply = call(path, {"cmd": "arm"})
    if reply.get("state") == "checking":
        deadline = time.monotonic() + CHECK_TIMEOUT_S
        started: set[str] = set()
        with Client(path) as client:
            while True:
                reply = client.request(STATUS)
                for name, what in CHECKS:
                    check = reply.get(name) or {}
                    if check.get("message") == "running" and name not in started:
                        started.add(name)
                        print(f"arm: {what}", file=sys.stderr)
                    elif name in started and check.get("passed") is not None:
                        started.discard(name)
                        print(check["message"], file=sys.stderr)
                if reply.get("state") != "checking" or time.monotonic() >= deadline:
                    break
                time.sleep(POLL_S)
    print_reply(args, reply, f"arm: {reply.get('state', 'ok')}"
           + (f" ({reply['fault']})" if reply.get("fault") else ""))
    return 0 if reply.get("state") == "armed" else 1


def reset(args: argparse.Namespace) -> int:
    """Reset, then wait for the daemon's verdict (it fault-resets the drives and leaves
    FAULT or ESTOP only once no drive problem is left, within about 1 s)."""
    path = socket_of(args)
    reply = call(path, {"cmd": "reset"})
    deadline = time.monotonic() + RESET_TIMEOUT_S
    with Client(path) as client:
        while reply.get("state") in ("fault", "estop") and time.monotonic() < deadline:
            time.sleep(POLL_S / 2)
            reply = client.request(STATUS)
    ok = reply.get("state") == "disarmed"
    print_reply(args, reply, f"reset: {reply.get('state')}"
           + ("" if ok else f" ({reply.get('fault') or 'the drives did not clear'})"))
    return 0 if ok else 1


def status(args: argparse.Namespace) -> int:
    reply = call(socket_of(args), STATUS)
    if args.json:
        print(json.dumps(reply))
        return 0
    force, timing = reply["force"], reply.get("timing", {})
    lines = [
        f"state      {reply['state']}" + (f" ({reply['fault']})" if reply.get("fault") else ""),
        f"tip        {pose_text(reply)}",
        f"force      F̂ {force['f_hat_n']:.1f} N (max {force['f_hat_max_n']:.1f} N), clamp "
        f"worst case {force['clamp_worst_case_n']:.1f} N of {force['clamp_limit_n']:.1f} N",
        "drives     " + ", ".join(f"{d['state']}" for d in reply["drives"]),
        f"weight     {reply['weight_check']['message']}",
        f"mount      {reply['mount_check']['message']}",
    ]
    if "latency_ns" in timing:
        lat = timing["latency_ns"]
        lines.append(f"timing     wake-up p50 {lat['p50'] / 1e3:.0f} µs, p99 "
                     f"{lat['p99'] / 1e3:.0f} µs, max {lat['max'] / 1e3:.0f} µs, "
                     f"overruns {timing.get('overruns', 0)}")
    if reply.get("timing_check", "ok") != "ok":
        lines.append(f"arming     {reply['timing_check']}")
    caps = jog_caps_text(reply)
    if caps:
        lines.append(f"jog caps   {caps}")
    if reply.get("excavation"):
        lane = lane_identity_text(reply)
        if lane:
            lines.append(f"lane       {lane.removeprefix('lane ')}")
        lines.append(progress_text(reply))
    print("\n".join(lines))
    return 0


def _file_path(text: str) -> Path:
    """A file's path as given (an empty one read as the current directory before)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path names no file")
    return Path(text)


def dump(args: argparse.Namespace) -> int:
    """Ask for a dump and wait until the daemon has written it (or says it could not)."""
    request: dict[str, Any] = {"cmd": "dump"}
    if args.path:
        request["path"] = str(args.path.absolute())  # the daemon runs elsewhere
    path = socket_of(args)
    reply = call(path, request)
    written, deadline = reply["path"], time.monotonic() + DUMP_TIMEOUT_S
    with Client(path) as client:
        while True:
            dumps = client.request(STATUS).get("dumps", {})
            failed = [f for f in dumps.get("failed", []) if written in f]
            if failed:
                print(f"dump: {failed[-1]}", file=sys.stderr)
                return 1
            if written not in dumps.get("pending", []):
                break
            if time.monotonic() > deadline:
                print(f"dump: {written} still being written after {DUMP_TIMEOUT_S:g} s",
                      file=sys.stderr)
                return 1
            time.sleep(POLL_S / 4)
    print_reply(args, reply, f"dump: {written}")
    return 0


def add_parsers(sub: Any, parent: argparse.ArgumentParser) -> dict[str, Ops]:
    """Sub-commands for the operator; returns their functions by name."""
    ops: dict[str, Ops] = {}
    text = "enable the drives and hold the pose (the first time, after the weight and " \
           "tine-mount checks)"
    sub.add_parser("arm", parents=[parent], help=text, description=f"Arm: {text}; exit "
                   "status 1 if a check faults.")
    ops["arm"] = with_next_step(arm)
    text = "clear a fault or e-stop once its cause is gone (exit status 1 if it stays)"
    sub.add_parser("reset", parents=[parent], help=text, description=f"Reset: {text}; then "
                   "rakectl arm.")
    ops["reset"] = reset
    for name, help_text, description in (
            ("disarm", "stop and disable the drives", "Disarm: stop any motion and disable "
             "the drives (0 V)."),
            ("stop", "stop jogging or excavating, hold the pose", "Stop the jog or the lane "
             "and hold the pose; the drives stay enabled."),
            ("estop", "emergency stop (latched until reset)", "Emergency stop: quick-stop both "
             "drives now; latched until rakectl reset."),
            ("shutdown", "end the daemon (tests, bench set-ups)", "End the daemon (tests and "
             "bench set-ups; under systemd: systemctl stop rakectl).")):
        sub.add_parser(name, parents=[parent], help=help_text, description=description)
        ops[name] = simple(name)
    sub.add_parser("status", parents=[parent], help="state, pose, forces, timing",
                   description="The daemon's state, the tip's pose, the forces, the loop's "
                   "timing, the fastest it jogs, and the lane in progress, with its number "
                   "since the daemon started (changes nothing).")
    ops["status"] = status
    p = sub.add_parser("dump", parents=[parent], help="write the flight recorder to a file",
                       description="Write the flight recorder's last seconds to a file on "
                       "the daemon's machine and wait until it is written.")
    p.add_argument("--path", type=_file_path, help="file on the daemon's machine")
    ops["dump"] = dump
    p = sub.add_parser("jog", parents=[parent], help="move while this command runs (dead-man)",
                       description="Move the tip (task space) or the joints (joint space) "
                       "while this command runs: the daemon stops when its requests stop "
                       "(dead-man). Without --duration, Ctrl-C ends it (exit status 0); "
                       "with it, Ctrl-C before the end stops it and exits 130. "
                       f"{SIGNALS_HELP}.")
    p.add_argument("--space", choices=("task", "joint"), default="task")
    p.add_argument("--reach", type=float, default=0.0, help="tip m/s, + away from the robot")
    p.add_argument("--height", type=float, default=0.0, help="tip m/s, + up")
    p.add_argument("--r", type=float, default=0.0, help="joint r m/s (joint space)")
    p.add_argument("--theta", type=float, default=0.0, help="joint θ rad/s, + lowers the rake")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds to keep moving (default: until Ctrl-C)")
    ops["jog"] = with_next_step(jog)
    p = sub.add_parser("excavate", parents=[parent], help=(
        "rake a lane deeper and deeper (exit status 0 once it holds at the target depth, at "
        "the descent limit or at an object found; 1 when it ends otherwise)"),
        description="Rake a lane deeper each cycle and follow it to its end. Exit status 0 "
        "once it holds at the target depth, at the descent limit or at an object found; "
        "1, with a line saying how, when it ends otherwise: stopped (rakectl stop), by the "
        "force limit, a fault or an e-stop; 3 if the daemon is lost. Ctrl-C stops the lane "
        f"and exits 130; {SIGNALS_HELP}.")
    p.add_argument("--reach-far", type=float, required=True, help="stroke start, m")
    p.add_argument("--reach-near", type=float, required=True, help="stroke end, m")
    p.add_argument("--depth", type=float, required=True, help="target depth, m")
    p.add_argument("--step", type=float, help="depth added per cycle, m")
    p.add_argument("--speed", type=float, help="stroke speed, m/s")
    p.add_argument("--no-wait", action="store_true", help="return once started (the lane is "
                   "then not followed, nor stopped on a signal)")
    ops["excavate"] = with_next_step(excavate)
    return ops
