"""The CAN link's bit rate read from the kernel (rakectl.drive.link), on real SocketCAN.

vcan has no bit rate; a real controller does. A serial-line CAN interface (the kernel's
slcan driver, Linux 6.0 and later) on a pseudo-terminal is one the kernel sets a bit rate
on (``ip link set … type can bitrate``) with no adapter behind it: a link running at
another rate than ``bus.bitrate`` is refused by ``rakectl run --check`` and by the daemon
before it opens the bus, naming both rates.
"""

from __future__ import annotations

import fcntl
import os
import struct
import subprocess
import sys
import termios
from collections.abc import Iterator
from pathlib import Path

import pytest

from rakectl.config.service import BusInterface, BusSettings
from rakectl.drive.link import check_link_bitrate
from rakectl.errors import ConfigError
from tests.vcan.vcan_bench import CHANNEL, vcan_unavailable

N_SLCAN = 17  # the serial-line CAN line discipline (include/uapi/linux/tty.h)
SIOCGIFNAME = 0x8910  # the tty's network interface's name, as slcan answers it
ROOT = Path(__file__).resolve().parents[2]

_reason = vcan_unavailable()
pytestmark = [pytest.mark.vcan,
              pytest.mark.skipif(_reason is not None, reason=f"no SocketCAN: {_reason}")]


@pytest.fixture
def slcan_at_500k() -> Iterator[str]:
    """An slcan interface at 500 kbit/s, down (its rate is set while it is down); gone when
    its terminal closes."""
    subprocess.run(["modprobe", "slcan"], check=True, capture_output=True)
    master, slave = os.openpty()
    try:
        fcntl.ioctl(slave, termios.TIOCSETD, struct.pack("i", N_SLCAN))
        name = fcntl.ioctl(slave, SIOCGIFNAME, bytes(16)).rstrip(b"\0").decode()
        subprocess.run(["ip", "link", "set", name, "type", "can", "bitrate", "500000"],
                       check=True, capture_output=True)
        yield name
    finally:
        os.close(slave)
        os.close(master)


def _rakectl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rakectl", *args], capture_output=True,
                          text=True, timeout=300, cwd=ROOT)


def test_a_link_at_another_bit_rate_is_refused_naming_both(slcan_at_500k: str,
                                                           tmp_path: Path) -> None:
    link = slcan_at_500k
    assert check_link_bitrate(BusSettings(interface=BusInterface.SOCKETCAN, channel=link,
                                          bitrate=500_000)) == (
        f"{link} runs at 500000 bit/s, as bus.bitrate says")
    expected = (f"bus.bitrate: 1000000 bit/s, but {link} runs at 500000 bit/s (ip -details "
                f"link show {link}); the link, the drives and bus.bitrate must agree "
                "(80-can0.network's BitRate=)")
    with pytest.raises(ConfigError) as refused:
        check_link_bitrate(BusSettings(interface=BusInterface.SOCKETCAN, channel=link))
    assert str(refused.value) == expected
    bus = ["--set", "bus.interface=socketcan", "--set", f"bus.channel={link}"]
    check = _rakectl("run", "--check", *bus)
    assert (check.returncode, check.stderr.strip()) == (2, f"rakectl: error: {expected}")
    daemon = _rakectl("run", *bus, "--set", f"daemon.socket_path={tmp_path / 'r.sock'}",
                      "--set", f"daemon.dump_dir={tmp_path}",
                      "--set", "daemon.startup_cyclictest_s=0")
    assert daemon.returncode == 2, daemon.stderr
    assert daemon.stderr.strip().splitlines()[-1] == f"rakectl: error: {expected}"
    assert not (tmp_path / "r.sock").exists()  # refused before the socket and the bus
    agreed = _rakectl("run", "--check", *bus, "--set", "bus.bitrate=500000")
    assert agreed.returncode == 0, agreed.stderr
    assert f"  link: {link} runs at 500000 bit/s, as bus.bitrate says" in agreed.stdout


def test_vcan_has_no_bit_rate_to_check() -> None:
    assert check_link_bitrate(BusSettings(interface=BusInterface.SOCKETCAN,
                                          channel=CHANNEL)) == (
        f"{CHANNEL} (vcan) has no bit rate of its own: not checked")
