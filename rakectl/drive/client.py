"""The controller's client of the two CANopen drives: bring-up (see rakectl.drive.bringup), then
a 1 kHz hot path.

The protocol is the one of :mod:`rakectl.protocol.codec` (``drives.profile: cia402``) or
of :mod:`rakectl.protocol.roboteq` (``roboteq``: the command in ‰ of the configured supply,
the current in 0.1 A, the flags read as CiA 402 states, and instead of the controlword
the power requests of :meth:`DriveClient.command`; :mod:`rakectl.drive.profiles`); the
bus is injected (only
:func:`rakectl.drive.canbus.open_bus` calls ``can.Bus``), and
:func:`rakectl.drive.joints.receive_ids` names the frames the controller listens to.

Hot path (single thread, once per tick, no allocation of tracked objects, no
logging, no exception for normal control flow). Each tick::

    receive()  →  (controller computes)  →  send(voltage_r_v, voltage_theta_v)  →  sync()

A drive answers SYNC k with the TPDO1 sampled at SYNC k and applies the RPDO1
it received before SYNC k from SYNC k on; the controller reads that TPDO1 at
the start of tick k+1. There is no round trip inside a tick.

- :meth:`DriveClient.receive` drains the bus (``recv(timeout=0)`` until None)
  and updates :attr:`DriveClient.feedback` in place: TPDO1 → joint position,
  velocity (motor model of :mod:`rakectl.core.motor_model`; encoder counts are zero
  at joint position 0) and current; TPDO2 → CiA 402 state and error register;
  EMCY → last EMCY and a fault flag (cleared by EMCY NO_ERROR); heartbeat → NMT
  state and the time it was seen (a BOOT_UP after bring-up latches a fault: the
  drive lost its configuration). A frame of the wrong length, undecodable
  content, an unknown ID, an echo of the controller's own frames (udp_multicast),
  an error frame (socketcan) or a receive error is counted in
  :class:`~rakectl.drive.health.Stats`, never raised (the drain reads on past a
  receive error, an undecodable datagram, and ends after
  ``RECEIVE_ERRORS_PER_DRAIN`` of them, a dead bus). A drive whose TPDO1 did not
  arrive after a SYNC gets one more stale cycle; TPDO1 carries no SYNC counter, so
  the counter recorded with it is the last SYNC sent before the drain (right while
  TPDO1 latency < one period). ``Feedback.samples`` counts the SYNCs both drives
  answered in the drain, for the force estimate's history (rakectl.core.impedance).
- :meth:`DriveClient.send` (both RPDO1s: the voltages and each drive's controlword,
  set by :meth:`DriveClient.command`), :meth:`DriveClient.sync` (SYNC and the
  controller's heartbeat) and a ``can.CanError`` from ``bus.send`` (counted and
  flagged, never raised in the hot path) are the send side's:
  :class:`~rakectl.drive.send.FrameSender`, a base of the client.

Supervision, cheap, each tick (:class:`~rakectl.drive.health.DriveSupervision`):
:meth:`drive_faults`, :meth:`stale_feedback`, :meth:`heartbeat_lost`;
:meth:`describe_problems` words them off the hot path.
:meth:`command` sets the controlword sent from then on; a fault reset sends 0,
then 0x80 (the rising edge of bit 7). :meth:`stop_all` sends 0 V with
DISABLE_VOLTAGE to both drives and a SYNC at once (fault, SIGTERM);
:meth:`shutdown` does that and stops the nodes.
"""

from __future__ import annotations

import array
import time
from collections.abc import Callable

import can

from rakectl.config.service import DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.core.motor_model import joint_per_motor_rad, joint_resolution
from rakectl.drive.bringup import run_bring_up
from rakectl.drive.canbus import TraceRecorder
from rakectl.drive.health import Feedback, Stats
from rakectl.drive.joints import (
    JOINTS,
    DriveInfo,
    Joint,
    motor_of,
    node_ids,
    own_ids,
)
from rakectl.drive.power import PowerRequests
from rakectl.drive.profiles import state_of
from rakectl.drive.send import LATENCY_RING, FrameSender
from rakectl.errors import FrameError
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveCommand, DriveState
from rakectl.protocol.codec import (
    NMT_COB_ID,
    RPDO1_SIZE,
    SYNC_COB_ID,
    SYNC_COUNTER_MAX,
    TPDO2_SIZE,
    FunctionCode,
    cob_id,
    rpm_to_rad_per_s,
)
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import (
    NmtCommand,
    NmtState,
    encode_heartbeat,
    encode_nmt,
)

