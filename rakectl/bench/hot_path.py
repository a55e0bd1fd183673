"""Benchmark of the drive client's hot path on python-can's ``virtual`` bus (prints, never asserts).

One tick = ``receive()`` (decode two TPDO1s) + ``send()`` (pack and send two
RPDO1s) + ``sync()`` (SYNC, and a heartbeat every 100th tick), for each drive profile
(``drives.profile``: the codecs the client chose at start-up). A scripted
drive side on a second virtual bus answers each SYNC with both TPDO1s outside
the timed section. ``VirtualBus.send`` deep-copies each frame per receiver
(several µs, measured by this benchmark's bus-only phase), so most of a tick
is the bus, not the client.
"""

from __future__ import annotations

import dataclasses
import gc
import os
import statistics
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import can

from rakectl.bench.sections import markers, write_section
from rakectl.config.service import BusInterface, BusSettings, DrivesSettings
from rakectl.config.settings import MotorsSettings
from rakectl.drive.canbus import TraceRecorder, open_bus
from rakectl.drive.client import DriveClient
from rakectl.drive.joints import node_ids, receive_ids
from rakectl.protocol.codec import FunctionCode, cob_id, pack_tpdo1_into
from rakectl.protocol.files import DriveProfile

_WARM_UP_TICKS = 200


def _percentile(sorted_values: list[float], q: float) -> float:
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def _summary(name: str, samples_ns: list[float]) -> str:
    us = sorted(s / 1e3 for s in samples_ns)
    return (f"  {name:<34} median {statistics.median(us):6.2f} µs   p99 "
            f"{_percentile(us, 0.99):6.2f} µs   max {us[-1]:7.1f} µs")


class _ScriptedDrives:
    """The drive side: drain the bus, answer with one TPDO1 per drive (preallocated)."""

    def __init__(self, bus: can.BusABC, drives: DrivesSettings) -> None:
        self._bus = bus
        self._tpdo = [can.Message(arbitration_id=cob_id(FunctionCode.TPDO1, node),
                                  is_extended_id=False, data=bytearray(8))
                      for node in node_ids(drives)]

    def answer(self, k: int) -> None:
        while self._bus.recv(0.0) is not None:
            pass
        for i, msg in enumerate(self._tpdo):
            pack_tpdo1_into(msg.data, 200_000 + k + i, 10, 500)
            self._bus.send(msg)


def _run(client: DriveClient, drives: _ScriptedDrives, ticks: int,
         timed: Callable[[DriveClient, int], object]) -> list[float]:
    clock = time.perf_counter_ns
    samples = [0.0] * ticks
    for k in range(_WARM_UP_TICKS + ticks):
        t0 = clock()
        timed(client, k)
        t1 = clock()
        if k >= _WARM_UP_TICKS:
            samples[k - _WARM_UP_TICKS] = t1 - t0
        drives.answer(k)
    return samples


def _tick(client: DriveClient, k: int) -> None:
    client.receive()
    client.send(1.0, -1.0)
    client.sync()


def _trace_cost_ns(frames: int) -> tuple[float, float]:
    """(record, drain) cost per frame in ns, writing a candump .log to /dev/null."""
    writer = can.CanutilsLogWriter(os.devnull)
    trace = TraceRecorder(writer, "can0", capacity=frames)
    msg = can.Message(arbitration_id=0x181, is_extended_id=False, data=bytearray(8))
    clock = time.perf_counter_ns
    t0 = clock()
    for _ in range(frames):
        trace.record(msg, False)
    t1 = clock()
    trace.drain(frames)
    t2 = clock()
    trace.close()
    return (t1 - t0) / frames, (t2 - t1) / frames


