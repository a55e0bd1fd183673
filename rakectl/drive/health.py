"""What the controller knows of the two drives, and the checks over it: the records
:class:`~rakectl.drive.client.DriveClient` fills in on its hot path (:class:`Feedback`,
:class:`Stats`) and :class:`DriveSupervision`, its supervision checks and their wording.

Kept apart from the bus-facing part (rakectl.drive.client: set-up, receive, reset;
rakectl.drive.decode: the frames received; rakectl.drive.send: send, SYNC, commands):
the checks only read the per-drive fault flags and heartbeat times its receive path
keeps.
"""

from __future__ import annotations

import enum
import math

from rakectl.config.service import DrivesSettings
from rakectl.drive.joints import JOINTS, drive_label, node_ids
from rakectl.drive.power import PowerRequests
from rakectl.protocol.cia402 import DriveState
from rakectl.protocol.codec import TPDO1_SIZE
from rakectl.protocol.files import DriveProfile
from rakectl.protocol.nmt import Emcy, EmcyCode, NmtState, emcy_code
from rakectl.protocol.roboteq import STATUS_WATCHDOG_EXPIRED


class Feedback:
    """What the drives reported, updated in place by
    :meth:`~rakectl.drive.client.DriveClient.receive`.

    Joint values are NaN until the first TPDO1; per-drive lists are indexed by
    :class:`~rakectl.drive.joints.Joint`. ``sync_counter`` is the SYNC the last TPDO1
    answered (see rakectl.drive.client's docstring), 0 before the first. ``samples`` is
    how many sampling instants (SYNCs answered by both drives' TPDO1s) the joint values
    advanced in the last drain: 1 normally, 0 when a drive's answer is late, n > 1 when
    late answers arrive together (the values are the newest).
    """

    __slots__ = ("current_r_a", "current_theta_a", "error_register", "last_emcy", "nmt_state",
                 "r_m", "r_vel_m_per_s", "samples", "stale_cycles", "state", "statusword",
                 "sync_counter", "theta_rad", "theta_vel_rad_per_s")

    def __init__(self) -> None:
        self.r_m = math.nan
        self.theta_rad = math.nan
        self.r_vel_m_per_s = math.nan
        self.theta_vel_rad_per_s = math.nan
        self.current_r_a = math.nan
        self.current_theta_a = math.nan
        self.state: list[DriveState | None] = [None, None]
        self.statusword = [0, 0]
        self.error_register = [0, 0]
        self.stale_cycles = [0, 0]
        self.sync_counter = [0, 0]
        self.samples = 0
        self.last_emcy: list[Emcy | None] = [None, None]
        self.nmt_state: list[NmtState | None] = [None, None]


class Stats:
    """Counters of the hot path; per-drive lists are indexed by
    :class:`~rakectl.drive.joints.Joint`."""

    __slots__ = (
        "bus_off_frames",
        "emcy_received",
        "error_frames",
        "foreign_rpdos",
        "frames_bad_length",
        "frames_invalid",
        "frames_own",
        "frames_unknown",
        "heartbeats_received",
        "receive_errors",
        "sdo_answers",
        "send_errors",
        "sends",
        "syncs",
        "ticks",
        "tpdo1_bad_length",
        "tpdo2_received",
        "tpdo_late",
        "tpdo_missed",
        "tpdo_received",
    )

    def __init__(self) -> None:
        self.ticks = 0  # receive() calls
        self.syncs = 0
        self.tpdo_received = [0, 0]  # TPDO1
        self.tpdo_missed = [0, 0]  # SYNC cycles without a TPDO1
        self.tpdo_late = [0, 0]  # extra TPDO1s in one drain: one came a cycle late
        self.tpdo2_received = [0, 0]
        self.tpdo1_bad_length = [0, 0]  # the length of the last TPDO1 of a wrong length, 0: none
        self.frames_bad_length = 0
        self.frames_invalid = 0  # right length, undecodable content (FrameError)
        self.frames_unknown = 0
        self.frames_own = 0  # echoes of the controller's own frames (udp_multicast)
        self.foreign_rpdos = [0, 0]  # RPDO1s on a drive's COB-ID this controller did not send
        self.error_frames = 0
        self.bus_off_frames = 0
        self.emcy_received = 0
        self.heartbeats_received = 0
        self.receive_errors = 0
        self.sdo_answers = 0  # a Roboteq-class drive's answers to power requests
        self.sends = 0  # frames sent successfully
        self.send_errors = 0

    def as_dict(self) -> dict[str, int]:
        """Flat copy for a summary log line (off the hot path)."""
        flat: dict[str, int] = {}
        for name in sorted(self.__slots__):
            value = getattr(self, name)
            if isinstance(value, list):
                flat |= {f"{name}_{joint.name.lower()}": value[joint] for joint in JOINTS}
            else:
                flat[name] = value
        return flat


