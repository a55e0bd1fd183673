"""The NMT side of the drives' bring-up (rakectl.drive.bringup): the drives' heartbeats
heard, NMT commands sent, reset communication repeated until the boot-up comes, NMT start
repeated until the heartbeat says OPERATIONAL, and the boot-ups counted since the reset
(a drive that restarted after its configuration holds its power-on values).

It sends through ``network.send_message`` and waits on events that the network's
callbacks set, so it works with a Notifier thread and with a network that delivers
synchronously.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import can
import canopen

from rakectl.drive.canbus import BusError
from rakectl.drive.joints import JOINTS, Joint
from rakectl.errors import CommsTimeout
from rakectl.protocol.codec import NMT_COB_ID, FunctionCode, cob_id
from rakectl.protocol.nmt import NmtCommand, NmtState, encode_nmt

ATTEMPTS = 3  # an NMT command awaited is sent this often, the timeout over all


class NmtLink:
    """Heartbeats and NMT commands of the drives (node-ID by :class:`Joint`)."""

    def __init__(self, network: canopen.Network, node_id: dict[Joint, int],
                 label: Callable[[Joint], str], timeout_s: float) -> None:
        """Subscribes to the drives' heartbeats; ``timeout_s``: how long a boot-up or an
        OPERATIONAL heartbeat is awaited, over all attempts."""
        self._network, self._node_id, self._label = network, node_id, label
        self._timeout_s = timeout_s
        self._joint_of_node = {node: joint for joint, node in node_id.items()}
        self._heard = {joint: threading.Event() for joint in JOINTS}  # anything from it
        self._booted = {joint: threading.Event() for joint in JOINTS}
        self._operational = {joint: threading.Event() for joint in JOINTS}
        self._boot_ups = dict.fromkeys(JOINTS, 0)  # boot-ups heard, and at the reset's
        self._boot_ups_at_reset = dict.fromkeys(JOINTS, 0)
        for node in node_id.values():
            network.subscribe(cob_id(FunctionCode.HEARTBEAT, node), self._on_heartbeat)

    def close(self) -> None:
        """Unsubscribe from the network."""
        for node in self._node_id.values():
            self._network.unsubscribe(cob_id(FunctionCode.HEARTBEAT, node), self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        joint = self._joint_of_node[can_id & 0x7F]
        self._heard[joint].set()
        if len(data) != 1:
            return
        if data[0] == NmtState.BOOT_UP:
            self._boot_ups[joint] += 1  # before the event: a waiter then reads it counted
            self._booted[joint].set()
        elif data[0] == NmtState.OPERATIONAL:
            self._operational[joint].set()

    def send(self, joint: Joint, command: NmtCommand) -> None:
        try:
            self._network.send_message(NMT_COB_ID, encode_nmt(command, self._node_id[joint]))
        except can.CanError as error:
            raise BusError(f"{self._label(joint)}: cannot send NMT {command.name}: "
                           f"{error}") from error

    def reset_communication(self, joint: Joint) -> None:
        """NMT reset communication until its boot-up comes (either frame may be lost, or the
        drive still be powering up: the boot-up it sends at power-on counts too):
        ``ATTEMPTS`` times, ``timeout_s`` over all; then CommsTimeout naming whether
        anything at all was heard from the drive."""
        booted, wait_s = self._booted[joint], self._timeout_s / ATTEMPTS
        for _ in range(ATTEMPTS):
            booted.clear()
            self.send(joint, NmtCommand.RESET_COMMUNICATION)
            if booted.wait(wait_s):
                self._boot_ups_at_reset[joint] = self._boot_ups[joint]
                return
        if not self._heard[joint].is_set():
            raise CommsTimeout(f"{self._label(joint)}: no heartbeat or boot-up within "
                               f"{self._timeout_s:g} s (NMT reset communication sent "
                               f"{ATTEMPTS} times)")
        raise CommsTimeout(f"{self._label(joint)}: no boot-up after NMT reset communication "
                           f"within {self._timeout_s:g} s, {ATTEMPTS} times")

    def start(self, joint: Joint) -> None:
        """NMT start until its heartbeat says OPERATIONAL: ``ATTEMPTS`` times, ``timeout_s``
        over all; then CommsTimeout."""
        operational, wait_s = self._operational[joint], self._timeout_s / ATTEMPTS
        for _ in range(ATTEMPTS):
            operational.clear()
            self.send(joint, NmtCommand.START)
            if operational.wait(wait_s):
                return
        raise CommsTimeout(f"{self._label(joint)}: no OPERATIONAL heartbeat after NMT start "
                           f"within {self._timeout_s:g} s ({ATTEMPTS} times)")

    def boot_ups_since_reset(self, joint: Joint) -> int:
        """Boot-ups heard since :meth:`reset_communication`'s: a restart."""
        return self._boot_ups[joint] - self._boot_ups_at_reset[joint]
