"""Opening the controller's CAN bus, and recording a trace of it without blocking the loop.

:func:`open_bus` is the only place in rakectl that calls ``can.Bus(...)``; the
composition root (the daemon, ``rakectl bench``) calls it and injects the bus
into :class:`rakectl.drive.client.DriveClient`.

Receive filters, per interface:

- ``socketcan``: the IDs the controller receives are installed as kernel
  filters (``CAN_RAW_FILTER``), so the hot path never even sees other frames.
  Error frames pass regardless (python-can enables ``CAN_RAW_ERR_FILTER``);
  the drive client counts them. The bit rate is a property of the link, set
  outside Python (``ip link set can0 type can bitrate 1000000``, or
  systemd-networkd); python-can's socketcan ignores a ``bitrate`` argument.
- ``virtual`` and ``udp_multicast``: no filters are set. python-can filters in
  software inside ``BusABC.recv``, and ``recv(timeout=0)`` then returns None
  as soon as the frame at the head of the queue does not match, even when
  matching frames wait behind it: the drive client's drain ("recv(0) until
  None") would stop early every tick, behind the echo of its own SYNC on
  ``udp_multicast``. The drive client classifies frames itself instead:
  echoes of its own IDs are counted as such and ignored (an RPDO1 that is none
  of the last two it sent is another master's: a fault), anything else is
  counted as unknown. The bring-up's network sees only 11-bit data frames
  (:class:`CanopenFrames`). ``udp_multicast`` is opened with ``fd=False`` (classic
  CAN) on a port derived from its group address (:attr:`BusSettings.udp_port`:
  benches on different groups do not hear each other) and needs ``msgpack``;
  only ever use it inside a private network namespace (docs/development.md).

:class:`TraceRecorder` copies every frame sent and received into a
preallocated ring in the hot path (no allocation, no I/O) and writes them to
a candump ``.log`` with python-can's ``CanutilsLogWriter`` when the loop
calls :meth:`TraceRecorder.drain` in its slack. A full ring drops the newest
frame and counts it. Decode a trace with
``python -m cantools decode rakectl/protocol/rakedrive.dbc < trace.log``.
:class:`TracedNetwork` is the bring-up's ``canopen.Network`` with every frame it sends
and receives in the same trace.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from typing import Any, Protocol

import can
import canopen

from rakectl.config.service import BusInterface, BusSettings
from rakectl.errors import RakeError

STANDARD_ID_MASK = 0x7FF
DEFAULT_TRACE_CAPACITY = 8192  # frames: ~1.6 s of the 1 kHz cycle (5 frames per tick)


class BusError(RakeError, OSError):
    """The CAN bus could not be opened or used; the message names interface and channel."""


def can_filters(receive_ids: Iterable[int]) -> list[dict[str, Any]]:
    """python-can filters that pass exactly these 11-bit IDs."""
    return [{"can_id": can_id, "can_mask": STANDARD_ID_MASK, "extended": False}
            for can_id in sorted(set(receive_ids))]


def bus_kwargs(settings: BusSettings, receive_ids: Iterable[int]) -> dict[str, Any]:
    """The ``can.Bus`` arguments for ``settings`` (pure; see the module docstring)."""
    kwargs: dict[str, Any] = {"interface": settings.interface.value,
                              "channel": settings.channel}
    if settings.interface is BusInterface.SOCKETCAN:
        kwargs["can_filters"] = can_filters(receive_ids)
    elif settings.interface is BusInterface.UDP_MULTICAST:
        kwargs["fd"] = False
        kwargs["port"] = settings.udp_port  # one port per group address: no cross-talk
    return kwargs


def open_bus(settings: BusSettings, receive_ids: Iterable[int]) -> can.BusABC:
    """Open the bus of ``settings``, receiving ``receive_ids`` (kernel-filtered on socketcan).

    Raises :class:`BusError` with one line naming the interface and channel.
    """
    kwargs = bus_kwargs(settings, receive_ids)
    try:
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError, RuntimeError) as error:
        raise BusError(
            f"cannot open CAN bus: interface {settings.interface.value}, channel "
            f"{settings.channel!r}: {type(error).__name__}: {error}"
        ) from error


# --------------------------------------------------------------------------- trace


class FrameWriter(Protocol):
    """What :class:`TraceRecorder` writes to: a python-can ``MessageWriter``."""

    def on_message_received(self, msg: can.Message) -> None: ...

    def stop(self) -> None: ...


class TraceRecorder:
    """A ring of frames filled in the hot path and written out in the loop's slack.

    ``record`` copies id, flags, data and a timestamp into preallocated slots
    (received frames keep the bus's timestamp, sent ones get ``time.time()``,
    the candump convention). ``drain(max_frames)`` writes at most that many to
    the writer, oldest first. ``dropped`` counts frames that found the ring full;
    ``first_dropped_at`` is how many frames were recorded before the first of them (-1:
    none), where the written trace stops being complete (a replay stops there).
    """

    __slots__ = ("_channel", "_data", "_flags", "_head", "_ids", "_lengths", "_size",
                 "_stamps", "_tail", "_writer", "dropped", "first_dropped_at", "recorded",
                 "written")

    _RX = 1
    _EXTENDED = 2
    _ERROR = 4
    _REMOTE = 8

    def __init__(self, writer: FrameWriter, channel: str,
                 capacity: int = DEFAULT_TRACE_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"trace capacity must be >= 1, got {capacity}")
        self._writer = writer
        self._channel = channel
        self._size = capacity
        self._ids = [0] * capacity
        self._flags = [0] * capacity
        self._lengths = [0] * capacity
        self._stamps = [0.0] * capacity
        self._data = [bytearray(64) for _ in range(capacity)]
        self._head = 0  # next slot to write
        self._tail = 0  # next slot to drain
        self.recorded = 0
        self.written = 0
        self.dropped = 0
        self.first_dropped_at = -1

    @property
    def pending(self) -> int:
        """Frames recorded but not written yet."""
        return self.recorded - self.written

    def record(self, msg: can.Message, is_rx: bool) -> None:
        """Copy ``msg`` into the ring (hot path: no allocation, no I/O)."""
        if self.recorded - self.written >= self._size:
            if not self.dropped:
                self.first_dropped_at = self.recorded
            self.dropped += 1
            return
        slot = self._head
        data = msg.data
        length = len(data)
        self._data[slot][0:length] = data
        self._lengths[slot] = length
        self._ids[slot] = msg.arbitration_id
        self._stamps[slot] = msg.timestamp if is_rx else time.time()
        self._flags[slot] = (
            (self._RX if is_rx else 0) | (self._EXTENDED if msg.is_extended_id else 0)
            | (self._ERROR if msg.is_error_frame else 0)
            | (self._REMOTE if msg.is_remote_frame else 0)
        )
        self._head = slot + 1 if slot + 1 < self._size else 0
        self.recorded += 1

    def drain(self, max_frames: int) -> int:
        """Write up to ``max_frames`` recorded frames; returns how many were written."""
        count = min(max_frames, self.recorded - self.written)
        for _ in range(count):
            slot = self._tail
            flags = self._flags[slot]
            self._writer.on_message_received(can.Message(
                timestamp=self._stamps[slot], arbitration_id=self._ids[slot],
                is_extended_id=bool(flags & self._EXTENDED),
                is_error_frame=bool(flags & self._ERROR),
                is_remote_frame=bool(flags & self._REMOTE), is_rx=bool(flags & self._RX),
                data=bytes(self._data[slot][0:self._lengths[slot]]), channel=self._channel,
                check=False,
            ))
            self._tail = slot + 1 if slot + 1 < self._size else 0
            self.written += 1
        return count

    def close(self) -> None:
        """Write everything still in the ring and close the writer."""
        self.drain(self.recorded - self.written)
        self._writer.stop()


def open_trace(settings: BusSettings, capacity: int = DEFAULT_TRACE_CAPACITY,
               ) -> TraceRecorder | None:
    """A recorder writing ``settings.trace_path`` as a candump .log; None for an empty path."""
    if not settings.trace_path:
        return None
    channel = settings.channel if settings.interface is BusInterface.SOCKETCAN else "can0"
    try:
        writer = can.CanutilsLogWriter(settings.trace_path, channel=channel)
    except OSError as error:
        raise BusError(f"bus.trace_path: cannot open the CAN trace {settings.trace_path!r}: "
                       f"{error}") from error
    return TraceRecorder(writer, channel, capacity)


class _TraceListener(can.Listener):
    """Frames the bring-up receives, into the bus trace (echoes of its own left out)."""

    def __init__(self, trace: TraceRecorder, own: frozenset[int], lock: threading.Lock) -> None:
        self._trace, self._own, self._lock = trace, own, lock

    def on_message_received(self, msg: can.Message) -> None:  # the notifier's thread
        if msg.arbitration_id not in self._own:
            with self._lock:
                self._trace.record(msg, True)


class TracedNetwork(canopen.Network):
    """The bring-up's network, with every frame it sends and receives in the bus trace,
    once (udp_multicast's echoes of frames sent are left out)."""

    def __init__(self, bus: can.BusABC, trace: TraceRecorder, own: frozenset[int]) -> None:
        super().__init__(bus)
        self._trace, self._lock = trace, threading.Lock()
        self.trace_listener = _TraceListener(trace, own, self._lock)  # for the notifier

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        super().send_message(can_id, data, remote)
        msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > 0x7FF,
                          is_remote_frame=remote)
        with self._lock:
            self._trace.record(msg, False)


