"""What each command of the API does to the running daemon (runs in the loop's slack).

A request the state table does not allow, or that cannot be carried out, is refused with
one sentence naming why; nothing changes then. With a bus trace, each :data:`CHANGING`
request carried out goes to the trace's inputs (rakectl.daemon.inputs) at its effective tick.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from rakectl.api.schema import COMMANDS, ApiCommand, JogSpace, Request
from rakectl.config.service import RtModeSetting
from rakectl.config.settings import held_command_gap
from rakectl.core import kinematics
from rakectl.core.jog import Jog, JogFrame
from rakectl.core.lane import LanePlanner
from rakectl.daemon.loop import Daemon
from rakectl.daemon.recorder import DumpError
from rakectl.daemon.states import ARMED_STATES, DaemonState, Event, next_state
from rakectl.daemon.timing import timing_verdict
from rakectl.errors import CommandRejected, ConfigError, KinematicsError

Reply = Mapping[str, Any]
# a lane's parameters as status says them: those an excavate request gives (the configured
# lane's where it leaves one out), and whether its strokes are force-adaptive
LANE_FIELDS = (*(arg.name for arg in COMMANDS[ApiCommand.EXCAVATE].args), "adaptive")
MAX_PENDING_DUMPS = 4  # operator dumps waiting for the slack (about 0.7 MB of memory each)

# The commands that change what the loop sends; a replay applies them again. The others
# read (status), write files (dump) or reset the timing statistics (timing_reset), which
# only the wall-clock checks before arming read.
CHANGING = frozenset({ApiCommand.ARM, ApiCommand.DISARM, ApiCommand.STOP, ApiCommand.ESTOP,
                      ApiCommand.RESET, ApiCommand.JOG, ApiCommand.EXCAVATE,
                      ApiCommand.SHUTDOWN})


# What the operator does next, where a state refuses a command (the states' own words).
_NEXT_STEP = {DaemonState.ESTOP: "reset clears it, then arm",
              DaemonState.FAULT: "reset clears it once its cause is gone, then arm",
              DaemonState.DISARMED: "arm first",
              DaemonState.CHECKING: "the checks before arming are running",
              DaemonState.INIT: "the drives are being brought up",
              DaemonState.JOG: "stop first", DaemonState.EXCAVATE: "stop first",
              DaemonState.ARMED: "it is armed", DaemonState.HOLD: "it is armed, holding"}


def _require(daemon: Daemon, event: Event, what: str) -> None:
    if next_state(daemon.state, event) is None:
        step: str | None
        if event is Event.RESET:
            step = "nothing to reset: a reset clears a fault or an e-stop"
        elif daemon.state is DaemonState.DISARMED and event in (Event.DISARM, Event.STOP):
            step = "nothing moves: the drives are disabled"
        else:
            step = _NEXT_STEP.get(daemon.state)
        raise CommandRejected(f"cannot {what} while {daemon.state.name.lower()}"
                              + (f" ({daemon.fault_reason})" if daemon.fault_reason else "")
                              + (f": {step}" if step else ""))


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _checks(daemon: Daemon) -> tuple[dict[str, Any], dict[str, Any]]:
    """The checks before arming: running (this arming's), the last verdict, or why none."""
    selftest, checks = daemon.settings.selftest, daemon.checks
    weight, mount = checks.weight_result, checks.mount_result
    if checks.weight_check is not None:
        weight_reply: dict[str, Any] = {"passed": None, "message": "running"}
    elif weight is not None:
        weight_reply = {"passed": weight.passed, "weight_n": _finite(weight.weight_n),
                        "expected_n": weight.expected_n, "message": weight.message}
    else:
        weight_reply = {"passed": None, "message": _not_run(checks.interrupted)
                        if selftest.enabled else "disabled (selftest.enabled: false)"}
    if checks.mount_check is not None:
        mount_reply: dict[str, Any] = {"passed": None, "message": "running" if
                                       checks.weight_check is None else "after the weight check"}
    elif mount is not None:
        down, side = mount.down, mount.side
        mount_reply = {"passed": mount.passed,
                       "stiffness_n_per_m": _finite(down.stiffness_n_per_m),
                       "expected_n_per_m": down.expected_n_per_m, "at_least": down.at_least,
                       "side_stiffness_n_per_m": _finite(side.stiffness_n_per_m),
                       "side_expected_n_per_m": side.expected_n_per_m,
                       "side_at_least": side.at_least, "ratio": _finite(mount.ratio),
                       "message": mount.message}
    else:
        mount_reply = {"passed": None, "message": _not_run(checks.interrupted)
                       if selftest.enabled and selftest.press
                       else "disabled (selftest.press: false)" if selftest.enabled
                       else "disabled (selftest.enabled: false)"}
    return weight_reply, mount_reply


def _not_run(interrupted: str) -> str:
    """A check without a verdict, not running: interrupted (naming why), or not run yet."""
    return (f"interrupted ({interrupted}): runs at the next arming" if interrupted
            else "not run")


def _tip(daemon: Daemon) -> dict[str, float | None]:
    """The tip's pose, and the highest the tines may stand above ground level 0 (the tip
    plus the mount's compression: what a survey mark takes, rakectl.api.survey)."""
    fb = daemon.client.feedback
    if not (math.isfinite(fb.r_m) and math.isfinite(fb.theta_rad)):
        return {"reach_m": None, "depth_m": None, "tines_height_max_m": None}
    reach_m, depth_m = daemon.tip_now()
    lift_m = daemon.controller.tines_lift_m(daemon.supervisor.f_current_n)
    return {"reach_m": reach_m, "depth_m": depth_m,
            "tines_height_max_m": _finite(lift_m - depth_m)}  # the pose stands without it


def _jog_caps(daemon: Daemon) -> dict[str, float]:
    """The fastest each jog moves (jog.*): a faster request is accepted and moved at it."""
    jog = daemon.settings.jog
    return {"max_tip_speed_m_per_s": jog.max_tip_speed_m_per_s,
            "max_r_speed_m_per_s": jog.max_r_speed_m_per_s,
            "max_theta_speed_rad_per_s": jog.max_theta_speed_rad_per_s}


def _excavation(daemon: Daemon, planner: LanePlanner) -> dict[str, Any]:
    """The lane's progress, and which lane it is: its number among the excavate requests
    carried out since start-up, and its parameters."""
    lane = planner.lane
    return {
        "lane": {"number": daemon.lanes_started,
                 **{name: getattr(lane, name) for name in LANE_FIELDS}},
        "phase": planner.phase.name.lower(), "cycle": planner.cycle,
        "depth_m": planner.floor_m, "target_depth_m": lane.target_depth_m,
        "done": planner.done, "stopped_by_force": planner.stopped_by_force,
        "held_by_descent": planner.held_by_descent,
        "object_found": ({"reach_m": planner.found_at[0], "depth_m": planner.found_at[1]}
                         if planner.found_at else None),
    }


def status(daemon: Daemon) -> dict[str, Any]:
    fb, c, client = daemon.client.feedback, daemon.controller, daemon.client
    timing = daemon.timing.summary()
    reply: dict[str, Any] = {
        "state": daemon.state.name.lower(),
        "fault": daemon.fault_reason or None,
        "pid": os.getpid(),
        "ticks": daemon.ticks,
        "joints": {"r_m": _finite(fb.r_m), "theta_rad": _finite(fb.theta_rad),
                   "current_r_a": _finite(fb.current_r_a),
                   "current_theta_a": _finite(fb.current_theta_a)},
        "tip": _tip(daemon),
        "force": {"f_hat_n": c.f_hat_n, "f_hat_max_n": daemon.f_hat_max_n,
                  "f_current_n": daemon.supervisor.f_current_n,
                  "level": daemon.supervisor.level.name.lower(),
                  "clamp_worst_case_n": c.clamp.worst_case_n,
                  "clamp_budget_n": _finite(c.clamp.budget_n),
                  "clamp_limit_n": c.clamp.limit_n, "clamped_ticks": c.clamp.clamped},
        "voltages": {"requested_r_v": c.requested_v[0], "requested_theta_v": c.requested_v[1],
                     "applied_r_v": daemon.voltages[0], "applied_theta_v": daemon.voltages[1]},
        "drives": [{"state": s.name.lower() if s is not None else None,
                    "stale_cycles": fb.stale_cycles[j]} for j, s in enumerate(fb.state)],
        "bus": client.stats.as_dict(),
        "timing": timing,
        "timing_check": _timing_status(daemon, timing),
        "timing_reference": daemon.timing_reference,
        "dumps": {"pending": daemon.pending_dumps(), "failed": list(daemon.dump_failures)},
        "jog": _jog_caps(daemon),
    }
    reply["weight_check"], reply["mount_check"] = _checks(daemon)
    if daemon.planner is not None:
        reply["excavation"] = _excavation(daemon, daemon.planner)
    return reply


def _jog(daemon: Daemon, request: Request) -> Reply:
    """A jog belongs to the connection that started it: its requests keep it going, and
    another connection's are refused while that one stays open (a client that opens a
    connection per request hands its jog on to its next one); once it has ended (a stop,
    the force limit, the dead-man) its connection's next requests are refused, naming
    why, instead of starting it again: a new connection starts a new jog. Requests not
    from a socket (client 0) are one caller."""
    if daemon.state is DaemonState.JOG:
        if request.client != daemon.jog_client:
            if daemon.connected(daemon.jog_client):
                raise CommandRejected("cannot jog: another client is jogging (its jog ends "
                                      "when its requests stop, or with stop)")
            daemon.jog_client = request.client
    else:
        _require(daemon, Event.JOG, "jog")
        ended = daemon.jog_ended.get(request.client) if request.client else None
        if ended is not None:  # every connection whose jog ended, not only the last one
            raise CommandRejected(f"this jog has ended ({ended}): start a new jog, on a new "
                                  "connection, to move again")
        r_m, theta_rad = _jog_start(daemon)
        daemon.jog = Jog(daemon.settings.jog, daemon.workspace, daemon.dt_s, r_m, theta_rad)
        daemon.jog_client = request.client
        daemon.jog_ended = {client: why for client, why in daemon.jog_ended.items()
                            if daemon.connected(client)}  # closed ones never ask again
        daemon.planner, daemon.f_hat_max_n = None, 0.0  # status: the jog's, not a lane's
        daemon._transition(Event.JOG, "operator jog")
    assert daemon.jog is not None
    if request.args.get("space") == JogSpace.TASK:
        daemon.jog.command(JogFrame.TASK, request.number("reach_m_per_s") or 0.0,
                           request.number("height_m_per_s") or 0.0)
    else:
        daemon.jog.command(JogFrame.JOINT, request.number("r_m_per_s") or 0.0,
                           request.number("theta_rad_per_s") or 0.0)
    return {"state": daemon.state.name.lower(), "jog": _jog_caps(daemon)}


def _jog_start(daemon: Daemon) -> tuple[float, float]:
    """Where a new jog's reference starts, in joint space: the tip reference held
    (``hold``: a back-off's, from its own tick), before the impedance's offset (the
    joints' reference has it, and the controller adds it again to the jog's), and no
    deeper than the descent limiter let the joints' reference go (a jog held at the
    floor leaves its reference below it, which a jog started there cannot leave: each
    step sideways would lag the tip more). One the joints cannot reach (held as
    unreachable) starts the jog where the joints' reference is."""
    c = daemon.controller
    reach_m, depth_m = daemon.hold
    depth_m = min(depth_m, c.x_ref_m - c.impedance.filter.x_c_m)
    try:
        return kinematics.inverse(daemon.workspace, reach_m, -depth_m)
    except KinematicsError:
        return daemon.controller.servo.q_ref


def _excavate(daemon: Daemon, request: Request) -> Reply:
    _require(daemon, Event.EXCAVATE, "excavate")
    given: dict[str, Any] = {k: v for k, v in request.args.items() if isinstance(v, float)}
    base = daemon.settings.lane
    for name, top in (("depth_step_m", base.max_depth_step_m),
                      ("stroke_speed_m_per_s", base.max_stroke_speed_m_per_s)):
        if base.adaptive and given.get(name, 0.0) > top:  # the lane would cap it unsaid
            raise CommandRejected(f"cannot excavate: {name} {given[name]:g} is above this "
                                  f"adaptive lane's largest, {top:g} (lane.max_{name})")
    try:
        lane = dataclasses.replace(base, **given)
    except ConfigError as error:  # the lane's own cross-checks
        raise CommandRejected(f"cannot excavate: {error}") from None
    ws = daemon.workspace
    for reach, depth in ((lane.reach_far_m, -lane.clearance_m),
                         (lane.reach_near_m, lane.target_depth_m),
                         (lane.reach_far_m, lane.target_depth_m),
                         (lane.reach_near_m, -lane.clearance_m)):
        try:
            kinematics.inverse(ws, reach, -depth)
        except KinematicsError as exc:
            raise CommandRejected(f"the lane leaves the workspace: {exc}") from None
    c = daemon.controller
    daemon.planner = LanePlanner(lane, daemon.dt_s, c.reach_m, c.depth_m,
                                 None if c.descent is None else c.descent.limit_at_m)
    daemon.lanes_started += 1  # the new lane's number (status: excavation.lane.number)
    daemon.f_hat_max_n = 0.0
    daemon._transition(Event.EXCAVATE, "operator excavate")
    return {"state": daemon.state.name.lower(), "lane": daemon.lanes_started}


def _dump(daemon: Daemon, request: Request) -> Reply:
    """Start a dump; the reply names the file, written in the slack (``status`` lists it
    under ``dumps.pending`` until it is complete). A path that cannot be written is
    refused here, before anything is queued."""
    if len(daemon.pending_dumps()) >= MAX_PENDING_DUMPS:  # each holds a snapshot in memory
        raise CommandRejected(f"cannot dump: {MAX_PENDING_DUMPS} dumps are still being "
                              "written (status: dumps.pending); ask again when they are done")
    given = request.text("path")
    if not given:
        return {"path": str(daemon._dump("request")), "pending": True}
    path = Path(given)
    if not path.is_absolute():
        raise CommandRejected(f"dump path must be absolute (the daemon's working directory "
                              f"is not the client's), got {given!r}")
    problem = _dump_path_problem(path)
    if problem:
        raise CommandRejected(f"cannot dump to {given!r}: {problem}")
    try:
        daemon.dump_to(path, open_now=True)
    except DumpError as error:
        raise CommandRejected(f"cannot dump: {error}") from None
    return {"path": str(path), "pending": True}


def _dump_path_problem(path: Path) -> str | None:
    """Why ``path`` cannot take a new dump, or None: a dump never replaces a file (the
    daemon's own socket among them) and needs a file name in a directory that exists."""
    try:
        os.fsencode(path)
    except UnicodeEncodeError:
        return "the path cannot be encoded as a file name"
    if path.name in ("", ".", ".."):
        return "it names a directory, not a file"
    if os.path.lexists(path):  # a dangling link too
        return "a file is already there (a dump never replaces one)"
    if not path.parent.is_dir():
        return f"no directory {str(path.parent)!r}"
    return None


def _timing_verdict(daemon: Daemon, summary: dict[str, Any] | None = None) -> str:
    """The loop's timing verdict; advice to arm again only where it refuses an arming
    (rt_mode enforce)."""
    s = daemon.settings
    summary = daemon.timing.summary() if summary is None else summary
    reference = daemon.timing_reference.get("p99_us")
    return timing_verdict(summary, daemon.ticks, s.rate_hz, s.daemon,
                          reference if isinstance(reference, float) else None,
                          advise=s.daemon.rt_mode is RtModeSetting.ENFORCE)


def _timing_status(daemon: Daemon, summary: dict[str, Any]) -> str:
    """The timing verdict as status gives it: "ok", what refuses an arming under rt_mode
    enforce, or, under another rt_mode, that verdict as the warning it is there."""
    verdict, mode = _timing_verdict(daemon, summary), daemon.settings.daemon.rt_mode
    if not verdict or mode is RtModeSetting.ENFORCE:
        return verdict or "ok"
    return f"a warning only, an arming goes on (daemon.rt_mode: {mode.value}): {verdict}"


def _check_before_arming(daemon: Daemon, timing_checked: bool) -> None:
    """What rt_mode enforce (the robot) requires before arming, each a verdict ("" when
    met): the loop's timing since start-up (unless not ``timing_checked``), and a clamp
    that carries the command the drives hold after the controller falls silent. Enforced,
    the first unmet one refuses the arming; otherwise each is logged as a warning."""
    if next_state(daemon.state, Event.ARM) is None:
        return  # refused below, naming the state
    enforce = daemon.settings.daemon.rt_mode is RtModeSetting.ENFORCE
    timing = _timing_verdict(daemon) if timing_checked else ""
    for warning, verdict in (("timing_warning", timing),
                             ("clamp_warning", held_command_gap(daemon.settings))):
        if not verdict:
            continue
        if enforce:
            daemon.event("arm_refused", reason=verdict)
            raise CommandRejected(f"cannot arm: {verdict} (daemon.rt_mode: enforce)")
        daemon.event(warning, reason=verdict)


def _simple(daemon: Daemon, event: Event, what: str, action: Callable[[], None]) -> Reply:
    _require(daemon, event, what)
    action()
    return {"state": daemon.state.name.lower()}


def make_handler(daemon: Daemon, timing_checked: bool = True) -> Callable[[Request], Reply]:
    """The API's handler: validated requests in, reply fields out (CommandRejected refuses).

    ``timing_checked`` False leaves out the check of the loop's measured timing before
    arming: a replay applies an arming its run carried out, on timing it cannot measure.
    """

    def handle(request: Request) -> Reply:
        reply = dispatch(request)
        if daemon.inputs is not None and request.cmd in CHANGING:
            daemon.inputs.command(daemon.ticks, request)
        return reply

    def dispatch(request: Request) -> Reply:
        cmd = request.cmd
        if cmd is ApiCommand.STATUS:
            return status(daemon)
        if cmd is ApiCommand.ARM:
            if daemon.client.stale_feedback(daemon.settings.drives.feedback_timeout_cycles):
                raise CommandRejected("cannot arm: the drives' feedback is stale")
            implausible = daemon.implausible_feedback()
            if implausible and next_state(daemon.state, Event.ARM) is not None:
                raise CommandRejected(f"cannot arm: {implausible}")
            _check_before_arming(daemon, timing_checked)
            return _simple(daemon, Event.ARM, "arm", daemon.arm)
        if cmd is ApiCommand.DISARM:
            return _simple(daemon, Event.DISARM, "disarm", daemon.disarm)
        if cmd is ApiCommand.STOP:
            return _simple(daemon, Event.STOP, "stop", daemon.hold_here)
        if cmd is ApiCommand.ESTOP:
            daemon.estop()
            return {"state": daemon.state.name.lower()}
        if cmd is ApiCommand.RESET:
            return _simple(daemon, Event.RESET, "reset", daemon.start_reset)
        if cmd is ApiCommand.DUMP:
            return _dump(daemon, request)
        if cmd is ApiCommand.JOG:
            return _jog(daemon, request)
        if cmd is ApiCommand.EXCAVATE:
            return _excavate(daemon, request)
        if cmd is ApiCommand.TIMING_RESET:
            daemon.timing.reset()
            return {"state": daemon.state.name.lower()}
        if cmd is ApiCommand.SHUTDOWN:
            daemon.request_stop()
            return {"state": daemon.state.name.lower(), "stopping": True}
        raise CommandRejected(f"{cmd} is not implemented")  # pragma: no cover

    return handle


__all__ = ["ARMED_STATES", "CHANGING", "make_handler", "status"]
