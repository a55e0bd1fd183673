"""What an emulated drive counts: bad input by kind, with the last such frame, and its
frames (summarized off the hot path by the emulator's status)."""

from __future__ import annotations

import enum


class BadInput(enum.Enum):
    """Kinds of input that are counted and ignored."""

    WRONG_LENGTH = "wrong_length"
    BAD_VALUE = "bad_value"  # a value the protocol does not define
    UNKNOWN_ID = "unknown_id"  # no drive listens to it (counted by the emulator)
    UNSUPPORTED = "unsupported"  # remote, error, extended-ID or FD frame (emulator)
    UNREADABLE = "unreadable"  # what the bus could not decode as a frame (emulator)


class InputStats:
    """Bad input per kind, and the last such frame of each kind."""

    __slots__ = ("counts", "last", "total")

    def __init__(self) -> None:
        self.counts = dict.fromkeys(BadInput, 0)
        self.last: dict[BadInput, tuple[int, bytes]] = {}
        self.total = 0

    def count(self, kind: BadInput, can_id: int, data: bytes | bytearray) -> None:
        self.counts[kind] += 1
        self.last[kind] = (can_id, bytes(data))
        self.total += 1


class NodeStats:
    """Counters of one drive (summarized off the hot path)."""

    __slots__ = ("bad", "clamped_commands", "emcys", "faults", "lost_syncs", "rpdos",
                 "rpdos_ignored", "sdo_requests", "syncs")

    def __init__(self) -> None:
        self.bad = InputStats()
        self.syncs = self.lost_syncs = self.rpdos = self.rpdos_ignored = 0
        self.sdo_requests = self.clamped_commands = self.emcys = self.faults = 0
