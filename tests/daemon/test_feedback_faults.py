"""The daemon and the emulated drives in one process, lock-step (rakectl.bench.tick's rig):
what absurd feedback does, and that a reset really restarts."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from rakectl.api.schema import decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.states import DaemonState
from rakectl.errors import CommandRejected
from rakectl.protocol import codec


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[LockstepRig]:
    rig = LockstepRig(tmp_path)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        yield rig
    finally:
        rig.close()


def _command(rig: LockstepRig, line: bytes) -> dict[str, object]:
    request = decode_request(line)
    assert not isinstance(request, str), request
    return make_handler(rig.daemon)(request)


def _absurd_tpdo1(rig: LockstepRig) -> None:
    """A TPDO1 of the r drive with position 2^31 − 1 counts, as the drive's own bus sends."""
    frame = can.Message(arbitration_id=0x181, is_extended_id=False,
                        data=codec.encode_tpdo1(2**31 - 1, 0, 0))
    rig.emulator_bus.send(frame)
    rig.tick()


def test_absurd_feedback_is_named_and_a_reset_arms_again(rig: LockstepRig) -> None:
    daemon = rig.daemon
    _command(rig, b'{"cmd": "arm"}')
    rig.until(DaemonState.ARMED, 6000)
    _absurd_tpdo1(rig)
    assert daemon.state is DaemonState.FAULT
    assert daemon.fault_reason.startswith("implausible feedback: r drive (node 1) reports ")
    assert "outside 0.3 … 1.65 m" in daemon.fault_reason
    for _ in range(50):
        rig.tick()  # the drive's next TPDO1s are plausible again
    _command(rig, b'{"cmd": "reset"}')
    rig.until(DaemonState.DISARMED, 1500)
    _command(rig, b'{"cmd": "arm"}')
    for _ in range(1000):  # before the fix, the clamp's latch faulted every arm at once
        rig.tick()
    assert daemon.state is DaemonState.ARMED, daemon.fault_reason


def test_arming_on_absurd_feedback_is_refused_naming_it(rig: LockstepRig) -> None:
    frame = can.Message(arbitration_id=0x182, is_extended_id=False,
                        data=codec.encode_tpdo1(-(2**31) + 1, 0, 0))
    rig.emulator_bus.send(frame)
    rig.daemon.tick()  # no emulator service: the absurd frame is the last one read
    with pytest.raises(CommandRejected, match=r"cannot arm: implausible feedback: θ drive "
                                              r"\(node 2\) reports"):
        _command(rig, b'{"cmd": "arm"}')
    assert rig.daemon.state is DaemonState.DISARMED
