"""The CAN link's own bit rate, as the kernel reports it (one RTM_GETLINK over netlink).

rakectl does not set the link's bit rate: systemd-networkd does (80-can0.network's
``BitRate=``), or ``ip link set can0 type can bitrate …``. The configuration declares it
(``bus.bitrate``): the loop's bus load is judged on it, and the drives run at it. A link
at another rate hears nothing of its drives, and the start would end in a bring-up that
times out naming the drives; the daemon (and ``rakectl run --check``) reads the link's
rate first and refuses a mismatch naming both rates, and a CAN controller whose rate was
never set. Links with no rate of their own (vcan; an adapter that keeps its own, as
slcand's ``-s`` sets it) and the ``virtual`` and ``udp_multicast`` interfaces are said to
be not checked, as is a link the kernel would not describe (it is named).

The link is read in this process over AF_NETLINK, which the service's unit allows for
it: ``ip`` drops capabilities with ``capset``, which the unit's system-call filter
refuses, and exits 1.
"""

from __future__ import annotations

import os
import socket
import struct
from collections.abc import Iterator

from rakectl.config.service import BusInterface, BusSettings
from rakectl.errors import ConfigError

RTM_NEWLINK, RTM_GETLINK = 16, 18  # include/uapi/linux/rtnetlink.h
NLMSG_ERROR, NLM_F_REQUEST = 2, 1  # include/uapi/linux/netlink.h
IFLA_IFNAME, IFLA_LINKINFO = 3, 18  # include/uapi/linux/if_link.h
IFLA_INFO_KIND, IFLA_INFO_DATA = 1, 2
IFLA_CAN_BITTIMING = 1  # include/uapi/linux/can/netlink.h; its first u32 is the bit rate
NLA_TYPE_MASK = 0x3FFF  # without NLA_F_NESTED and NLA_F_NET_BYTEORDER
HEADER = struct.Struct("=IHHII")  # struct nlmsghdr
IFINFO = struct.Struct("=BxHiII")  # struct ifinfomsg
CAN_BITRATE_UNKNOWN = 0xFFFF_FFFF  # the kernel's "the adapter keeps its own" (slcan)
NETLINK_TIMEOUT_S = 2.0


def _attributes(data: bytes) -> Iterator[tuple[int, bytes]]:
    """The netlink attributes (type, payload) packed in ``data``."""
    at = 0
    while at + 4 <= len(data):
        length, kind = struct.unpack_from("=HH", data, at)
        if length < 4 or at + length > len(data):
            raise ValueError(f"an attribute of {length} bytes at {at} of {len(data)}")
        yield kind & NLA_TYPE_MASK, data[at + 4:at + length]
        at += (length + 3) & ~3


def read_link(channel: str) -> tuple[str, int | None]:
    """The kind of network interface ``channel`` ("can", "vcan", …; "" if it has none) and
    the bit rate of its bit timing (None where it has none). OSError if the kernel does not
    describe it (no such link: ENODEV), ValueError if its answer cannot be read."""
    name = channel.encode() + b"\0"
    attribute = struct.pack("=HH", 4 + len(name), IFLA_IFNAME) + name
    body = IFINFO.pack(socket.AF_UNSPEC, 0, 0, 0, 0) + attribute + b"\0" * (-len(name) % 4)
    request = HEADER.pack(HEADER.size + len(body), RTM_GETLINK, NLM_F_REQUEST, 1, 0) + body
    with socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, socket.NETLINK_ROUTE) as rtnl:
        rtnl.settimeout(NETLINK_TIMEOUT_S)
        rtnl.send(request)
        reply = rtnl.recv(1 << 16)
    if len(reply) < HEADER.size + 4:
        raise ValueError(f"an answer of {len(reply)} bytes")
    length, kind, _, _, _ = HEADER.unpack_from(reply)
    if kind == NLMSG_ERROR:
        (error,) = struct.unpack_from("=i", reply, HEADER.size)
        raise OSError(-error, os.strerror(-error))
    if kind != RTM_NEWLINK or length > len(reply) or length < HEADER.size + IFINFO.size:
        raise ValueError(f"a message of type {kind}, {length} bytes of {len(reply)}")
    link_kind, bitrate = "", None
    for attribute_type, payload in _attributes(reply[HEADER.size + IFINFO.size:length]):
        if attribute_type != IFLA_LINKINFO:
            continue
        for info_type, info in _attributes(payload):
            if info_type == IFLA_INFO_KIND:
                link_kind = info.rstrip(b"\0").decode(errors="replace")
            elif info_type == IFLA_INFO_DATA and link_kind == "can":  # the kind comes first
                for can_type, can in _attributes(info):
                    if can_type == IFLA_CAN_BITTIMING and len(can) >= 4:
                        (bitrate,) = struct.unpack_from("=I", can)
    return link_kind, bitrate


def check_link_bitrate(settings: BusSettings) -> tuple[int | None, str]:
    """The link's bit rate (None where it has none, or it was not read) and a line for a
    person; ConfigError naming ``bus.bitrate`` if the link runs at another rate, naming
    ``bus.channel`` if it is a CAN controller whose rate is not set."""
    if settings.interface is not BusInterface.SOCKETCAN:
        return None, f"{settings.interface.value}: no link bit rate to check"
    channel = settings.channel
    set_it = (f"ip link set {channel} type can bitrate {settings.bitrate}, or "
              "systemd-networkd's BitRate=, as in systemd/80-can0.network")
    try:
        kind, bitrate = read_link(channel)
    except OSError as error:
        return None, f"{channel}: not checked: {error.strerror or error}"
    except ValueError as error:
        return None, f"{channel}: not checked: the kernel's answer is unreadable ({error})"
    if kind != "can":
        return None, f"{channel} ({kind or 'no kind'}) has no bit rate of its own: not checked"
    if bitrate is None:
        raise ConfigError(f"bus.channel: {channel} is a CAN controller whose bit rate is not "
                          f"set, and it cannot come up so ({set_it})")
    if bitrate == CAN_BITRATE_UNKNOWN:
        return None, f"{channel} (can) keeps its adapter's own bit rate: not checked"
    if bitrate != settings.bitrate:
        raise ConfigError(f"bus.bitrate: {settings.bitrate} bit/s, but {channel} runs at "
                          f"{bitrate} bit/s; the link, the drives and bus.bitrate must agree "
                          f"({set_it})")
    return bitrate, f"{channel} runs at {bitrate} bit/s, as bus.bitrate says"