RECEIVE_ERRORS_PER_DRAIN = 32  # bad datagrams do not end the drain (a burst of 300 held
# the TPDO1s behind it 25 ticks at 4, a false stale-feedback fault); a dead bus does


# =========================================================================== hot path


_TPDO1, _TPDO2, _EMCY, _HEARTBEAT, _SDO, _OWN, _RPDO = range(7)  # _OWN on: its own IDs


def _new_message(can_id: int, size: int) -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=False, data=bytearray(size))


class DriveClient(FrameSender):
    """Both drives over one injected bus; see the module docstring for the tick protocol."""

    def __init__(self, bus: can.BusABC, drives: DrivesSettings, motors: MotorsSettings,
                 rate_hz: float, trace: TraceRecorder | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """``clock`` stamps heartbeats; :meth:`heartbeat_lost` needs times of the same clock."""
        self._bus = bus
        self._drives = drives
        self._motors = motors
        self._trace = trace
        self.clock = clock  # the heartbeat check's "now" must come from it too
        # called (rarely) with each frame whose send failed and the error: the bus trace
        # holds only frames sent, a replay needs the failures too (rakectl.daemon.inputs)
        self.on_send_error: Callable[[can.Message, can.CanError], None] | None = None
        self.feedback = Feedback()
        self.stats = Stats()
        self.last_send_error: can.CanError | None = None
        self.last_receive_error: can.CanError | None = None
        self.infos: tuple[DriveInfo, DriveInfo] | None = None
        nodes = node_ids(drives)
        # The profile's codecs (rakectl.drive.profiles), chosen here: the CiA 402 path is the
        # codec module's as it was; a Roboteq-class drive's TPDO1 has the same layout with
        # the current in 0.1 A, its RPDO1 the command in ‰ and its TPDO2 the flags.
        self._roboteq = drives.profile is DriveProfile.ROBOTEQ
        self._units_per_amp = 1.0 / roboteq.CURRENT_A_PER_UNIT if self._roboteq else 1000.0
        self._tpdo2_size = roboteq.TPDO2_SIZE if self._roboteq else TPDO2_SIZE
        self._supply_v = [motor_of(motors, j).supply_voltage_v for j in JOINTS]
        self._power = PowerRequests(nodes, self._transmit)  # Roboteq-class: no controlword
        self._position_per_count = [joint_resolution(motor_of(motors, j)) for j in JOINTS]
        self._velocity_per_rpm = [rpm_to_rad_per_s(1.0) * joint_per_motor_rad(motor_of(motors, j))
                                  for j in JOINTS]
        self._route: dict[int, tuple[int, int]] = {can_id: (_OWN, 0) for can_id in own_ids(drives)}
        for j, node in zip(JOINTS, nodes, strict=True):
            self._route |= {cob_id(FunctionCode.TPDO1, node): (_TPDO1, j),
                            cob_id(FunctionCode.TPDO2, node): (_TPDO2, j),
                            cob_id(FunctionCode.EMCY, node): (_EMCY, j),
                            cob_id(FunctionCode.HEARTBEAT, node): (_HEARTBEAT, j),
                            cob_id(FunctionCode.SDO_RESPONSE, node): (_SDO, j),
                            cob_id(FunctionCode.RPDO1, node): (_RPDO, j)}
        self._rpdo = [_new_message(cob_id(FunctionCode.RPDO1, node), RPDO1_SIZE) for node in nodes]
        self._rpdo_before = [bytearray(m.data) for m in self._rpdo]  # the one sent before
        self._sync_counted = drives.sync_counter_overflow > 0  # else SYNC has no data
        self._sync_top = drives.sync_counter_overflow or SYNC_COUNTER_MAX  # counted here
        self._sync_msg = _new_message(SYNC_COB_ID, 1 if self._sync_counted else 0)
        self._heartbeat_msg = _new_message(cob_id(FunctionCode.HEARTBEAT,
                                                  drives.controller_node_id), 1)
        self._heartbeat_msg.data[:] = encode_heartbeat(NmtState.OPERATIONAL)
        self._heartbeat_ticks = max(1, round(drives.heartbeat_period_ms * rate_hz / 1000.0))
        self._heartbeat_countdown = 0  # the first SYNC goes out with a heartbeat
        self._heartbeat_timeout_s = drives.heartbeat_timeout_ms / 1000.0
        self._sync_counter = 0
        self._syncs_pending = 0  # SYNCs sent since the last receive()
        self._sync_sent_s = 0.0  # wall clock (python-can's receive timestamps) of the last SYNC
        self._latency_s = array.array("d", bytes(8 * LATENCY_RING))  # SYNC → TPDO1 arrival
        self._latency_index = 0
        self.latency_samples = 0
        self._fresh = [0, 0]  # TPDO1s per drive in this drain
        self._answered = 0  # SYNCs both drives' TPDO1s answered (Feedback.samples)
        self._send_failed = False
        self._command: list[DriveCommand] = [DriveCommand.DISABLE_VOLTAGE] * 2
        self._controlword = [0, 0]  # goes out with the next send()
        self._controlword_after = [0, 0]  # ... and from the one after on
        self._controlword_sent = [0, 0]
        self._heard_s = [clock(), clock()]
        self._state_fault = [False, False]
        self._emcy_fault = [False, False]
        self._rebooted = [False, False]
        self._left_enabled: list[DriveState | None] = [None, None]
        self._left_status = [0, 0]  # the status it was read with
        self._foreign_rpdo: list[bytes | None] = [None, None]
        self._nmt_fault = [False, False]
        self._unconfigured = [False, False]
        self._tpdo2_after_emcy = [True, True]  # a TPDO2 came after the drive's last EMCY
        self._enabled_expected = False  # both drives were enabled, no other command since
        self._operational = False  # both drives started (NMT) and answering: heartbeats count
        self._answers_forgiven = 0
        self._fault = [False, False]

    # ------------------------------------------------------------------- bring-up

    def bring_up(self, boot_timeout_s: float = 2.0) -> tuple[DriveInfo, DriveInfo]:
        """Configure, verify and start both drives (blocking; see rakectl.drive.bringup)."""
        infos = run_bring_up(self._bus, self._drives, self._motors, boot_timeout_s,
                             self._trace)
        self.infos = infos
        self.started((infos[Joint.R].statusword, infos[Joint.THETA].statusword))
        return infos

    def started(self, statuswords: tuple[int, int]) -> None:
        """Take up where a bring-up left the drives: each drive's statusword read at its
        end (per :class:`Joint`); heartbeat times start now, and a heartbeat in any NMT
        state but OPERATIONAL is a fault from now on (bring-up heard both say OPERATIONAL).
        :meth:`bring_up` calls it; a replay (rakectl.daemon.replay) calls it with the
        statuswords its run recorded."""
        self._heard_s = [self.clock(), self.clock()]
        self._rebooted = [False, False]
        self._left_enabled = [None, None]
        self._nmt_fault = [False, False]
        self._unconfigured = [False, False]
        self._operational = True  # bring-up heard each drive say OPERATIONAL
        for joint in JOINTS:
            statusword = statuswords[joint]
            state = state_of(self._drives.profile, statusword)
            self.feedback.statusword[joint] = statusword
            self.feedback.state[joint] = state
            self._state_fault[joint] = state in (DriveState.FAULT,
                                                 DriveState.FAULT_REACTION_ACTIVE)
            self._update_fault(joint)

    # ------------------------------------------------------------------- receive

    def receive(self) -> int:
        """Drain the bus without blocking and update :attr:`feedback`; returns frames read."""
        recv = self._bus.recv
        route = self._route
        stats = self.stats
        trace = self._trace
        fresh = self._fresh
        fresh[0] = fresh[1] = 0
        count = errors = 0
        while True:
            try:
                msg = recv(0.0)
            except can.CanError as error:
                stats.receive_errors += 1
                self.last_receive_error = error
                errors += 1
                if errors >= RECEIVE_ERRORS_PER_DRAIN:
                    break
                continue
            if msg is None:
                break
            count += 1
            if msg.is_error_frame or msg.is_extended_id or msg.is_remote_frame:
                if trace is not None:
                    trace.record(msg, True)
                self._on_odd_frame(msg)
                continue
            kind_joint = route.get(msg.arbitration_id)
            if trace is not None and (kind_joint is None or kind_joint[0] < _OWN):
                trace.record(msg, True)  # an echo of a frame sent is traced once, as sent
            if kind_joint is None:
                stats.frames_unknown += 1
                continue
            kind, j = kind_joint
            try:
                if kind == _TPDO1:
                    self._on_tpdo1(j, msg.data)
                    self._latency(msg.timestamp)
                elif kind == _TPDO2:
                    self._on_tpdo2(j, msg.data)
                elif kind == _EMCY:
                    self._on_emcy(j, msg.data)
                elif kind == _HEARTBEAT:
                    self._on_heartbeat(j, msg.data)
                elif kind == _SDO:
                    stats.sdo_answers += 1  # to a Roboteq-class power request: the flags tell
                elif kind == _RPDO and msg.data != self._rpdo[j].data and \
                        msg.data != self._rpdo_before[j]:  # not the echo of one of the last
                    if trace is not None:  # two sent (udp_multicast's may come a tick late)
                        trace.record(msg, True)
                    self._on_foreign_rpdo(j, msg)
                else:
                    stats.frames_own += 1
            except FrameError:
                stats.frames_invalid += 1
        self._count_stale()
        stats.ticks += 1
        return count

    # ------------------------------------------------------------------- commands
    # (the controlword, the RPDO1s and SYNC go out from FrameSender, rakectl.drive.send)

    def enabled(self) -> None:
        """Both drives reached OPERATION ENABLED: from now until another command, a drive
        reporting any other state is a latched fault (the controlword the next send()
        carries would enable a drive in QUICK STOP ACTIVE again, CiA 402 transition 16).
        ENABLE_OPERATION is asked of both even so: a state read just after a disarm may be
        the drive's last before it, whose disable (a Roboteq-class drive's shutdown) is
        still on its way, and the drive then leaving OPERATION ENABLED is that fault."""
        self.command(None, DriveCommand.ENABLE_OPERATION)
        self._enabled_expected = True

    def clear_contradicted_emcy(self) -> None:
        """During a fault reset: an EMCY flag a later TPDO2 contradicts (the drive not in
        FAULT, its error register 0) is cleared: its NO_ERROR EMCY was lost, or the drive
        sends none after a warning."""
        fb = self.feedback
        for j in JOINTS:
            if (self._emcy_fault[j] and self._tpdo2_after_emcy[j] and not self._state_fault[j]
                    and fb.error_register[j] == 0):
                self._emcy_fault[j] = False
                self._update_fault(j)

    def reset_faults(self) -> None:
        """The operator's reset: a fault reset of both drives (:meth:`command`); a drive
        whose heartbeat says STOPPED (an NMT command from elsewhere: a stopped node keeps
        its values) started again. Not one that has said PRE-OPERATIONAL since bring-up,
        whatever it says now: that is also what a drive that restarted with its boot-up
        lost says, holding its power-on values (its own watchdog time, its stored PDOs), so
        it needs its bring-up, as a rebooted one does (a latched fault until then). And
        the extra TPDO1s counted so far judged no more (:meth:`answers_beyond_syncs`
        counts from the start: a SYNC producer gone would fault the loop again at once)."""
        self.command(None, DriveCommand.FAULT_RESET)
        for j in JOINTS:
            if (self._operational and not self._rebooted[j] and not self._unconfigured[j]
                    and self.feedback.nmt_state[j] is NmtState.STOPPED):
                self.start_node(j)
        received = self.stats.tpdo_received  # negative after SYNCs went unanswered: the
        # count starts from 0 again (an answer on its way then reads as one extra, which
        # the reset's check allows for)
        self._answers_forgiven = max(received[0], received[1]) - self.stats.syncs

    def stop_all(self) -> None:
        """0 V and DISABLE_VOLTAGE to both drives, applied now (RPDO1s, then a SYNC)."""
        self.command(None, DriveCommand.DISABLE_VOLTAGE)
        self.send(0.0, 0.0)
        self.sync()

    def shutdown(self, stop_nodes: bool = True) -> None:
        """End of operation: :meth:`stop_all`, then NMT stop to each drive. The bus stays open."""
        self.stop_all()
        if stop_nodes:
            for node in node_ids(self._drives):
                msg = can.Message(arbitration_id=NMT_COB_ID, is_extended_id=False,
                                  data=encode_nmt(NmtCommand.STOP, node))
                self._transmit(msg)
