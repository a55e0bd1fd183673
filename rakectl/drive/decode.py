"""The drive client's receive side: each frame a drive sends, decoded into
:class:`~rakectl.drive.health.Feedback` and the per-drive fault flags, on the hot path.

:class:`FrameDecoder` is a base of :class:`~rakectl.drive.client.DriveClient`, which owns
the attributes declared below (set up in its constructor) and drains the bus
(:meth:`~rakectl.drive.client.DriveClient.receive`); each handler here takes one frame's
data, counts a frame of the wrong length or undecodable content, and never raises. A
TPDO1 has one layout in both drive profiles (i32, i16, i16: the current's unit differs);
a TPDO2 is a CiA 402 statusword and error register, or a Roboteq-class drive's flags read
as the CiA 402 state that behaves the same (:mod:`rakectl.protocol.roboteq`).
"""

from __future__ import annotations

from collections.abc import Callable

import can

from rakectl.drive.health import DriveSupervision, Stats
from rakectl.drive.power import PowerRequests
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveState, decode_statusword
from rakectl.protocol.codec import TPDO1_SIZE, decode_tpdo1, decode_tpdo2
from rakectl.protocol.nmt import EMCY_SIZE, EmcyCode, NmtState, decode_emcy, decode_heartbeat

CAN_ERR_BUSOFF = 0x040  # error class of a socketcan error frame (linux/can/error.h)


class FrameDecoder(DriveSupervision):
    """The frame handlers of :class:`~rakectl.drive.client.DriveClient` (module docstring)."""

    stats: Stats
    clock: Callable[[], float]
    _roboteq: bool
    _units_per_amp: float  # TPDO1's current in its unit, per ampere
    _tpdo2_size: int
    _position_per_count: list[float]
    _velocity_per_rpm: list[float]
    _sync_counter: int
    _syncs_pending: int
    _fresh: list[int]
    _answered: int
    _power: PowerRequests
    _tpdo2_after_emcy: list[bool]
    _enabled_expected: bool
    _operational: bool

    def _count_stale(self) -> None:
        fresh, stale, stats = self._fresh, self.feedback.stale_cycles, self.stats
        received = stats.tpdo_received
        answered = received[0] if received[0] < received[1] else received[1]
        self.feedback.samples = answered - self._answered
        self._answered = answered
        for j in (0, 1):
            if fresh[j]:
                stale[j] = 0
                if fresh[j] > 1:
                    stats.tpdo_late[j] += fresh[j] - 1
            elif self._syncs_pending:
                stale[j] += 1
                stats.tpdo_missed[j] += 1
        self._syncs_pending = 0

    def _on_tpdo1(self, j: int, data: bytearray) -> None:
        if len(data) != TPDO1_SIZE:
            self.stats.frames_bad_length += 1
            self.stats.tpdo1_bad_length[j] = len(data)  # named if the feedback goes stale
            return
        counts, rpm, current_ma = decode_tpdo1(data)
        fb = self.feedback
        position = counts * self._position_per_count[j]
        velocity = rpm * self._velocity_per_rpm[j]
        if j == 0:
            fb.r_m, fb.r_vel_m_per_s = position, velocity
            fb.current_r_a = current_ma / self._units_per_amp
        else:
            fb.theta_rad, fb.theta_vel_rad_per_s = position, velocity
            fb.current_theta_a = current_ma / self._units_per_amp
        fb.sync_counter[j] = self._sync_counter
        self._fresh[j] += 1
        stats = self.stats
        stats.tpdo_received[j] += 1
        stats.tpdo1_bad_length[j] = 0

    def _on_tpdo2(self, j: int, data: bytearray) -> None:
        if len(data) != self._tpdo2_size:
            self.stats.frames_bad_length += 1
            return
        if self._roboteq:
            statusword = roboteq.flags_image(*roboteq.decode_flags(data))
            state = roboteq.state_of(statusword)
            error_register = 1 if state is DriveState.FAULT else 0  # bit 0: generic error
        else:
            statusword, error_register = decode_tpdo2(data)
            state = decode_statusword(statusword)
        fb = self.feedback
        fb.statusword[j], fb.error_register[j], fb.state[j] = statusword, error_register, state
        self._state_fault[j] = state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
        # latched: the next RPDO1 would enable it again (a Roboteq-class drive's watchdog
        # lets go at the next command: its expiry may be gone within the same drain)
        if self._enabled_expected and state is not DriveState.OPERATION_ENABLED and (
                not self._roboteq or state is DriveState.FAULT):
            self._left_enabled[j], self._left_status[j] = state, statusword
        self._tpdo2_after_emcy[j] = True
        self._update_fault(j)
        self.stats.tpdo2_received[j] += 1

    def _on_emcy(self, j: int, data: bytearray) -> None:
        if len(data) != EMCY_SIZE:
            self.stats.frames_bad_length += 1
            return
        emcy = decode_emcy(data)
        self.feedback.last_emcy[j] = emcy
        self._emcy_fault[j] = emcy.code != EmcyCode.NO_ERROR
        self._tpdo2_after_emcy[j] = False
        self._update_fault(j)
        self.stats.emcy_received += 1

    def _on_heartbeat(self, j: int, data: bytearray) -> None:
        if len(data) != 1:
            self.stats.frames_bad_length += 1
            return
        state = decode_heartbeat(data)
        self.feedback.nmt_state[j] = state
        self._heard_s[j] = self.clock()
        if state is NmtState.BOOT_UP:
            self._rebooted[j] = True
        self._nmt_fault[j] = self._operational and state is not NmtState.OPERATIONAL
        if self._operational and state is NmtState.PRE_OPERATIONAL:
            self._unconfigured[j] = True  # latched: what a drive restarted unseen says
        self._update_fault(j)
        self.stats.heartbeats_received += 1

    def _on_odd_frame(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.stats.error_frames += 1
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self.stats.bus_off_frames += 1
        else:
            self.stats.frames_unknown += 1

    def _update_fault(self, j: int) -> None:
        self._fault[j] = (self._state_fault[j] or self._emcy_fault[j] or self._rebooted[j]
                          or self._unconfigured[j]
                          or self._power.lost[j] or self._left_enabled[j] is not None
                          or self._nmt_fault[j] or self._foreign_rpdo[j] is not None)

    def _on_foreign_rpdo(self, j: int, msg: can.Message) -> None:
        """An RPDO1 on drive ``j``'s COB-ID that is not the echo of the last one sent:
        another node commands the drive (the last RPDO1 before a SYNC is the one it
        applies), a fault latched until a fault reset (rare: allocates)."""
        self.stats.foreign_rpdos[j] += 1
        if self._foreign_rpdo[j] is None:
            self._foreign_rpdo[j] = bytes(msg.data)
            self._update_fault(j)

    def _power_lost(self, drives: int) -> None:
        """Roboteq-class drives that went off by themselves while asked on (bit j): a fault
        until a fault reset (rakectl.drive.power)."""
        for j in (0, 1):
            if drives >> j & 1:
                self._update_fault(j)
