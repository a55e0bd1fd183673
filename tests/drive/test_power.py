"""The power requests that stand in for a Roboteq-class drive's controlword
(rakectl.drive.power), tick by tick against the states and flags a drive reports: what
is sent, when it is made again, and when a drive counts as lost."""

from __future__ import annotations

import can

from rakectl.drive.power import REQUEST_TICKS, PowerRequests, path_to_enabled
from rakectl.protocol import roboteq
from rakectl.protocol.cia402 import DriveCommand, DriveState

OFF, ON, FAULT = DriveState.SWITCH_ON_DISABLED, DriveState.OPERATION_ENABLED, DriveState.FAULT
STOPPED = roboteq.FAULT_EMERGENCY_STOP << 16  # the emergency stop flag in a flags image
RELEASE, SHUTDOWN = roboteq.RELEASE_SHUTDOWN, roboteq.EMERGENCY_SHUTDOWN


class Wire:
    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []

    def transmit(self, msg: can.Message) -> None:
        self.sent.append((msg.arbitration_id, bytes(msg.data)))

    def take(self) -> list[tuple[int, bytes]]:
        sent, self.sent = self.sent, []
        return sent


def ticks(power: PowerRequests, count: int, r: tuple[DriveState | None, int],
          theta: tuple[DriveState | None, int] = (OFF, STOPPED)) -> int:
    lost = 0
    for _ in range(count):
        lost |= power.send((r[0], theta[0]), (r[1], theta[1]))
    return lost


def test_a_release_is_made_again_until_the_drive_shows_it_on_and_never_after() -> None:
    wire = Wire()
    power = PowerRequests((1, 2), wire.transmit)
    power.command(0, DriveCommand.ENABLE_OPERATION)
    ticks(power, REQUEST_TICKS + 1, (OFF, STOPPED))  # the first one was lost
    assert wire.take() == [(0x601, RELEASE), (0x601, RELEASE)]
    assert ticks(power, 5, (ON, 0)) == 0 and not power.lost[0]
    assert ticks(power, 1, (OFF, STOPPED)) == 1  # off by itself: lost, not released
    ticks(power, 3 * REQUEST_TICKS, (OFF, STOPPED))
    assert wire.take() == [] and power.lost == [True, False]
    power.command(0, DriveCommand.ENABLE_OPERATION)  # the daemon asking again changes nothing
    ticks(power, REQUEST_TICKS + 1, (OFF, STOPPED))
    assert wire.take() == [] and power.lost[0]


def test_a_drive_asked_off_is_shut_down_in_any_state_but_switched_off() -> None:
    wire = Wire()
    power = PowerRequests((1, 2), wire.transmit)
    power.command(0, DriveCommand.DISABLE_VOLTAGE)
    ticks(power, 1, (FAULT, roboteq.STATUS_WATCHDOG_EXPIRED))  # stopped by its watchdog
    assert wire.take() == [(0x601, SHUTDOWN)]
    ticks(power, REQUEST_TICKS, (ON, 0))  # made again while the flag does not show
    assert wire.take() == [(0x601, SHUTDOWN)]
    ticks(power, 3 * REQUEST_TICKS, (OFF, STOPPED))
    assert wire.take() == []


def test_a_fault_reset_releases_and_shuts_down_and_does_so_again_while_faulted() -> None:
    wire = Wire()
    power = PowerRequests((1, 2), wire.transmit)
    power.command(0, DriveCommand.ENABLE_OPERATION)
    ticks(power, 1, (ON, 0))
    ticks(power, 1, (FAULT, roboteq.FAULT_COMMUNICATION << 16))
    assert power.lost[0]
    wire.take()
    power.command(0, DriveCommand.FAULT_RESET)
    assert wire.take() == [(0x601, RELEASE), (0x601, SHUTDOWN)] and not power.lost[0]
    power.command(0, DriveCommand.FAULT_RESET)  # asked again at once: not yet
    ticks(power, REQUEST_TICKS, (FAULT, roboteq.FAULT_COMMUNICATION << 16))  # refused
    assert wire.take() == [(0x601, RELEASE), (0x601, SHUTDOWN)]
    ticks(power, 3 * REQUEST_TICKS, (OFF, STOPPED))  # cleared, off
    assert wire.take() == []


def test_the_path_to_enabled() -> None:
    assert path_to_enabled(OFF) == [DriveCommand.ENABLE_OPERATION]
    assert path_to_enabled(FAULT) == [DriveCommand.FAULT_RESET, DriveCommand.ENABLE_OPERATION]
    assert path_to_enabled(ON) == []


def test_asked_off_while_a_release_awaits_its_answer_shuts_down_at_once() -> None:
    """Disarm, e-stop, a fault or the daemon's exit within 50 ticks of arming: the
    shutdown waited out the release's REQUEST_TICKS (49 ms with the power stage on), and
    the exit's one last send never made it."""
    wire = Wire()
    power = PowerRequests((1, 2), wire.transmit)
    power.command(0, DriveCommand.ENABLE_OPERATION)
    ticks(power, 1, (OFF, STOPPED))
    assert wire.take() == [(0x601, RELEASE)]
    ticks(power, 2, (ON, 0))
    power.command(0, DriveCommand.QUICK_STOP)
    ticks(power, 1, (ON, 0))
    assert wire.take() == [(0x601, SHUTDOWN)]
    power.command(0, DriveCommand.ENABLE_OPERATION)  # asked on again at once: the same
    ticks(power, 1, (OFF, STOPPED))
    assert wire.take() == [(0x601, RELEASE)]
