"""The power requests that stand in for the controlword on a Roboteq-class drive
(``drives.profile: roboteq``): it has no CiA 402 state machine, so
:meth:`~rakectl.drive.client.DriveClient.command` maps each CiA 402 command onto its
power stage, switched on by *release shutdown* (0x200D) and off by *emergency shutdown*
(0x200C), each one expedited SDO download (:mod:`rakectl.protocol.roboteq`).

* ENABLE_OPERATION asks for the power stage on: a release goes out while the drive reads
  as switched off (its emergency stop flag), until it is seen on. From then on it is not
  released again: a drive that goes off by itself while asked on (an emergency stop the
  controller did not send, its watchdog, a fault) is *lost*, a fault of the client
  latched until a fault reset, and never switched back on behind the daemon's back.
* Every other command asks for it off: an emergency shutdown goes out while the drive's
  emergency stop flag is not set, whatever else it reads (in FAULT too: a fault cleared
  later must not leave it on).
* FAULT_RESET sends a release and an emergency shutdown back to back (the release clears
  the fault flags whose cause is gone, the shutdown leaves the power stage off, as a CiA
  402 fault reset ends in SWITCH ON DISABLED), clears *lost*, and sends the pair again
  while the drive still reads FAULT.
* Requests go out in :meth:`PowerRequests.send`, once per tick before the RPDOs, each at
  most every ``REQUEST_TICKS`` while the drive's flags (its TPDO2) do not show it yet: a
  request or its answer lost on the bus is made again. A request the other way (off
  while a release waits for its answer) goes out at the next send, not after the wait.

Sends through the client's ``transmit`` (counted, traced, never raising); allocates
nothing per tick.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import can

from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveCommand, DriveState
from rakectl.protocol.codec import FunctionCode, cob_id

REQUEST_TICKS = 50  # a request not yet shown by the drive's flags is made again this often
_STOPPED = roboteq.FAULT_EMERGENCY_STOP << 16  # the emergency stop flag in a flags image


class PowerRequests:
    """Both drives' power stages as asked for, and the frames that ask."""

    def __init__(self, node_ids: Sequence[int], transmit: Callable[[can.Message], None]) -> None:
        self._transmit = transmit
        self.lost = [False, False]  # went off by itself while asked on: latched
        self._want_on = [False, False]
        self._seen_on = [False, False]  # seen on since asked on
        self._resetting = [False, False]
        self._countdown = [0, 0]  # ticks until a request may be made again
        self._frames: list[tuple[can.Message, can.Message]] = []
        for node in node_ids:
            release, shutdown = (can.Message(arbitration_id=cob_id(FunctionCode.SDO_REQUEST, node),
                                             is_extended_id=False, data=bytearray(frame))
                                 for frame in (roboteq.RELEASE_SHUTDOWN,
                                               roboteq.EMERGENCY_SHUTDOWN))
            self._frames.append((release, shutdown))

    def command(self, j: int, command: DriveCommand) -> None:
        """What ``command`` asks of drive ``j``'s power stage (the module docstring)."""
        want_on = command is DriveCommand.ENABLE_OPERATION
        if want_on is not self._want_on[j]:  # asked the other way: at once, not after the
            self._countdown[j] = 0  # wait for the last request's answer (50 ms)
            if want_on:
                self._seen_on[j] = False
        self._want_on[j] = want_on
        if command is DriveCommand.FAULT_RESET:  # asked again: again once the last is old
            self.lost[j] = False
            if not self._resetting[j] or self._countdown[j] == 0:
                self._reset(j)
            self._resetting[j] = True
        else:
            self._resetting[j] = False

    def send(self, states: Sequence[DriveState | None], images: Sequence[int]) -> int:
        """Once per tick, before the RPDOs: a request for each drive whose flags do not show
        it yet. Returns a bit per drive newly found *lost* (bit j)."""
        newly_lost = 0
        countdown = self._countdown
        for j in (0, 1):
            on = states[j] is DriveState.OPERATION_ENABLED
            if self._want_on[j]:
                if on:
                    self._seen_on[j] = True
                elif self._seen_on[j] and not self.lost[j]:
                    self.lost[j] = True
                    newly_lost |= 1 << j
            if countdown[j] > 0:
                countdown[j] -= 1
                continue
            if self._want_on[j]:
                if self._seen_on[j] or states[j] is not DriveState.SWITCH_ON_DISABLED:
                    continue
                self._transmit(self._frames[j][0])
            elif self._resetting[j] and states[j] is DriveState.FAULT:
                self._reset(j)
            elif not images[j] & _STOPPED:
                self._transmit(self._frames[j][1])
            else:
                continue
            countdown[j] = REQUEST_TICKS - 1  # made again REQUEST_TICKS ticks later
        return newly_lost

    def _reset(self, j: int) -> None:
        release, shutdown = self._frames[j]
        self._transmit(release)
        self._transmit(shutdown)
        self._countdown[j] = REQUEST_TICKS - 1


def path_to_enabled(state: DriveState) -> list[DriveCommand]:
    """A Roboteq-class drive's commands from ``state`` to OPERATION_ENABLED: switched off,
    one (ENABLE_OPERATION); in FAULT, a fault reset first."""
    if state is DriveState.SWITCH_ON_DISABLED:
        return [DriveCommand.ENABLE_OPERATION]
    if state is DriveState.FAULT:
        return [DriveCommand.FAULT_RESET, DriveCommand.ENABLE_OPERATION]
    return []
