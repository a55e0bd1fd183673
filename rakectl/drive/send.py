"""The drive client's send side, on the hot path: the controlword each drive's RPDO1
carries (:meth:`FrameSender.command`: a CiA 402 command, or a Roboteq-class drive's
power requests of :mod:`rakectl.drive.power`), the RPDO1s with the voltages, SYNC with
the controller's heartbeat, the NMT start of one drive, the SYNC → TPDO1 latencies kept
for the benchmark, and every frame sent through one place that counts a failed send
instead of raising it. :class:`FrameSender` is a base of
:class:`~rakectl.drive.client.DriveClient`, which owns the attributes declared below (set
up in its constructor); it stands on :class:`~rakectl.drive.decode.FrameDecoder`, whose
per-drive fault flags a command and a Roboteq-class drive gone off update.

- :meth:`FrameSender.send` converts the voltages with
  :func:`rakectl.protocol.codec.voltage_v_to_mv` (rounds, saturates at ±32.767 V) and
  packs both RPDO1s into preallocated messages with each drive's controlword.
  A non-finite voltage raises :class:`~rakectl.errors.NonFiniteError` before
  anything is sent; the daemon turns that into a fault
  (:meth:`~rakectl.drive.client.DriveClient.stop_all`).
  The drive refuses a voltage beyond its 0x2001 with EMCY INVALID_COMMAND,
  which this client counts as a fault until the drive's EMCY NO_ERROR: the
  safety clamp upstream bounds voltages to ``DriveInfo.limits.max_voltage_mv``.
- :meth:`FrameSender.sync` sends SYNC with the next counter (1 … 0x1019,
  ``drives.sync_counter_overflow``; without data when that is 0) and, every
  heartbeat period, the controller's heartbeat (the first one with the first SYNC).
- A ``can.CanError`` from ``bus.send`` is counted (``stats.send_errors``) and
  flagged (:meth:`FrameSender.send_failed`, ``last_send_error``),
  never raised in the hot path. socketcan raises ``CanOperationError`` (ENOBUFS
  "No buffer space available" or "Transmit buffer full" while the controller is
  bus-off or the queue is full, ENETDOWN when the link is down) and reports
  bus-off as a received error frame with class CAN_ERR_BUSOFF (its ``bus.state``
  always says ACTIVE); virtual raises only for a closed bus or a full bounded
  queue; udp_multicast raises ``CanOperationError``/``CanTimeoutError`` for socket errors.
"""

from __future__ import annotations

import array
import time
from collections.abc import Callable

import can

from rakectl.drive.canbus import TraceRecorder
from rakectl.drive.decode import FrameDecoder
from rakectl.drive.joints import JOINTS, Joint, node_ids
from rakectl.drive.power import path_to_enabled as power_path
from rakectl.protocol.cia402 import (
    FAULT_RESET_BIT,
    DriveCommand,
    DriveState,
    path_to_enabled,
)
from rakectl.protocol.codec import (
    NMT_COB_ID,
    next_sync_counter,
    pack_rpdo_into,
    voltage_v_to_mv,
)
from rakectl.protocol.nmt import NmtCommand, encode_nmt
from rakectl.protocol.roboteq import pack_command_into, volts_to_per_mille

LATENCY_RING = 65536  # SYNC → TPDO1 latencies kept for the benchmark


