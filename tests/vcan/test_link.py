"""The CAN link's bit rate read from the kernel (rakectl.drive.link), on real SocketCAN.

vcan has no bit rate; a real controller does. A serial-line CAN interface (the kernel's
slcan driver, Linux 6.0 and later) on a pseudo-terminal is one the kernel sets a bit rate
on (``ip link set … type can bitrate``) with no adapter behind it: a link with no rate set,
or running at another rate than ``bus.bitrate``, is refused by ``rakectl run --check``
and by the daemon before it claims its socket and opens the bus, naming both rates.
"""

from __future__ import annotations

import fcntl
import os
import struct
import subprocess
import termios
from collections.abc import Iterator
from pathlib import Path

import pytest

from rakectl.config.service import BusInterface, BusSettings
from rakectl.drive.link import check_link_bitrate
from rakectl.errors import ConfigError
from tests.cli_run import run_rakectl
from tests.vcan.vcan_bench import CHANNEL, vcan_unavailable

CLI_TIMEOUT_S = 300.0  # Python under the VM's software emulation
N_SLCAN = 17  # the serial-line CAN line discipline (include/uapi/linux/tty.h)
SIOCGIFNAME = 0x8910  # the tty's network interface's name, as slcan answers it

_reason = vcan_unavailable()
pytestmark = [pytest.mark.vcan,
              pytest.mark.skipif(_reason is not None, reason=f"no SocketCAN: {_reason}")]


@pytest.fixture
def slcan() -> Iterator[str]:
    """A new slcan interface, down, its bit rate not set; gone when its terminal closes."""
    if os.geteuid() != 0:
        pytest.skip("makes a CAN interface and sets its bit rate: root")
    if subprocess.run(["modprobe", "slcan"], capture_output=True).returncode != 0:
        pytest.skip("no slcan module in this kernel")
    master, slave = os.openpty()
    try:
        fcntl.ioctl(slave, termios.TIOCSETD, struct.pack("i", N_SLCAN))
        yield fcntl.ioctl(slave, SIOCGIFNAME, bytes(16)).rstrip(b"\0").decode()
    finally:
        os.close(slave)
        os.close(master)


def _socketcan(channel: str, bitrate: int = 1_000_000) -> BusSettings:
    return BusSettings(interface=BusInterface.SOCKETCAN, channel=channel, bitrate=bitrate)


def test_a_link_at_another_bit_rate_or_none_is_refused_naming_it(slcan: str,
                                                                 tmp_path: Path) -> None:
    link = slcan
    set_it = (f"ip link set {link} type can bitrate 1000000, or systemd-networkd's "
              "BitRate=, as in systemd/80-can0.network")
    with pytest.raises(ConfigError) as unset:
        check_link_bitrate(_socketcan(link))
    assert str(unset.value) == (f"bus.channel: {link} is a CAN controller whose bit rate is "
                                f"not set, and it cannot come up so ({set_it})")
    subprocess.run(["ip", "link", "set", link, "type", "can", "bitrate", "800000"],
                   check=True, capture_output=True)
    assert check_link_bitrate(_socketcan(link, 800_000)) == (
        800_000, f"{link} runs at 800000 bit/s, as bus.bitrate says")
    expected = (f"bus.bitrate: 1000000 bit/s, but {link} runs at 800000 bit/s; the link, "
                f"the drives and bus.bitrate must agree ({set_it})")
    with pytest.raises(ConfigError) as refused:
        check_link_bitrate(_socketcan(link))
    assert str(refused.value) == expected
    bus = ["--set", "bus.interface=socketcan", "--set", f"bus.channel={link}"]
    check = run_rakectl("run", "--check", *bus, timeout_s=CLI_TIMEOUT_S)
    assert (check.returncode, check.stderr.strip()) == (2, f"rakectl: error: {expected}")
    sock = tmp_path / "r.sock"
    daemon = run_rakectl("run", *bus, "--set", f"daemon.socket_path={sock}",
                         "--set", f"daemon.dump_dir={tmp_path}",
                         "--set", "daemon.startup_cyclictest_s=0", timeout_s=CLI_TIMEOUT_S)
    assert daemon.returncode == 2, daemon.stderr
    assert daemon.stderr.strip().splitlines()[-1] == f"rakectl: error: {expected}"
    assert not Path(f"{sock}.lock").exists()  # refused before it claims the socket
    agreed = run_rakectl("run", "--check", *bus, "--set", "bus.bitrate=800000",
                         timeout_s=CLI_TIMEOUT_S)
    assert agreed.returncode == 0, agreed.stderr
    assert f"  link: {link} runs at 800000 bit/s, as bus.bitrate says" in agreed.stdout


def test_vcan_has_no_bit_rate_to_check() -> None:
    assert check_link_bitrate(_socketcan(CHANNEL)) == (
        None, f"{CHANNEL} (vcan) has no bit rate of its own: not checked")
