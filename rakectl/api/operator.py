"""The operator's commands: talk to the running daemon over its socket.

Each prints a short human answer, or with ``--json`` the daemon's reply as
one JSON object on the last line of stdout. Errors are one line (the CLI
chooses the exit status).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from rakectl.api.client import Client, call, socket_path
from rakectl.api.schema import COMMANDS, DEAD_MAN_PERIOD_S, ApiCommand
from rakectl.errors import ApiError

POLL_S = 0.2
CLEAR_TO_END = "\x1b[K"  # ANSI: erase from the cursor to the end of the line
CHECK_TIMEOUT_S = 120.0  # the weight check takes about 3 s, the press up to a minute
CHECKS = (("weight_check", "weight check: lifting the tip and lowering it back"),
          ("mount_check", "tine-mount check: pressing the tines on the anvil"))
RESET_TIMEOUT_S = 2.0  # the daemon gives the drives 1 s to clear
DUMP_TIMEOUT_S = 30.0
MAX_JOG_S = 600.0  # a dump is written in the loop's slack, a few hundred ms
Ops = Callable[[argparse.Namespace], int]


def _path(args: argparse.Namespace) -> Path:
    return socket_path(args.socket)


def _print(args: argparse.Namespace, reply: dict[str, Any], text: str) -> None:
    print(json.dumps(reply) if args.json else text)


def simple(cmd: str) -> Ops:
    """status-less commands: disarm, stop, estop, shutdown."""

    def op(args: argparse.Namespace) -> int:
        reply = call(_path(args), {"cmd": cmd})
        _print(args, reply, f"{cmd}: {reply.get('state', 'ok')}")
        return 0

    return op


def arm(args: argparse.Namespace) -> int:
    """Arm; the first time after start-up, wait for the checks, printing each as it starts
    and its verdict (a check that faults is named in the final line too)."""
    path = _path(args)
    reply = call(path, {"cmd": "arm"})
    if reply.get("state") == "checking":
        deadline = time.monotonic() + CHECK_TIMEOUT_S
        started: set[str] = set()
        with Client(path) as client:
            while True:
                reply = client.request({"cmd": "status"})
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
    _print(args, reply, f"arm: {reply.get('state', 'ok')}"
           + (f" ({reply['fault']})" if reply.get("fault") else ""))
    return 0 if reply.get("state") == "armed" else 1


def reset(args: argparse.Namespace) -> int:
    """Reset, then wait for the daemon's verdict (it fault-resets the drives and leaves
    FAULT or ESTOP only once no drive problem is left, within about 1 s)."""
    path = _path(args)
    reply = call(path, {"cmd": "reset"})
    deadline = time.monotonic() + RESET_TIMEOUT_S
    with Client(path) as client:
        while reply.get("state") in ("fault", "estop") and time.monotonic() < deadline:
            time.sleep(POLL_S / 2)
            reply = client.request({"cmd": "status"})
    ok = reply.get("state") == "disarmed"
    _print(args, reply, f"reset: {reply.get('state')}"
           + ("" if ok else f" ({reply.get('fault') or 'the drives did not clear'})"))
    return 0 if ok else 1


def status(args: argparse.Namespace) -> int:
    reply = call(_path(args), {"cmd": "status"})
    if args.json:
        print(json.dumps(reply))
        return 0
    tip, force, timing = reply["tip"], reply["force"], reply.get("timing", {})
    lines = [
        f"state      {reply['state']}" + (f" ({reply['fault']})" if reply.get("fault") else ""),
        f"tip        reach {tip['reach_m']:.3f} m, depth {1e3 * tip['depth_m']:.1f} mm",
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
    if reply.get("excavation"):
        lines.append(_progress_text(reply))
    print("\n".join(lines))
    return 0


def dump(args: argparse.Namespace) -> int:
    """Ask for a dump and wait until the daemon has written it (or says it could not)."""
    request: dict[str, Any] = {"cmd": "dump"}
    if args.path:
        request["path"] = str(args.path.absolute())  # the daemon runs elsewhere
    path = _path(args)
    reply = call(path, request)
    written, deadline = reply["path"], time.monotonic() + DUMP_TIMEOUT_S
    with Client(path) as client:
        while True:
            dumps = client.request({"cmd": "status"}).get("dumps", {})
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
    _print(args, reply, f"dump: {written}")
    return 0


def jog(args: argparse.Namespace) -> int:
    """Send the jog every 0.1 s (the daemon's dead-man) while this command runs: for
    ``--duration`` seconds, or until Ctrl-C without it; then stop."""
    speeds = {"--reach": args.reach, "--height": args.height, "--r": args.r,
              "--theta": args.theta}
    for flag, value in speeds.items():
        if not math.isfinite(value):
            raise ApiError(f"jog: {flag} must be a finite speed, got {value}")
    other = ("--r", "--theta") if args.space == "task" else ("--reach", "--height")
    given = [flag for flag in other if speeds[flag]]
    if given:
        raise ApiError(f"jog: {' and '.join(given)} {'does' if len(given) == 1 else 'do'} "
                       f"not apply in {args.space} space "
                       f"(task: --reach/--height; joint: --r/--theta)")
    if args.duration is not None and not 0.0 < args.duration <= MAX_JOG_S:
        raise ApiError(f"jog: --duration must be in (0, {MAX_JOG_S:g}] s, got {args.duration}")
    if args.space == "task":
        request = {"cmd": "jog", "space": "task", "reach_m_per_s": args.reach,
                   "height_m_per_s": args.height}
    else:
        request = {"cmd": "jog", "space": "joint", "r_m_per_s": args.r,
                   "theta_rad_per_s": args.theta}
    started = time.monotonic()
    end = started + (args.duration if args.duration is not None else math.inf)
    with Client(_path(args)) as client:
        moving, refused = False, None
        try:
            while time.monotonic() < end:
                client.request(request)
                if not moving and args.duration is None:  # said once the daemon took it
                    print("jog: moving while this runs; Ctrl-C stops", file=sys.stderr)
                moving = True
                time.sleep(DEAD_MAN_PERIOD_S)
        except KeyboardInterrupt:
            pass
        except ApiError as error:  # the daemon's reason, not that of a stop after it
            refused = error
        if moving:
            try:
                client.request({"cmd": "stop"})
            except ApiError:
                if refused is None:
                    raise
        if refused is not None:
            raise refused
        reply = client.request({"cmd": "status"})
    _print(args, reply, f"jogged {time.monotonic() - started:.1f} s; tip at reach "
           f"{reply['tip']['reach_m']:.3f} m, depth {1e3 * reply['tip']['depth_m']:.1f} mm")
    return 0


def _progress_text(reply: dict[str, Any]) -> str:
    ex = reply["excavation"]
    found = ex.get("object_found")
    text = (f"excavate   cycle {ex['cycle']}, depth {1e3 * ex['depth_m']:.0f}/"
            f"{1e3 * ex['target_depth_m']:.0f} mm, {ex['phase']}, "
            f"F̂ max {reply['force']['f_hat_max_n']:.1f} N")
    if found:
        text += (f", OBJECT FOUND at reach {found['reach_m']:.3f} m, depth "
                 f"{1e3 * found['depth_m']:.0f} mm")
    elif ex.get("stopped_by_force"):
        text += ", STOPPED BY THE FORCE LIMIT (lane not finished)"
    return text


def _bar(share: float, width: int = 24) -> str:
    filled = round(max(0.0, min(1.0, share)) * width)
    return "[" + "#" * filled + "-" * (width - filled) + "]"


def progress_line(text: str, tty: bool, finished: bool) -> str:
    """On a terminal: back to the line's start, the text, and clear what a longer line
    left there (a newline only at the end); elsewhere one line each time."""
    if not tty:
        return text + "\n"
    return "\r" + text + CLEAR_TO_END + ("\n" if finished else "")


def follow_excavation(path: Path, out: TextIO, timeout_s: float = 3600.0) -> dict[str, Any]:
    """Poll until the excavation ends; a progress bar on a terminal, lines elsewhere."""
    tty, last_line, started = out.isatty(), 0.0, time.monotonic()
    with Client(path) as client:
        while True:
            reply = client.request({"cmd": "status"})
            ex = reply.get("excavation") or {}
            finished = reply["state"] != "excavate"
            now = time.monotonic()
            if tty or now - last_line >= 2.0 or finished:
                share = ex.get("depth_m", 0.0) / max(ex.get("target_depth_m", 1.0), 1e-9)
                line = f"{_bar(share)} {_progress_text(reply)}" if ex else reply["state"]
                out.write(progress_line(line, tty, finished))
                out.flush()
                last_line = now
            if finished:
                return reply
            if now - started > timeout_s:
                raise TimeoutError(f"excavation still running after {timeout_s:g} s")
            time.sleep(POLL_S)


# excavate's flags by the API argument each gives
EXCAVATE_FLAGS = {"reach_far_m": "--reach-far", "reach_near_m": "--reach-near",
                  "target_depth_m": "--depth", "depth_step_m": "--step",
                  "stroke_speed_m_per_s": "--speed"}


def check_excavate(request: dict[str, Any]) -> None:
    """The API's bounds on an excavate request, said with the flags that gave each value
    (the daemon checks them again, naming its arguments)."""
    for arg in COMMANDS[ApiCommand.EXCAVATE].args:
        value = request.get(arg.name)
        problem = arg.bounds.violation(value) if value is not None else None
        if problem:
            raise ApiError(f"excavate: {EXCAVATE_FLAGS[arg.name]} {problem}")
    if not request["reach_far_m"] > request["reach_near_m"]:
        raise ApiError(f"excavate: --reach-far must be > --reach-near "
                       f"({request['reach_near_m']:g}), got {request['reach_far_m']:g}")


def excavate(args: argparse.Namespace) -> int:
    request: dict[str, Any] = {"cmd": "excavate", "reach_far_m": args.reach_far,
                               "reach_near_m": args.reach_near, "target_depth_m": args.depth}
    if args.step is not None:
        request["depth_step_m"] = args.step
    if args.speed is not None:
        request["stroke_speed_m_per_s"] = args.speed
    check_excavate(request)  # before the daemon is asked
    call(_path(args), request)
    if args.no_wait:
        print("excavate: started")
        return 0
    reply = follow_excavation(_path(args), sys.stderr)
    excavation = reply.get("excavation") or {}
    _print(args, reply, _progress_text(reply) if excavation else reply["state"])
    return 0 if reply["state"] == "hold" and not excavation.get("stopped_by_force") else 1


def add_parsers(sub: Any, parent: argparse.ArgumentParser) -> dict[str, Ops]:
    """Sub-commands for the operator; returns their functions by name."""
    ops: dict[str, Ops] = {}
    sub.add_parser("arm", parents=[parent], help="enable the drives and hold the pose (the "
                   "first time, after the weight and tine-mount checks)")
    ops["arm"] = arm
    sub.add_parser("reset", parents=[parent], help="clear a fault or e-stop once its cause "
                   "is gone (exit status 1 if it stays)")
    ops["reset"] = reset
    for name, help_text in (("disarm", "stop and disable the drives"),
                            ("stop", "stop jogging or excavating, hold the pose"),
                            ("estop", "emergency stop (latched until reset)"),
                            ("shutdown", "end the daemon (tests, bench set-ups)")):
        sub.add_parser(name, parents=[parent], help=help_text)
        ops[name] = simple(name)
    sub.add_parser("status", parents=[parent], help="state, pose, forces, timing")
    ops["status"] = status
    p = sub.add_parser("dump", parents=[parent], help="write the flight recorder to a file")
    p.add_argument("--path", type=Path, help="file on the daemon's machine")
    ops["dump"] = dump
    p = sub.add_parser("jog", parents=[parent], help="move while this command runs (dead-man)")
    p.add_argument("--space", choices=("task", "joint"), default="task")
    p.add_argument("--reach", type=float, default=0.0, help="tip m/s, + away from the robot")
    p.add_argument("--height", type=float, default=0.0, help="tip m/s, + up")
    p.add_argument("--r", type=float, default=0.0, help="joint r m/s (joint space)")
    p.add_argument("--theta", type=float, default=0.0, help="joint θ rad/s, + lowers the rake")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds to keep moving (default: until Ctrl-C)")
    ops["jog"] = jog
    p = sub.add_parser("excavate", parents=[parent], help=(
        "rake a lane deeper and deeper (exit status 0 once it holds at the target depth or "
        "at an object found; 1 on a force-limit stop, fault or e-stop)"))
    p.add_argument("--reach-far", type=float, required=True, help="stroke start, m")
    p.add_argument("--reach-near", type=float, required=True, help="stroke end, m")
    p.add_argument("--depth", type=float, required=True, help="target depth, m")
    p.add_argument("--step", type=float, help="depth added per cycle, m")
    p.add_argument("--speed", type=float, help="stroke speed, m/s")
    p.add_argument("--no-wait", action="store_true", help="return once started")
    ops["excavate"] = excavate
    return ops
