"""The power requests that stand in for the controlword on a Roboteq-class drive
(``drives.profile: roboteq``): it has no CiA 402 state machine, so
:meth:`~rakectl.drive.client.DriveClient.command` maps each CiA 402 command onto its
power stage, switched on by *release shutdown* (0x200D) and off by *emergency shutdown*
(0x200C), each one expedited SDO download (:mod:`rakectl.protocol.roboteq`).

* ENABLE_OPERATION asks for the power stage on; every other command for it off.
* FAULT_RESET sends a release at once (it clears the fault flags whose cause is gone)
  and asks for the power stage off, as a CiA 402 fault reset ends in SWITCH ON DISABLED;
  asked again, it sends another release once ``REQUEST_TICKS`` have passed.
* Each tick (:meth:`PowerRequests.send`, after the RPDOs), a request goes out while the
  drive's flags (its TPDO2, read as a CiA 402 state) do not show it, at most every
  ``REQUEST_TICKS``: a request or its answer lost on the bus is made again. A drive in
  FAULT is not released by an ENABLE_OPERATION: only a fault reset does that.

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


class PowerRequests:
    """Both drives' power stages as asked for, and the frames that ask."""

    def __init__(self, node_ids: Sequence[int], transmit: Callable[[can.Message], None]) -> None:
        self._transmit = transmit
        self._want_on = [False, False]
        self._countdown = [0, 0]  # ticks until a request may be made again
        self._reset_countdown = [0, 0]  # ticks until a fault reset may send another release
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
        if command is DriveCommand.FAULT_RESET:
            if self._reset_countdown[j] == 0:
                self._transmit(self._frames[j][0])
                self._reset_countdown[j] = REQUEST_TICKS
            self._countdown[j] = 0
        if want_on is not self._want_on[j]:
            self._countdown[j] = 0
        self._want_on[j] = want_on

    def send(self, states: Sequence[DriveState | None]) -> None:
        """Once per tick: a request for each drive whose flags do not show it yet."""
        countdown, reset_countdown = self._countdown, self._reset_countdown
        for j in (0, 1):
            if reset_countdown[j] > 0:
                reset_countdown[j] -= 1
            if countdown[j] > 0:
                countdown[j] -= 1
                continue
            on = states[j] is DriveState.OPERATION_ENABLED
            if self._want_on[j] and not on and states[j] is not DriveState.FAULT:
                self._transmit(self._frames[j][0])
            elif not self._want_on[j] and on:
                self._transmit(self._frames[j][1])
            else:
                continue
            countdown[j] = REQUEST_TICKS


def path_to_enabled(state: DriveState) -> list[DriveCommand]:
    """A Roboteq-class drive's commands from ``state`` to OPERATION_ENABLED: switched off,
    one (ENABLE_OPERATION); in FAULT, a fault reset first."""
    if state is DriveState.SWITCH_ON_DISABLED:
        return [DriveCommand.ENABLE_OPERATION]
    if state is DriveState.FAULT:
        return [DriveCommand.FAULT_RESET, DriveCommand.ENABLE_OPERATION]
    return []
