"""Bring-up (rakectl.drive.bringup) among frames that are not its drives' answers: a 29-bit
frame whose ID reads as a heartbeat or an SDO answer, an SDO answer naming another object
(another SDO client on the drive's channel, or a late answer to an earlier request).

Tier 3 (``virtual`` bus): the emulated drives of tests/drive/test_bringup_cia301.py,
whose bus edge puts the stray frames on the wire just before the r drive's own answer.
Before the mend, canopen took each of them as the drive's: "a boot-up during its
configuration, 3 times: it keeps restarting" for a 29-bit 0x701, "SDO abort 0x08000000
writing 0x2003 watchdog timeout = 3 ms: General error" for an abort of 0x1234:0, and a
download answer for 0x1234:0 as the acknowledgement of 0x2003's write.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar

import can
import pytest
from can.interfaces.virtual import VirtualBus

from rakectl.drive.bringup import run_bring_up
from rakectl.errors import CommsTimeout
from tests.drive.test_bringup_cia301 import (
    BOOT_TIMEOUT_S,
    DRIVES,
    MOTORS,
    R_NODE,
    drives_on_a_bus,
    sdo_read,
)

WATCHDOG_ACK = (0x580 + R_NODE, b"\x60\x03\x20\x00")  # the r drive's answer to 0x2003's write
OTHER_ABORT = b"\x80\x34\x12\x00\x00\x00\x00\x08"  # abort 0x08000000 of 0x1234:0
OTHER_ACK = b"\x60\x34\x12\x00\x00\x00\x00\x00"  # a download answer for 0x1234:0


def frame(can_id: int, data: bytes, extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=extended)


class StraysBeforeAnAnswer(VirtualBus):
    """The drives' bus edge: ``strays`` go out just before each frame that starts as
    ``before`` (CAN-ID, first bytes); with ``drop``, that frame itself is lost."""

    before: ClassVar[tuple[int, bytes]] = WATCHDOG_ACK
    strays: ClassVar[tuple[can.Message, ...]] = ()
    drop: ClassVar[bool] = False

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        self.sent_strays = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        can_id, start = self.before
        if msg.arbitration_id == can_id and bytes(msg.data).startswith(start):
            for stray in self.strays:
                super().send(stray, timeout)
                self.sent_strays += 1
            if self.drop:
                return
        super().send(msg, timeout)


@pytest.mark.parametrize("strays", [
    (frame(0x580 + R_NODE, OTHER_ABORT),),
    (frame(0x580 + R_NODE, OTHER_ACK),),
    (frame(0x700 + R_NODE, b"\x00", extended=True),  # a "boot-up", 29 bits
     frame(0x580 + R_NODE, OTHER_ABORT, extended=True),
     frame(0x580 + R_NODE, b"\x80\x03\x20\x00\x00\x00\x00\x08", extended=True)),
], ids=["abort-of-another-object", "answer-for-another-object", "29-bit-frames"])
def test_answers_not_the_drives_own_are_not_taken_for_them(
        monkeypatch: pytest.MonkeyPatch, strays: tuple[can.Message, ...]) -> None:
    monkeypatch.setattr(StraysBeforeAnAnswer, "strays", strays)
    with drives_on_a_bus(emulator_bus_class=StraysBeforeAnAnswer) as (emulator, bus):
        infos = run_bring_up(bus, DRIVES, MOTORS, BOOT_TIMEOUT_S)
        assert emulator.bus.sent_strays >= len(strays)
        assert infos[0].limits.watchdog_timeout_ms == DRIVES.watchdog_timeout_ms
        assert sdo_read(bus, R_NODE, 0x2003) == DRIVES.watchdog_timeout_ms


def test_a_transfer_left_with_another_objects_answer_times_out_naming_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The drive's own answers to 0x2003's write all lost, another object's answer each
    time instead: no acknowledgement taken from it; the timeout names what came."""
    monkeypatch.setattr(StraysBeforeAnAnswer, "strays", (frame(0x580 + R_NODE, OTHER_ACK),))
    monkeypatch.setattr(StraysBeforeAnAnswer, "drop", True)
    drives = replace(DRIVES, sdo_timeout_s=0.05)
    with drives_on_a_bus(emulator_bus_class=StraysBeforeAnAnswer) as (_, bus), pytest.raises(
            CommsTimeout) as raised:
        run_bring_up(bus, drives, MOTORS, BOOT_TIMEOUT_S)
    assert str(raised.value) == (
        "r drive (node 1): no SDO response writing 0x2003 watchdog timeout = 3 ms within "
        "0.05 s (ignored, naming other objects: download answer for 0x1234:0, download "
        "answer for 0x1234:0, download answer for 0x1234:0, …)")
