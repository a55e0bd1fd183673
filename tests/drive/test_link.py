"""The CAN link's bit rate as the kernel reports it (rakectl.drive.link), read over
netlink. This kernel has no CAN link: links of other kinds in a private network
namespace, and what is not checked saying why. A CAN link's rate, and a mismatch
refused, on real SocketCAN: tests/vcan/test_link.py."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap

import pytest

from rakectl.config.service import BusInterface, BusSettings
from rakectl.drive.link import _attributes, check_link_bitrate, read_link


def _socketcan(channel: str) -> BusSettings:
    return BusSettings(interface=BusInterface.SOCKETCAN, channel=channel)


def test_a_link_without_a_bit_rate_is_said_not_checked() -> None:
    assert check_link_bitrate(_socketcan("lo")) == (
        None, "lo (no kind) has no bit rate of its own: not checked")
    assert check_link_bitrate(_socketcan("no-such-link")) == (
        None, "no-such-link: not checked: No such device")
    for interface in (BusInterface.VIRTUAL, BusInterface.UDP_MULTICAST):
        assert check_link_bitrate(BusSettings(interface=interface, channel="lo")) == (
            None, f"{interface.value}: no link bit rate to check")


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None,
                    reason="makes links in a private network namespace: root and unshare")
def test_the_kind_of_a_link_is_read_as_ip_reads_it() -> None:
    """A bridge and a veth pair, made in a private network namespace: their kinds as the
    kernel names them, against iproute2's own reading of the same links."""
    script = textwrap.dedent("""
        import json, subprocess
        from rakectl.drive.link import read_link
        subprocess.run(["ip", "link", "add", "rk-br", "type", "bridge"], check=True)
        subprocess.run(["ip", "link", "add", "rk-a", "type", "veth", "peer", "name", "rk-b"],
                       check=True)
        for name in ("rk-br", "rk-a", "lo"):
            ip = json.loads(subprocess.run(["ip", "-details", "-json", "link", "show", "dev",
                                            name], check=True, capture_output=True,
                                           text=True).stdout)[0]
            print(name, read_link(name), ip.get("linkinfo", {}).get("info_kind", ""))
    """)
    done = subprocess.run(["unshare", "-n", sys.executable, "-c", script],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["rk-br ('bridge', None) bridge",
                                        "rk-a ('veth', None) veth", "lo ('', None) "]


def test_a_malformed_attribute_is_refused_not_read_past() -> None:
    assert list(_attributes(b"\x08\x00\x01\x00abcd\x05\x00\x02\x00x\x00\x00\x00")) == [
        (1, b"abcd"), (2, b"x")]
    with pytest.raises(ValueError, match=r"^an attribute of 12 bytes at 0 of 8$"):
        list(_attributes(b"\x0c\x00\x01\x00abcd"))
    with pytest.raises(ValueError, match=r"^an attribute of 2 bytes at 0 of 4$"):
        list(_attributes(b"\x02\x00\x01\x00"))
    assert read_link("lo") == ("", None)
