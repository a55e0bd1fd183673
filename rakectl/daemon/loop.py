"""The 1 kHz control daemon: one thread, a fixed step, the drives and the operator.

Each tick, on an absolute deadline (rakectl.daemon.timing)::

    receive the drives' TPDOs ─▶ supervise ─▶ reference (hold, jog, lane) ─▶
    TipController (impedance, IK, joint loops, CLAMP) ─▶ RPDOs + SYNC ─▶ recorder

Only this thread touches the bus. What is not the tick (the command socket, dumps,
bus traces, log lines, systemd's watchdog) runs in the tick's slack with a hard time
budget, so it can delay nothing but itself.

Every voltage that reaches the bus comes from ``TipController.step``, whose last stage
is the voltage clamp; outside the armed states the loop sends 0 V with the drives
disabled. Any fault (a drive's EMCY or FAULT state, stale feedback, lost heartbeats,
failed sends, a non-finite number, a clamp that cannot meet its bound, a streak of late
ticks) sends 0 V from its tick on, disables the drives, dumps the recorder and latches
FAULT until ``reset`` finds the cause gone. A dead controller leaves the arm to the
drives' own command watchdogs.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import structlog

from rakectl.config.settings import Settings
from rakectl.core.control import TipController
from rakectl.core.descent import drag_limit_n
from rakectl.core.ground_map import DescentLimiter
from rakectl.core.jog import Jog
from rakectl.core.lane import LanePlanner
from rakectl.core.supervision import (
    ForceLevel,
    ForceSupervisor,
    implausible_joints,
    plausible_ranges,
)
from rakectl.daemon.checks import ArmingChecks
from rakectl.daemon.events import EventLog, drive_summary, kept_rpdos
from rakectl.daemon.inputs import InputLog
from rakectl.daemon.recorder import DumpWriter, FlightRecorder
from rakectl.daemon.sdnotify import Notifier
from rakectl.daemon.states import ARMED_STATES, DaemonState, Event
from rakectl.daemon.timing import LoopTiming, TickTimer
from rakectl.daemon.transitions import StateChanges
from rakectl.drive.canbus import TraceRecorder
from rakectl.drive.client import DriveClient
from rakectl.drive.health import FOREIGN_SYNC_ANSWERS, state_name
from rakectl.drive.joints import Joint
from rakectl.errors import CommsTimeout, NonFiniteError
from rakectl.protocol.cia402 import DriveState

RECORDER_COLUMNS = (
    "t_s", "state", "reach_ref_m", "depth_ref_m", "reach_m", "depth_m", "x_ref_m", "f_hat_n",
    "voltage_r_req_v", "voltage_theta_req_v", "voltage_r_v", "voltage_theta_v",
    "clamp_worst_case_n", "r_m", "theta_rad", "current_r_a", "current_theta_a",
    "f_current_n", "force_level", "latency_us", "exec_us",
)
SEND_FAILURE_STREAK = 3  # ticks in a row with a failed send: fault
HEARTBEAT_CHECK_TICKS = 10
DESCENT_QUIET_TICKS = 2000  # a descent-limit event again only after 2 s without a hold

log = structlog.get_logger("rakectl")


class Daemon(StateChanges):
    """The control loop and its state; ``handle`` (rakectl.daemon.handlers) serves requests."""

    def __init__(self, settings: Settings, client: DriveClient, notifier: Notifier,
                 dump_dir: Path, clock_ns: Callable[[], int] = time.monotonic_ns) -> None:
        self.settings = settings
        self.client = client
        self.notifier = notifier
        self.dump_dir = dump_dir
        self.dt_s = 1.0 / settings.rate_hz
        self.timer = TickTimer(self.dt_s, clock_ns)
        self.timing = LoopTiming(self.timer)
        self.controller = TipController(settings)
        bound = settings.clamp
        self.supervisor = ForceSupervisor(
            settings.supervision, bound, settings.motors.r, settings.motors.theta, self.dt_s,
            drag_limit_n(settings.descent, bound.force_limit_n, bound.model_margin))
        self.workspace = self.controller.servo.workspace
        capacity = round(settings.daemon.recorder_s * settings.rate_hz)
        self.recorder = FlightRecorder(RECORDER_COLUMNS, capacity)
        self.state = DaemonState.INIT
        self.fault_reason = ""
        self.ticks = 0
        self.hold = (0.0, 0.0)  # (reach, depth) held in ARMED and HOLD
        self.jog: Jog | None = None
        self.jog_client = 0  # the connection whose requests drive the jog (Request.client)
        self.jog_ended: dict[int, str] = {}  # connections whose jog ended, and why
        # whether a connection is still open (the command server's; none in-process)
        self.connected: Callable[[int], bool] = _no_connection
        self.planner: LanePlanner | None = None
        self.checks = ArmingChecks(settings, self.workspace, self.dt_s)  # in CHECKING
        self._plausible = plausible_ranges(settings.geometry)
        self.f_hat_max_n = 0.0
        self.voltages = (0.0, 0.0)  # sent on the last tick (after the clamp)
        # cyclictest's wake-up latency at start-up ({"p99_us", …}), or why it is absent
        self.timing_reference: dict[str, Any] = {"reason": "not measured"}
        self._enabled = False
        self._enable_deadline = 0
        self._reset_deadline = -1
        self._send_failures = 0
        self._overrun_streak = 0
        self._stop_requested = False
        self._dumps: collections.deque[DumpWriter] = collections.deque()
        self.dump_failures: collections.deque[str] = collections.deque(maxlen=5)
        self.events = EventLog(log, rate_limited=("timing",))
        self._clock_ns = clock_ns
        self._next_stats_tick = 0
        self._next_watchdog_tick = 0
        self._next_starved_tick = 0
        self._ref = (0.0, 0.0)
        self._descent_clipped = 0  # the descent limiter's count of held ticks, last tick
        self._descent_free_ticks = DESCENT_QUIET_TICKS  # ticks since it last held one
        self.slack_hook: Callable[[float], object] | None = None  # the command server's poll
        self.trace: TraceRecorder | None = None  # bus trace, drained in the slack
        self.inputs: InputLog | None = None  # the trace's sidecar (rakectl.daemon.inputs)
        # "now" of the heartbeat check: the clock that stamps heartbeats (a replay gives
        # the check the outcomes its run recorded instead)
        self.heartbeat_clock: Callable[[], float] = client.clock
        client.on_send_error = self._on_send_error
        self._exec_us = 0.0

    # ------------------------------------------------------------------ life cycle

    def request_stop(self) -> None:
        """Ask the loop to end (signal handlers and the shutdown command only set this)."""
        self._stop_requested = True

    def bring_up(self) -> None:
        """Configure the drives, then cycle until both report valid feedback: READY."""
        infos = self.client.bring_up(self.settings.daemon.boot_timeout_s)
        if self.inputs is not None:
            self.inputs.start(self.trace.recorded if self.trace is not None else 0,
                              (infos[Joint.R].statusword, infos[Joint.THETA].statusword),
                              self.settings)
        self.event("drives_configured", drives=[drive_summary(i) for i in infos])
        for fields in kept_rpdos(infos):  # an RPDO beyond the EDS's the drive keeps valid
            self.event("drive_rpdo_kept_valid", **fields)

    def run(self) -> None:
        """The loop, until a stop is requested. Ends with 0 V, drives disabled, a dump."""
        timeout_ticks = round(self.settings.daemon.boot_timeout_s * self.settings.rate_hz)
        self.timer.start()
        ended = "stop requested"
        try:
            while not self._stop_requested:
                skipped = self.timer.wait()
                if skipped and self.inputs is not None:
                    self.inputs.overrun(self.ticks, skipped)
                started_ns = self._clock_ns()
                self.tick(skipped)
                exec_ns = self._clock_ns() - started_ns
                self._exec_us = exec_ns * 1e-3
                self.timing.record(exec_ns)
                if self.state is DaemonState.INIT and self.ticks > timeout_ticks:
                    raise CommsTimeout("no valid feedback from both drives within "
                                       f"{self.settings.daemon.boot_timeout_s:g} s of bring-up")
                self.slack()
        except BaseException as error:
            ended = f"{type(error).__name__}: {error}"
            raise
        finally:
            self.finish(ended)

    # ------------------------------------------------------------------ one tick

    def tick(self, skipped: int = 0) -> None:
        """One control period: feedback in, voltages out (0 V unless armed and healthy)."""
        self.ticks, self.skipped = self.ticks + 1 + skipped, skipped
        client = self.client
        client.receive()
        voltages = (0.0, 0.0)
        state = self.state
        if state is DaemonState.INIT:
            self._check_ready()
        elif state is not DaemonState.FAULT and state is not DaemonState.ESTOP:
            problem = self._supervise(armed=state in ARMED_STATES)
            if problem:
                self.fault(problem)
            elif state in ARMED_STATES:  # a fault within it (a check's, the force limit's
                voltages = self._control()  # in CHECKING) sends 0 V from this tick on
                if self.state not in ARMED_STATES:
                    voltages = (0.0, 0.0)
        elif self._reset_deadline >= 0:
            self._try_reset()
        try:
            client.send(*voltages)
        except NonFiniteError as error:  # the clamp's output is finite: a bug, made a fault
            self.fault(f"non-finite voltage at the bus: {error}")
            voltages = (0.0, 0.0)
            client.send(*voltages)
        client.sync()
        self._send_failures = self._send_failures + 1 if client.send_failed() else 0
        self._overrun_streak = self._overrun_streak + 1 if skipped else 0
        self.voltages = voltages
        self._record(voltages)

    def _check_ready(self) -> None:
        """READY once both drives' feedback is fresh and finite; a drive problem before it
        (a heartbeat not OPERATIONAL: a restart unseen since bring-up) is a fault."""
        fb = self.client.feedback
        if self.client.drive_faults():
            return self.fault(self._drive_problems())
        fresh = fb.stale_cycles[0] == 0 and fb.stale_cycles[1] == 0
        if fresh and math.isfinite(fb.r_m) and math.isfinite(fb.theta_rad):
            self._transition(Event.READY, "drives configured, feedback valid")

    def _supervise(self, armed: bool) -> str:
        """Why the loop must fault now, or "" (cheap: strings only when something is wrong).
        Disarmed, only drive faults and lost heartbeats count: stale feedback matters once
        voltages depend on it (arming requires it fresh)."""
        client, fb = self.client, self.client.feedback
        limit = self.settings.drives.feedback_timeout_cycles
        heartbeat_check = self.ticks % HEARTBEAT_CHECK_TICKS == 0
        if client.drive_faults() or (armed and client.stale_feedback(limit)) or (
                heartbeat_check and self._heartbeat_lost()) or (
                client.answers_beyond_syncs() > FOREIGN_SYNC_ANSWERS):
            return self._drive_problems()
        if not armed:
            return ""
        if not (math.isfinite(fb.r_m) and math.isfinite(fb.theta_rad)
                and math.isfinite(fb.r_vel_m_per_s) and math.isfinite(fb.theta_vel_rad_per_s)):
            return "non-finite joint feedback"
        r_range, theta_range = self._plausible
        if not (r_range[0] <= fb.r_m <= r_range[1]
                and theta_range[0] <= fb.theta_rad <= theta_range[1]):
            return self.implausible_feedback()
        if self._send_failures >= SEND_FAILURE_STREAK:
            return f"CAN send failed {self._send_failures} ticks in a row: {client.last_send_error}"
        if self._overrun_streak >= self.settings.daemon.overrun_fault_streak:
            return f"{self._overrun_streak} late ticks in a row: the loop cannot keep time"
        return ""

    def _on_send_error(self, msg: can.Message, error: can.CanError) -> None:
        """A send failed (the client calls this, rarely): into the trace's inputs."""
        if self.inputs is not None:
            stats = self.client.stats
            self.inputs.send_failed(self.ticks, stats.sends + stats.send_errors - 1,
                                    self.trace.recorded if self.trace is not None else 0,
                                    msg, error)

    def implausible_feedback(self) -> str:
        """Which drive reports a joint position no robot of this geometry can have, or ""."""
        fb, d = self.client.feedback, self.settings.drives
        return implausible_joints(fb.r_m, fb.theta_rad, self._plausible,
                                  (d.r_node_id, d.theta_node_id))

    def _control(self) -> tuple[float, float]:
        if not self._enabled and not self._enable_drives():
            return 0.0, 0.0
        reach, depth, contact = self._reference()
        self._ref = (reach, depth)
        fb, c = self.client.feedback, self.controller
        c.set_contact(contact)
        voltages = c.step(reach, depth, fb.r_m, fb.theta_rad, fb.r_vel_m_per_s,
                          fb.theta_vel_rad_per_s, fb.samples,
                          mount_force_n=self.supervisor.f_current_n)
        if c.fault or c.clamp.infeasible:
            self.fault(c.fault or "the voltage clamp cannot meet its bound: "
                       f"worst case {c.clamp.worst_case_n:.1f} N")
            return 0.0, 0.0
        if c.f_hat_n > self.f_hat_max_n:
            self.f_hat_max_n = c.f_hat_n
        if c.descent is not None:
            self._report_descent(c.descent, reach)
        previous = self.supervisor.level
        level = self.supervisor.step(c.f_hat_n, fb.r_m, fb.theta_rad, fb.current_r_a,
                                     fb.current_theta_a)
        if level is ForceLevel.HARD and previous is not ForceLevel.HARD:
            self._back_off()
        planner = self.planner
        if planner is not None and self.state is DaemonState.EXCAVATE:
            if planner.observe(c.reach_m, c.depth_m, fb.samples):
                self.event("object_found", reach_m=c.reach_m, depth_m=c.depth_m)
            sup = self.supervisor  # an adaptive stroke follows the larger estimate
            planner.govern(max(c.f_hat_n, sup.f_current_n), sup.caution_n)
        return voltages

    def _report_descent(self, descent: DescentLimiter, reach_ref_m: float) -> None:
        """One event when the descent limiter starts holding references at the ground
        map's floor after DESCENT_QUIET_TICKS without (docs/safety.md, "Not covered"),
        naming where and how deep."""
        holding = descent.clipped != self._descent_clipped
        self._descent_clipped = descent.clipped
        if not holding:
            self._descent_free_ticks += 1
            return
        quiet = self._descent_free_ticks >= DESCENT_QUIET_TICKS
        self._descent_free_ticks = 0
        if quiet:
            c = self.controller
            limit_m = descent.limit_depth_m(reach_ref_m, c.reach_m)
            self.event("descent_limit", reach_m=c.reach_m, depth_m=c.depth_m,
                       limit_depth_m=limit_m,
                       message=f"descent limit here: the tines are held at "
                               f"{-limit_m * 1e3:+.1f} mm from ground level 0 at reach "
                               f"{c.reach_m:.3f} m (the soil beside them may stand no more "
                               "than the declared soil's step above them)")

    def _back_off(self) -> None:
        """Hard force level: stop where the tip is and back off upward; report it."""
        c, sup = self.controller, self.supervisor
        reach, depth = c.reach_m, c.depth_m - self.settings.supervision.back_off_m
        self.event("force_limit", f_hat_n=c.f_hat_n, f_current_n=sup.f_current_n,
                   f_reach_current_n=sup.f_reach_current_n, reach_m=c.reach_m,
                   depth_m=c.depth_m)
        if self.state is DaemonState.EXCAVATE and self.planner is not None:
            self.planner.force_stop(c.reach_m, c.depth_m)
            return
        if self.state is DaemonState.CHECKING:  # its reference is the check's: end it
            self.fault(f"force limit during the checks before arming: F̂ {c.f_hat_n:.1f} N, "
                       f"from the currents {sup.f_current_n:.1f} N down, "
                       f"{sup.f_reach_current_n:.1f} N along the reach")
            return
        self.hold = (reach, depth)
        if self.state is DaemonState.JOG:
            self._transition(Event.STOP, "force limit: backing off")

    def _reference(self) -> tuple[float, float, bool]:
        """Tip reference (reach, depth) and contact flag of the current mode, one tick on.
        At the caution level the reference holds still (jog and lane do not advance); a
        jog's dead-man counts on, and the jog starts again from rest."""
        state = self.state
        if state is DaemonState.CHECKING:
            c = self.controller
            reach, depth, verdict = self.checks.step(self.client.feedback, c.reach_m, c.depth_m)
            if verdict is not None:
                self._judge(verdict)
            return reach, depth, False
        caution = self.supervisor.level is ForceLevel.CAUTION
        if state is DaemonState.JOG and self.jog is not None:
            self.jog.observe(self.controller.reach_m, self.controller.depth_m)
            self.jog.step(held=caution)
            if self.jog.expired and not self.jog.moving:
                self.hold = self.jog.tip()
                self._transition(Event.STOP, "dead-man: no jog command")
            reach, depth = self.jog.tip()
            return reach, depth, caution or self.jog.contact
        if caution and state is DaemonState.EXCAVATE:
            return self._ref[0], self._ref[1], True
        if state is DaemonState.EXCAVATE and self.planner is not None:
            planner = self.planner
            planner.step()
            if planner.done:
                self.hold = (planner.reach_m, planner.depth_m)
                self._transition(Event.DONE, "object found" if planner.found_at else
                                 "stopped by the force limit" if planner.stopped_by_force
                                 else "held by the descent limit at "
                                 f"{planner.floor_m * 1e3:.1f} mm (the declared soil's step "
                                 "allows no deeper there: descent.*)"
                                 if planner.held_by_descent else "target depth reached")
            return planner.reach_m, planner.depth_m, planner.contact
        return self.hold[0], self.hold[1], False

    def _enable_drives(self) -> bool:
        """Step both drives through CiA 402 to OPERATION ENABLED; True once both are."""
        states = self.client.feedback.state
        if states[0] is DriveState.OPERATION_ENABLED and states[1] is DriveState.OPERATION_ENABLED:
            self._enabled = True
            self.client.enabled()
            self.event("drives_enabled")
            return True
        if self.ticks > self._enable_deadline:
            self.fault(f"drives did not enable within {self.settings.daemon.enable_timeout_s:g} s"
                       f" (r: {state_name(states[0])}, θ: {state_name(states[1])})")
            return False
        for joint in (Joint.R, Joint.THETA):
            state = states[joint]
            if state is not None and state is not DriveState.OPERATION_ENABLED:
                steps = self.client.path_to_enabled(state)
                if steps:
                    self.client.command(joint, steps[0])
        return False

    def _record(self, voltages: tuple[float, float]) -> None:
        fb, c = self.client.feedback, self.controller
        self.recorder.record_row((
            self.ticks * self.dt_s, self.state.value, self._ref[0], self._ref[1], c.reach_m,
            c.depth_m, c.x_ref_m, c.f_hat_n, c.requested_v[0], c.requested_v[1], voltages[0],
            voltages[1], c.clamp.worst_case_n, fb.r_m, fb.theta_rad, fb.current_r_a,
            fb.current_theta_a, self.supervisor.f_current_n, float(self.supervisor.level),
            self.timer.latency_ns * 1e-3, self._exec_us,
        ))


def _no_connection(client: int) -> bool:
    """Without a command server no request comes on a connection that stays open."""
    return False
