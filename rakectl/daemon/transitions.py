"""The daemon's state changes: the operator's commands and the faults.

The base of :class:`rakectl.daemon.loop.Daemon`, on :class:`rakectl.daemon.slack.SlackWork`.
Every change of state goes through :meth:`StateChanges._transition` (the table of
rakectl.daemon.states): leaving the armed states disables the drives (a quick stop
for an e-stop); a fault also dumps the flight recorder and latches until a reset
finds its cause gone. The operator's requests (rakectl.daemon.handlers) call these
between ticks, on the loop's thread, so nothing here races the tick.
"""

from __future__ import annotations

from collections.abc import Callable

from rakectl.core import kinematics
from rakectl.core.control import TipController
from rakectl.core.supervision import ForceSupervisor
from rakectl.daemon.checks import ArmingChecks, Verdict
from rakectl.daemon.slack import SlackWork
from rakectl.daemon.states import ARMED_STATES, DaemonState, Event, next_state
from rakectl.protocol.cia402 import DriveCommand

RESET_QUIET_TICKS = 30  # a reset ends no sooner: a SYNC producer of 100 Hz or more shows
# (3 extra answers at the robot's 1 kHz, more than RESET_EXTRA_ANSWERS)
RESET_EXTRA_ANSWERS = 2  # TPDO1s beyond the SYNCs it tolerates: one still on its way when
# the reset forgave the count, one stray frame (a foreign producer at 100 Hz sends 2)


