"""The daemon and the emulated drives in one process, lock-step (rakectl.bench.tick's rig):
what absurd feedback does, and that a reset really restarts."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from rakectl.bench.tick import LockstepRig
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from rakectl.protocol import codec
from tests.rig_commands import command, disarmed_rig


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[LockstepRig]:
    with disarmed_rig(tmp_path) as rig:
        yield rig


def _absurd_tpdo1(rig: LockstepRig) -> None:
    """A TPDO1 of the r drive with position 2^31 − 1 counts, as the drive's own bus sends."""
    frame = can.Message(arbitration_id=0x181, is_extended_id=False,
                        data=codec.encode_tpdo1(2**31 - 1, 0, 0))
    rig.emulator_bus.send(frame)
    rig.tick()


def test_absurd_feedback_is_named_and_a_reset_arms_again(rig: LockstepRig) -> None:
    daemon = rig.daemon
    command(rig, b'{"cmd": "arm"}')
    rig.until(DaemonState.ARMED, 6000)
    _absurd_tpdo1(rig)
    assert daemon.state is DaemonState.FAULT
    assert daemon.fault_reason.startswith("implausible feedback: r drive (node 1) reports ")
    assert "outside 0.3 … 1.65 m" in daemon.fault_reason
    for _ in range(50):
        rig.tick()  # the drive's next TPDO1s are plausible again
    command(rig, b'{"cmd": "reset"}')
    rig.until(DaemonState.DISARMED, 1500)
    command(rig, b'{"cmd": "arm"}')
    for _ in range(1000):  # before the fix, the clamp's latch faulted every arm at once
        rig.tick()
    assert daemon.state is DaemonState.ARMED, daemon.fault_reason


def test_a_non_finite_voltage_at_the_bus_is_a_fault_not_the_end_of_the_loop(
        rig: LockstepRig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The clamp sends only finite voltages; were a bug to hand the drive client a NaN,
    the tick faults, sends 0 V instead and the loop goes on."""
    daemon = rig.daemon
    command(rig, b'{"cmd": "arm"}')
    rig.until(DaemonState.ARMED, 6000)
    monkeypatch.setattr(daemon, "_control", lambda: (math.nan, 1.0))
    rig.tick()
    assert daemon.state is DaemonState.FAULT
    assert daemon.fault_reason.startswith("non-finite voltage at the bus: ")
    assert daemon.voltages == (0.0, 0.0)
    for _ in range(20):
        rig.tick()  # the loop goes on, the drives read 0 V
    assert [node.output_voltage_v for node in rig.emulator.nodes] == [0.0, 0.0]


def test_arming_on_absurd_feedback_is_refused_naming_it(rig: LockstepRig) -> None:
    frame = can.Message(arbitration_id=0x182, is_extended_id=False,
                        data=codec.encode_tpdo1(-(2**31) + 1, 0, 0))
    rig.emulator_bus.send(frame)
    rig.daemon.tick()  # no emulator service: the absurd frame is the last one read
    with pytest.raises(CommandRejected, match=r"cannot arm: implausible feedback: θ drive "
                                              r"\(node 2\) reports"):
        command(rig, b'{"cmd": "arm"}')
    assert rig.daemon.state is DaemonState.DISARMED