class FrameSender(FrameDecoder):
    """The send side of :class:`~rakectl.drive.client.DriveClient` (module docstring)."""

    _bus: can.BusABC
    _trace: TraceRecorder | None
    # called (rarely) with each frame whose send failed and the error (rakectl.daemon.inputs)
    on_send_error: Callable[[can.Message, can.CanError], None] | None
    last_send_error: can.CanError | None
    _supply_v: list[float]  # Roboteq-class: the supply the command's ‰ are of, per drive
    _rpdo: list[can.Message]  # preallocated, one per drive
    _sync_counted: bool  # else SYNC has no data
    _sync_top: int
    _sync_msg: can.Message
    _heartbeat_msg: can.Message
    _heartbeat_ticks: int
    _heartbeat_countdown: int
    _sync_sent_s: float
    _latency_s: array.array[float]
    _latency_index: int
    latency_samples: int
    _send_failed: bool
    _command: list[DriveCommand]
    _controlword: list[int]  # goes out with the next send()
    _controlword_after: list[int]  # ... and from the one after on
    _controlword_sent: list[int]
    _rpdo_before: list[bytearray]

    def command(self, joint: Joint | None, command: DriveCommand) -> None:
        """Send ``command``'s controlword to one drive (None: both) from the next send() on.

        Repeating the current command changes nothing. FAULT_RESET sends 0, then
        0x80 (held); asked again once 0x80 went out, it makes a new edge.
        """
        if command is not DriveCommand.ENABLE_OPERATION:
            self._enabled_expected = False
        for j in JOINTS if joint is None else (joint,):
            if self._roboteq:
                self._power.command(j, command)
                self._update_fault(j)  # a fault reset clears a drive found lost
            elif command is DriveCommand.FAULT_RESET:
                self._fault_reset(j)
            elif command is not self._command[j]:
                self._controlword[j] = self._controlword_after[j] = command.value
            if command is DriveCommand.FAULT_RESET:
                self._left_enabled[j] = None  # judged again from the next arming on
                self._foreign_rpdo[j] = None  # judged again from the reset on
                self._update_fault(j)
            self._command[j] = command

    def path_to_enabled(self, state: DriveState) -> list[DriveCommand]:
        """The commands that bring a drive from ``state`` to OPERATION_ENABLED
        (:func:`rakectl.protocol.cia402.path_to_enabled`; a Roboteq-class drive switched off
        needs one, ENABLE_OPERATION, and one in FAULT a fault reset first)."""
        return power_path(state) if self._roboteq else path_to_enabled(state)

    def _fault_reset(self, j: int) -> None:
        in_progress = (self._command[j] is DriveCommand.FAULT_RESET
                       and self._controlword_sent[j] != FAULT_RESET_BIT)
        if not in_progress:
            self._controlword[j], self._controlword_after[j] = 0, FAULT_RESET_BIT

    def send(self, voltage_r_v: float, voltage_theta_v: float) -> None:
        """Pack and send both RPDO1s: the voltages and each drive's controlword.

        NonFiniteError for a NaN or infinite voltage, before anything is sent.
        """
        rpdo, controlword, sent = self._rpdo, self._controlword, self._controlword_sent
        before = self._rpdo_before  # what the last send carried: its echo may come late
        before[0][:] = rpdo[0].data
        before[1][:] = rpdo[1].data
        if self._roboteq:
            lost = self._power.send(self.feedback.state, self.feedback.statusword)
            if lost:
                self._power_lost(lost)
            r_per_mille = volts_to_per_mille(voltage_r_v, self._supply_v[0])
            theta_per_mille = volts_to_per_mille(voltage_theta_v, self._supply_v[1])
            pack_command_into(rpdo[0].data, r_per_mille)
            pack_command_into(rpdo[1].data, theta_per_mille)
        else:
            voltage_r_mv = voltage_v_to_mv(voltage_r_v)
            voltage_theta_mv = voltage_v_to_mv(voltage_theta_v)
            pack_rpdo_into(rpdo[0].data, voltage_r_mv, controlword[0])
            pack_rpdo_into(rpdo[1].data, voltage_theta_mv, controlword[1])
        self._send_failed = False
        self._transmit(rpdo[0])
        self._transmit(rpdo[1])
        sent[0], sent[1] = controlword
        controlword[0], controlword[1] = self._controlword_after

    def _latency(self, received_s: float) -> None:
        """SYNC → TPDO1 arrival, when the drain answers exactly one SYNC (ring, no allocation)."""
        if self._syncs_pending == 1 and received_s > self._sync_sent_s:
            i = self._latency_index
            self._latency_s[i] = received_s - self._sync_sent_s
            self._latency_index = 0 if i + 1 == LATENCY_RING else i + 1
            self.latency_samples += 1

    def sync_to_tpdo_s(self) -> list[float]:
        """The recorded SYNC → TPDO1 latencies (s), most recent ring's worth (off the hot path)."""
        return list(self._latency_s[:min(self.latency_samples, LATENCY_RING)])

    def sync(self) -> None:
        """Send SYNC with the next counter and, once per heartbeat period, the heartbeat."""
        counter = next_sync_counter(self._sync_counter, self._sync_top)
        self._sync_counter = counter
        if self._sync_counted:
            self._sync_msg.data[0] = counter
        self._sync_sent_s = time.time()
        self._transmit(self._sync_msg)
        self._syncs_pending += 1
        self.stats.syncs += 1
        self._heartbeat_countdown -= 1
        if self._heartbeat_countdown <= 0:
            self._heartbeat_countdown = self._heartbeat_ticks
            self._transmit(self._heartbeat_msg)

    def _transmit(self, msg: can.Message) -> None:
        try:
            self._bus.send(msg)
        except can.CanError as error:
            self.stats.send_errors += 1
            self.last_send_error = error
            self._send_failed = True
            if self.on_send_error is not None:
                self.on_send_error(msg, error)
            return
        self.stats.sends += 1
        if self._trace is not None:
            self._trace.record(msg, False)

    def send_failed(self) -> bool:
        """Whether a send of this tick (send() and sync() since the last send()) failed."""
        return self._send_failed

    def start_node(self, joint: Joint) -> None:
        """NMT start to one drive now (the daemon repeats it while a drive is not yet
        OPERATIONAL: on a lossy bus the bring-up's NMT start can be lost)."""
        node = node_ids(self._drives)[joint]
        self._transmit(can.Message(arbitration_id=NMT_COB_ID, is_extended_id=False,
                                   data=encode_nmt(NmtCommand.START, node)))