class CanopenFrames(can.Listener):
    """Passes to ``listeners`` only the frames a CANopen network is made of: 11-bit data
    frames (CiA 301). canopen's own listener hands any frame's ID to its subscribers,
    so a 29-bit frame whose ID reads as a drive's heartbeat or SDO answer (0x701, 0x581)
    would be taken for one on ``virtual`` and ``udp_multicast``, where nothing filters
    them out before the bring-up sees them. Dropped frames are counted in ``dropped``, and
    what the bus could not decode (a udp_multicast datagram that is no frame) in
    ``unreadable``: handled here, it no longer ends the notifier's thread, which left
    the bring-up deaf ("no heartbeat or boot-up") with its drives running."""

    def __init__(self, listeners: Iterable[can.Listener]) -> None:
        self._listeners = tuple(listeners)
        self.dropped = self.unreadable = 0

    def on_error(self, exc: Exception) -> None:  # the notifier's thread, its recv failed
        if not isinstance(exc, can.CanError):
            raise NotImplementedError  # not handled: the notifier raises it
        self.unreadable += 1

    def on_message_received(self, msg: can.Message) -> None:  # the notifier's thread
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame or msg.is_fd:
            self.dropped += 1
            return
        for listener in self._listeners:
            listener.on_message_received(msg)

    def stop(self) -> None:
        for listener in self._listeners:
            listener.stop()
