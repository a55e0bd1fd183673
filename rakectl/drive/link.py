"""The CAN link's own bit rate, as the kernel reports it (``ip -details -json link show``).

rakectl does not set the link's bit rate: systemd-networkd does (80-can0.network's
``BitRate=``), or ``ip link set can0 type can bitrate …``. The configuration declares it
(``bus.bitrate``): the loop's bus load is judged on it, and the drives run at it. A link
at another rate hears nothing of its drives, and the start would end in a bring-up that
times out naming the drives; the daemon (and ``rakectl run --check``) reads the link's
rate first and refuses a mismatch naming both rates. Only a real CAN controller has a
rate: vcan has none, nor does an adapter that keeps its own (slcand's ``-s``), nor the
``virtual`` and ``udp_multicast`` interfaces; those are said to be not checked.
"""

from __future__ import annotations

import json
import shutil
import subprocess

from rakectl.config.service import BusInterface, BusSettings
from rakectl.errors import ConfigError

IP_TIMEOUT_S = 5.0
CAN_BITRATE_UNKNOWN = 0xFFFF_FFFF  # the kernel's "set by the adapter" (slcan)


def link_bitrate(channel: str) -> tuple[int | None, str]:
    """The bit rate of network interface ``channel`` (None where it has none, or it could
    not be read) and, for a person, what was found."""
    ip = shutil.which("ip") or shutil.which("ip", path="/usr/sbin:/sbin")
    if ip is None:
        return None, "not checked: no ip command (Debian's iproute2)"
    try:
        done = subprocess.run([ip, "-details", "-json", "link", "show", "dev", channel],
                              capture_output=True, text=True, timeout=IP_TIMEOUT_S,
                              check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        return None, f"not checked: ip: {error}"
    if done.returncode != 0:
        return None, f"not checked: {done.stderr.strip() or f'ip exited {done.returncode}'}"
    try:
        info = json.loads(done.stdout)[0].get("linkinfo", {})
        kind = str(info.get("info_kind", "no kind"))
        bitrate = info.get("info_data", {}).get("bittiming", {}).get("bitrate")
    except (ValueError, IndexError, AttributeError, TypeError):
        return None, "not checked: ip's answer unreadable"
    if not isinstance(bitrate, int) or bitrate in (0, CAN_BITRATE_UNKNOWN):
        return None, f"{channel} ({kind}) has no bit rate of its own: not checked"
    return bitrate, f"{channel} runs at {bitrate} bit/s"


def check_link_bitrate(settings: BusSettings) -> str:
    """What the start says of the link's bit rate, as a line for a person; ConfigError
    naming ``bus.bitrate`` if the link runs at another rate."""
    if settings.interface is not BusInterface.SOCKETCAN:
        return f"{settings.interface.value}: no link bit rate to check"
    bitrate, found = link_bitrate(settings.channel)
    if bitrate is not None and bitrate != settings.bitrate:
        raise ConfigError(f"bus.bitrate: {settings.bitrate} bit/s, but {found} (ip -details "
                          f"link show {settings.channel}); the link, the drives and bus.bitrate "
                          "must agree (80-can0.network's BitRate=)")
    return found + (", as bus.bitrate says" if bitrate is not None else "")