# TPDO1s a drive may answer beyond the SYNCs this controller sent before it is taken
# for another SYNC producer (none is expected: each TPDO1 answers one SYNC).
FOREIGN_SYNC_ANSWERS = 10


NMT_CAUSES = {  # why a started drive's heartbeat says a state, and what undoes it
    NmtState.STOPPED: "(an NMT command from another master; reset starts it again)",
    NmtState.PRE_OPERATIONAL: "(an NMT command from another master, or a restart whose "
                              "boot-up was lost, with its power-on values: restart the "
                              "service, whose bring-up configures it again)"}


class DriveSupervision:
    """The supervision of :class:`~rakectl.drive.client.DriveClient`, a base of it: cheap
    checks run each tick and, off the hot path, their wording.

    The attributes below are the client's: its receive path keeps them up to date.
    """

    feedback: Feedback
    stats: Stats
    _drives: DrivesSettings
    _heartbeat_timeout_s: float
    _heard_s: list[float]  # when each drive's heartbeat was last seen (the client's clock)
    _state_fault: list[bool]  # in FAULT or FAULT_REACTION_ACTIVE
    _emcy_fault: list[bool]  # an EMCY other than NO_ERROR is active
    _rebooted: list[bool]  # a boot-up heartbeat came after bring-up
    _power: PowerRequests  # its lost: a Roboteq-class drive went off by itself while on
    _left_enabled: list[DriveState | None]  # the state a drive left OPERATION ENABLED for
    _left_status: list[int]  # ... and the status it was read with
    _foreign_rpdo: list[bytes | None]  # the first RPDO1 another node sent the drive, latched
    last_receive_error: Exception | None  # the bus's, in the drain
    _nmt_fault: list[bool]  # a heartbeat not OPERATIONAL once the drives were started
    _unconfigured: list[bool]  # one said PRE-OPERATIONAL since: bring-up needed (latched)
    _answers_forgiven: int  # TPDO1s beyond the SYNCs sent, counted before the last reset
    _fault: list[bool]  # any of these

    def drive_faults(self) -> bool:
        """A drive is in FAULT (or its reaction), has an active EMCY, rebooted, went off by
        itself (Roboteq-class), left OPERATION ENABLED while armed, or is not NMT
        OPERATIONAL."""
        return self._fault[0] or self._fault[1]

    def stale_feedback(self, limit_cycles: int) -> bool:
        """A drive's TPDO1 has been missing for ``limit_cycles`` SYNC cycles or more."""
        stale = self.feedback.stale_cycles
        return stale[0] >= limit_cycles or stale[1] >= limit_cycles

    def answers_beyond_syncs(self) -> int:
        """How many more TPDO1s a drive answered than this controller sent SYNCs, since the
        last reset (``reset_faults``): more than a few means another node sends SYNC on
        this bus (another master, whose SYNCs double the drives' answers and the samples the
        force estimate counts)."""
        received, syncs = self.stats.tpdo_received, self.stats.syncs
        return max(received[0], received[1]) - syncs - self._answers_forgiven

    def _answers_beyond(self, j: int) -> int:
        """:meth:`answers_beyond_syncs` of drive ``j`` alone (off the hot path)."""
        return self.stats.tpdo_received[j] - self.stats.syncs - self._answers_forgiven

    def heartbeat_lost(self, now_s: float) -> bool:
        """A drive's heartbeat is older than the heartbeat timeout at ``now_s`` (same clock).

        Before the first heartbeat the reference is construction, or the end of bring-up.
        """
        heard, timeout = self._heard_s, self._heartbeat_timeout_s
        return now_s - heard[0] > timeout or now_s - heard[1] > timeout

    def _flags(self, status: int) -> str:
        """A Roboteq-class drive's flags image for a message, "" for a CiA 402 drive."""
        return flags_text(status) if self._drives.profile is DriveProfile.ROBOTEQ else ""

    def describe_problems(self, now_s: float, limit_cycles: int) -> list[str]:
        """One line per problem the supervision checks see (off the hot path)."""
        problems = []
        fb = self.feedback
        for joint, node in zip(JOINTS, node_ids(self._drives), strict=True):
            label = drive_label(joint, node)
            flags = self._flags(fb.statusword[joint])
            if self._state_fault[joint]:
                problems.append(f"{label}: state {state_name(fb.state[joint])}{flags}")
            left = self._left_enabled[joint]
            if left is not None:
                problems.append(f"{label}: left OPERATION ENABLED for {state_name(left)} while "
                                "armed (not by this daemon: another CANopen master, or the "
                                f"drive itself){self._flags(self._left_status[joint])}")
            foreign = self._foreign_rpdo[joint]
            if foreign is not None:
                problems.append(f"{label}: an RPDO1 on its COB-ID 0x{0x200 + node:03X} that this "
                                f"daemon did not send (data {foreign.hex()}): another node "
                                "commands the drive (another CANopen master)")
            nmt_state = fb.nmt_state[joint]
            latched = self._unconfigured[joint] and nmt_state is not NmtState.PRE_OPERATIONAL
            if self._nmt_fault[joint]:
                problems.append(f"{label}: its heartbeat says NMT {state_name(nmt_state)}, "
                                "not OPERATIONAL " + ("(an NMT command from another master)"
                                                      if latched else _nmt_cause(nmt_state)))
            emcy = fb.last_emcy[joint]
            if self._emcy_fault[joint] and emcy is not None:
                known = emcy_code(emcy.code)
                problems.append(f"{label}: EMCY 0x{emcy.code:04X} {known.name if known else '?'}, "
                                f"error register 0x{emcy.error_register:02X}"
                                + _EMCY_CAUSES.get(emcy.code, ""))
            if latched:
                problems.append(f"{label}: said NMT PRE OPERATIONAL after bring-up "
                                + NMT_CAUSES[NmtState.PRE_OPERATIONAL])
            if self._rebooted[joint]:
                problems.append(f"{label}: rebooted (boot-up heartbeat): bring-up needed")
            if self._power.lost[joint]:
                problems.append(f"{label}: its power stage went off by itself{flags}")
            extra, other = self._answers_beyond(joint), self._answers_beyond(1 - joint)
            if extra > FOREIGN_SYNC_ANSWERS:  # a foreign SYNC is answered by both drives
                problems.append(f"{label}: {extra} TPDO1s more than the SYNCs sent: " + (
                    "another node sends SYNC on this bus (another CANopen master)"
                    if other > FOREIGN_SYNC_ANSWERS // 2 else "the other drive's are not: "
                    "this one answers a SYNC more than once, or another node sends on its "
                    f"TPDO1 COB-ID (0x{0x180 + node:03X})"))
            if fb.stale_cycles[joint] >= limit_cycles:
                bad = self.stats.tpdo1_bad_length[joint]
                problems.append(f"{label}: no TPDO1 for {fb.stale_cycles[joint]} cycles"
                                + (f" (its last TPDO1 had {bad} bytes, {TPDO1_SIZE} expected:"
                                   " its PDO mapping was changed)" if bad else ""))
            if now_s - self._heard_s[joint] > self._heartbeat_timeout_s:
                problems.append(f"{label}: no heartbeat for {now_s - self._heard_s[joint]:.3f} s")
        stale = max(fb.stale_cycles) >= limit_cycles
        if stale and self.stats.receive_errors:  # what held the TPDO1s back, perhaps
            problems.append(f"the bus could not decode {self.stats.receive_errors} "
                            f"receptions since start-up (the last: {self.last_receive_error})")
        return problems


_EMCY_CAUSES: dict[int, str] = {  # what an EMCY's code says of its cause on this bus
    EmcyCode.SYNC_DATA_LENGTH: " (a SYNC of a length the drive does not take: another node "
    "sends SYNC, or drives.sync_counter_overflow is not the drive's)"}


def flags_text(image: int) -> str:
    """A Roboteq-class drive's flags image (:func:`rakectl.protocol.roboteq.flags_image`)
    for a message, naming an expired command watchdog, which no EMCY reports."""
    status = image & 0xFFFF
    expired = "; its command watchdog expired" if status & STATUS_WATCHDOG_EXPIRED else ""
    return f" (fault flags 0x{image >> 16:04X}, status flags 0x{status:04X}{expired})"


def state_name(state: enum.Enum | None) -> str:
    """A drive's CiA 402 or NMT state as its standard name (QUICK STOP ACTIVE), for a message."""
    return "unknown" if state is None else state.name.replace("_", " ")


def _nmt_cause(state: NmtState | None) -> str:
    return "(the drive's own)" if state is None else NMT_CAUSES.get(state, "(the drive's own)")