class StateChanges(SlackWork):
    """Arm, disarm, stop, e-stop, fault and reset; the loop's state is the subclass's."""

    controller: TipController
    supervisor: ForceSupervisor
    checks: ArmingChecks
    workspace: kinematics.Workspace
    fault_reason: str
    hold: tuple[float, float]  # (reach, depth) held in ARMED and HOLD
    heartbeat_clock: Callable[[], float]
    _ref: tuple[float, float]
    _enabled: bool
    _enable_deadline: int
    _reset_deadline: int
    _reset_quiet_tick: int = 0
    skipped: int = 0  # the periods this tick woke late by
    jog_client: int  # the connection whose requests drive the jog
    jog_ended: dict[int, str]  # the connections whose jog ended, and why
    # excavate requests carried out since start-up: the number of the newest lane, which
    # status names its lane by (one lane told from the next)
    lanes_started: int = 0

    def _heartbeat_lost(self) -> bool:
        """The heartbeat check, on the wall clock; a lost heartbeat goes to the trace's
        inputs (rare: it faults)."""
        lost = self.client.heartbeat_lost(self.heartbeat_clock())
        if lost and self.inputs is not None:
            self.inputs.heartbeat_lost(self.ticks)
        return lost

    def _transition(self, event: Event, reason: str = "") -> bool:
        new = next_state(self.state, event)
        if new is None:
            return False
        old, self.state = self.state, new
        if old is DaemonState.JOG and new is not DaemonState.JOG:
            self.jog_ended[self.jog_client] = reason
        if old is DaemonState.CHECKING:  # passed, or left unfinished (judged again next arm)
            self.checks.stop(reason)
        if old in ARMED_STATES and new not in ARMED_STATES:
            self._enabled = False
            self.controller.requested_v = (0.0, 0.0)  # nothing asked until armed again
            self.client.command(None, DriveCommand.QUICK_STOP if new is DaemonState.ESTOP
                                else DriveCommand.DISABLE_VOLTAGE)
        self.event("state", old=old.name, new=new.name, reason=reason)
        status = f"{new.name.lower()}{': ' + reason if reason else ''}"
        if old is DaemonState.INIT:  # systemd's READY=1 however INIT ends: a fault in
            self.notifier.ready(status)  # INIT is a start too, which a reset may clear
        else:
            self.notifier.status(status)
        return True

    def fault(self, reason: str) -> None:
        """0 V from this tick on, drives disabled, the recorder dumped; latched until reset."""
        if self._transition(Event.FAULT, reason):
            self.fault_reason = reason
            self.client.command(None, DriveCommand.DISABLE_VOLTAGE)
            self._dump("fault")

    def estop(self) -> None:
        """Quick stop, latched until a reset asked after it (one asked before, still
        waiting for its cause to clear, is called off); a fault's cause stays named."""
        self._reset_deadline = -1
        if self.state is DaemonState.ESTOP:  # again: nothing new to latch or dump
            self.client.command(None, DriveCommand.QUICK_STOP)
            return
        cause = self.fault_reason if self.state is DaemonState.FAULT else ""
        self._transition(Event.ESTOP, "operator e-stop")
        self.fault_reason = "operator e-stop" + (f" (in fault: {cause})" if cause else "")
        self.client.command(None, DriveCommand.QUICK_STOP)
        self._dump("estop")

    def arm(self) -> None:
        """Hold the present pose and step the drives to OPERATION ENABLED; the first time
        after start-up, through the checks before arming (CHECKING: rakectl.daemon.checks)."""
        fb, s = self.client.feedback, self.settings
        self.controller.reset(fb.r_m, fb.theta_rad)
        self.controller.clamp.clear_latched()  # a fault it raised before was reset
        self.supervisor.reset()
        self.hold = (self.controller.reach_m, self.controller.depth_m)
        self._ref = self.hold
        self._enabled = False
        self._enable_deadline = self.ticks + round(s.daemon.enable_timeout_s * s.rate_hz)
        if self.checks.passed:
            self._transition(Event.ARM)
            return
        reason = self.checks.start(*self.hold)  # built here, off the tick
        if not self._transition(Event.CHECK, reason):
            self.checks.stop()

    def _judge(self, verdict: Verdict) -> None:
        """A check ended: log it, then fault, run the next check, or arm."""
        self.hold = verdict.start
        self.event(verdict.event, **verdict.fields)
        if not verdict.passed:
            self.fault(verdict.message)
        elif self.checks.mount_check is None:
            self._transition(Event.CHECKED, verdict.message)

    def start_reset(self) -> None:
        """Fault-reset the drives; FAULT/ESTOP → DISARMED once no problem is left (≤ 1 s),
        and no more than ``RESET_EXTRA_ANSWERS`` TPDO1s beyond the SYNCs sent within
        ``RESET_QUIET_TICKS`` (another SYNC producer still on the bus: the answers counted
        before are forgiven at the reset, the new ones counted)."""
        self.client.reset_faults()
        self._reset_deadline = self.ticks + round(self.settings.rate_hz)
        self._reset_quiet_tick = self.ticks + RESET_QUIET_TICKS

    def _drive_problems(self) -> str:
        """What the supervision checks see wrong with the drives, in one line; after a
        stall of the loop longer than the drives' command watchdog (this tick woke that
        late: the process stopped, the machine busy), that stall first, as their cause."""
        limit = self.settings.drives.feedback_timeout_cycles
        problems = ("; ".join(self.client.describe_problems(self.heartbeat_clock(), limit))
                    or "drive problem")
        stalled_ms = (self.skipped + 1) * 1e3 / self.settings.rate_hz  # without a tick
        watchdog_ms = self.settings.drives.watchdog_timeout_ms
        if stalled_ms <= watchdog_ms:
            return problems
        return (f"the loop stalled {stalled_ms:.0f} ms, past the drives' {watchdog_ms} ms "
                f"command watchdog, which stopped them: {problems}")

    def _try_reset(self) -> None:
        limit = self.settings.drives.feedback_timeout_cycles
        client = self.client
        client.clear_contradicted_emcy()
        if not (client.drive_faults() or client.stale_feedback(limit)
                or self._heartbeat_lost()
                or client.answers_beyond_syncs() > RESET_EXTRA_ANSWERS):
            if self.ticks < self._reset_quiet_tick:
                return
            self._reset_deadline = -1
            self.client.command(None, DriveCommand.DISABLE_VOLTAGE)
            self.fault_reason = ""
            self._transition(Event.RESET, "reset")
        elif self.ticks > self._reset_deadline:
            self._reset_deadline = -1
            problems = client.describe_problems(self.heartbeat_clock(), limit)
            extra = client.answers_beyond_syncs()
            if not problems and extra > RESET_EXTRA_ANSWERS:
                problems = [f"{extra} TPDO1s more than the SYNCs sent since the reset: another "
                            "node sends SYNC on this bus (another CANopen master)"]
            self.fault_reason = "reset failed: " + ("; ".join(problems) or "a drive problem")
            self.event("reset_failed", problems=problems)

    def disarm(self) -> None:
        self._transition(Event.DISARM, "operator disarm")

    def hold_here(self) -> None:
        """Stop a jog or excavation where the reference is now."""
        self.hold = self._ref
        self._transition(Event.STOP, "operator stop")

    def tip_now(self) -> tuple[float, float]:
        fb = self.client.feedback
        reach, height = kinematics.forward(self.workspace, fb.r_m, fb.theta_rad)
        return reach, -height
