"""The CAN link's bit rate as the kernel reports it (rakectl.drive.link), where this
kernel has no CAN link: what is not checked says why. A link with a rate, and a mismatch
refused, run on real SocketCAN (tests/vcan/test_link.py)."""

from __future__ import annotations

from rakectl.config.service import BusInterface, BusSettings
from rakectl.drive.link import check_link_bitrate, link_bitrate


def test_a_link_without_a_bit_rate_is_said_not_checked() -> None:
    assert link_bitrate("lo") == (None, "lo (no kind) has no bit rate of its own: not checked")
    assert link_bitrate("no-such-link") == (
        None, 'not checked: Device "no-such-link" does not exist.')
    for interface in (BusInterface.VIRTUAL, BusInterface.UDP_MULTICAST):
        assert check_link_bitrate(BusSettings(interface=interface, channel="lo")) == (
            f"{interface.value}: no link bit rate to check")
    assert check_link_bitrate(BusSettings(interface=BusInterface.SOCKETCAN, channel="lo")) == (
        "lo (no kind) has no bit rate of its own: not checked")