def bench_hot_path(ticks: int) -> str:
    """Per-tick cost of receive + send + sync on ``virtual``, with and without a trace."""
    drives_settings = DrivesSettings()
    channel = f"bench-{uuid.uuid4().hex}"
    settings = BusSettings(interface=BusInterface.VIRTUAL, channel=channel)
    controller_bus = open_bus(settings, receive_ids(drives_settings))
    drive_bus = open_bus(settings, ())
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        drives = _ScriptedDrives(drive_bus, drives_settings)
        lines = [f"drive client hot path on virtual, {ticks} ticks (gc off):"]
        parts: dict[str, Callable[[DriveClient, int], object]] = {
            "receive (2 TPDO1)": lambda c, k: c.receive(),
            "send (2 RPDO1)": lambda c, k: c.send(1.0, -1.0),
            "sync (SYNC, heartbeat 1/100)": lambda c, k: c.sync(),
        }
        clients = {profile: DriveClient(controller_bus, dataclasses.replace(
            drives_settings, profile=profile), MotorsSettings(), rate_hz=1000.0)
            for profile in DriveProfile}  # the TPDO1 layout is the same: one drive side
        ticks_ns: dict[DriveProfile, list[float]] = {profile: [] for profile in DriveProfile}
        for _ in range(2):  # alternated, so that neither profile has the quieter moment
            for profile, client in clients.items():
                ticks_ns[profile] += _run(client, drives, ticks, _tick)
        for profile, client in clients.items():
            lines.append(f" drives.profile {profile.value}:")
            lines.append(_summary("tick = receive + send + sync", ticks_ns[profile]))
            for name, part in parts.items():
                lines.append(_summary(name, _run(client, drives, ticks, part)))
        client = DriveClient(controller_bus, drives_settings, MotorsSettings(), rate_hz=1000.0)
        bare = [can.Message(arbitration_id=can_id, is_extended_id=False, data=bytearray(size))
                for can_id, size in ((0x201, 4), (0x202, 4), (0x080, 1))]

        def bus_only(c: DriveClient, k: int) -> None:  # the same frames, no client
            while controller_bus.recv(0.0) is not None:
                pass
            for msg in bare:
                controller_bus.send(msg)

        lines.append(_summary("bus alone: drain 2 + send 3 frames", _run(client, drives, ticks,
                                                                          bus_only)))
        with open(os.devnull, "w") as sink:
            trace = TraceRecorder(can.CanutilsLogWriter(sink), "can0", capacity=8 * ticks)
            traced = DriveClient(controller_bus, drives_settings, MotorsSettings(), 1000.0,
                                 trace=trace)
            lines.append(_summary("tick with trace recording", _run(traced, drives, ticks, _tick)))
            trace.close()
        record_ns, drain_ns = _trace_cost_ns(max(ticks, 1000))
        lines.append(f"  trace per frame: record {record_ns / 1e3:.2f} µs (hot path), "
                     f"drain to candump .log {drain_ns / 1e3:.2f} µs (slack)")
        lines.append("  (goal: tick median <= 30 µs)")
        return "\n".join(lines)
    finally:
        if gc_was_enabled:
            gc.enable()
        controller_bus.shutdown()
        drive_bus.shutdown()


# --------------------------------------------------------------------------- its report

HOT_PATH_START, HOT_PATH_END = markers("hot-path", "rakectl bench --profiles")


def hot_path_section(command: str, started: str, tree: str, text: str) -> list[str]:
    """Section (e) of BENCHMARKS.md: the drive client's hot path per drive profile, as
    printed by :func:`bench_hot_path`."""
    return [HOT_PATH_START, "## (e) The drive client's hot path, per drive profile", "",
            f"`{command}` on {started}, tree {tree}. The drive client's "
            "receive + send + sync on python-can's `virtual` bus against a scripted drive "
            "side, for each `drives.profile` (the codecs the client chose at start-up), the "
            "profiles' ticks alternated so that neither has the quieter moment; most of a "
            "tick is the virtual bus (its line below).", "", "```text", text, "```",
            HOT_PATH_END, ""]


def write_hot_path_section(path: Path, section: list[str]) -> None:
    """Section (e) into ``path`` in place of its last version (appended if it has none);
    the rest of the file is left as ``rakectl bench --all`` wrote it."""
    write_section(path, HOT_PATH_START, HOT_PATH_END, section)
