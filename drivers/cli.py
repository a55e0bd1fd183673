"""``python -m drivers``: the emulated drives on a CAN bus (the emulator's composition root).

    python -m drivers --config config/emulator.yaml --interface virtual --channel CH \\
        [--set key=value ...] [--truth FILE.csv] [--bench CYCLES]

Reads the configuration (``--interface``/``--channel`` override ``bus.*``),
opens the bus, runs :class:`drivers.emulator.Emulator` until SIGTERM or SIGINT
and exits 0. Once the drives have booted it prints one line to stdout, e.g.
``emulator: ready node-ids 1,2 on virtual:CH``. Logs go to stderr (structlog;
JSON unless stderr is a terminal). Exit codes: 2 for a bad configuration or
command line, 1 if the bus cannot be opened. ``--bench CYCLES`` instead drives
the emulator itself over a private ``virtual`` channel (NMT start, enable, a
SYNC and two RPDOs per cycle, LOCKSTEP) and prints µs per SYNC.

Never run ``udp_multicast`` outside a private network namespace that you
created (``unshare -rn``): the traffic would leave through the machine's
network interface.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn, TextIO

import can
import structlog

from drivers.emulator import Emulator
from drivers.settings import EmulatorConfig, TimingMode
from rakectl.config.loader import load_settings
from rakectl.config.service import BusInterface, BusSettings
from rakectl.errors import ConfigError
from rakectl.protocol import codec, nmt
from rakectl.protocol.cia402 import DriveCommand
from rakectl.protocol.files import DriveProfile

UDP_MULTICAST_OPTIONS = {"fd": False}  # CAN 2.0 frames; the IPv4 group is given as channel


def load_config(path: str | Path | None, overrides: Sequence[str] = ()) -> EmulatorConfig:
    """config/emulator.yaml plus ``--set`` overrides, validated; ConfigError names file:line."""
    return load_settings(path, overrides, root=EmulatorConfig)


def configure_logging(stream: TextIO = sys.stderr) -> None:
    renderer: Any = (structlog.dev.ConsoleRenderer() if stream.isatty()
                     else structlog.processors.JSONRenderer())
    structlog.configure(
        processors=[structlog.processors.add_log_level,
                    structlog.processors.TimeStamper(fmt="iso"), renderer],
        logger_factory=structlog.PrintLoggerFactory(file=stream),
        cache_logger_on_first_use=True,
    )


def open_bus(settings: BusSettings) -> can.BusABC:
    options: dict[str, Any] = {}
    if settings.interface is BusInterface.UDP_MULTICAST:
        options.update(UDP_MULTICAST_OPTIONS, port=settings.udp_port)  # the controller's
    return can.Bus(interface=settings.interface.value, channel=settings.channel, **options)


class StopRequest:
    """Records SIGTERM/SIGINT; the loop checks it (the handler does nothing else)."""

    def __init__(self) -> None:
        self.signal: int | None = None

    def install(self) -> None:
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, self._record)

    def _record(self, signum: int, frame: FrameType | None) -> None:
        self.signal = signum

    def __call__(self) -> bool:
        return self.signal is not None


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``--help`` gives the usage), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parser(prog: str) -> argparse.ArgumentParser:
    parser = _Parser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, help="YAML file (default: built-in defaults)")
    parser.add_argument("--interface", choices=[i.value for i in BusInterface])
    parser.add_argument("--channel")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override one option (repeatable)")
    parser.add_argument("--truth", type=Path, help="write the ground truth to this CSV file")
    parser.add_argument("--bench", type=_cycles, metavar="CYCLES",
                        help="time CYCLES SYNCs on a private virtual bus, print µs, exit")
    return parser


def _cycles(text: str) -> int:
    """``--bench``'s count: a whole number of at least 1 (0 would start the emulator)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def main(argv: Sequence[str] | None = None, prog: str = "python -m drivers") -> int:
    """``prog``: how the command was called (``rakectl emulator`` passes its own name)."""
    args = _parser(prog).parse_args(argv)
    overrides = list(args.overrides)
    overrides += [f"bus.interface={args.interface}"] if args.interface else []
    overrides += [f"bus.channel={args.channel}"] if args.channel else []
    try:
        config = load_config(args.config, overrides)
    except ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    configure_logging()
    if args.bench is not None:
        bench(config, args.bench)
        return 0
    with ExitStack() as stack:
        try:  # the files first: a path that cannot be written starts nothing
            truth = stack.enter_context(args.truth.open("w")) if args.truth else None
            trace = (stack.enter_context(can.CanutilsLogWriter(config.bus.trace_path))
                     if config.bus.trace_path else None)
        except OSError as exc:
            print(f"{prog}: cannot write {exc.filename}: "
                  f"{exc.strerror or exc}", file=sys.stderr)
            return 1
        try:
            bus = open_bus(config.bus)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            print(f"{prog}: cannot open {config.bus.interface.value}:"
                  f"{config.bus.channel}: {exc}", file=sys.stderr)
            return 1
        stack.callback(bus.shutdown)
        stop = StopRequest()
        stop.install()
        emulator = Emulator(config, bus, truth=truth, trace=trace)
        stack.callback(emulator.close)
        emulator.start()
        ids = ",".join(str(n.node_id) for n in emulator.nodes)
        print(f"emulator: ready node-ids {ids} on {config.bus.interface.value}:"
              f"{config.bus.channel}", flush=True)
        emulator.run(stop)
    return 0


_ROBOTEQ_ZERO_COMMAND = bytes(4)  # RPDO1 of roboteq_class_drive.eds: 0x2000:01 = 0 ‰


def bench(config: EmulatorConfig, cycles: int) -> None:
    """Drive the emulator from a scripted controller on a private virtual channel."""
    config = replace(config, drives=replace(config.drives, timing=TimingMode.LOCKSTEP))
    channel = f"drivers-bench-{time.monotonic_ns()}"
    controller = can.Bus(interface="virtual", channel=channel)
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    try:
        emulator = Emulator(config, emulator_bus, log=structlog.get_logger("bench"))
        emulator.start()
        ids = [n.node_id for n in emulator.nodes]
        roboteq = config.drives.profile is DriveProfile.ROBOTEQ

        def send(can_id: int, data: bytes) -> None:
            controller.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

        send(codec.NMT_COB_ID, nmt.encode_nmt(nmt.NmtCommand.START, 0))
        counter, started_s = 0, 0.0
        bring_up = [DriveCommand.SHUTDOWN, DriveCommand.SWITCH_ON]
        bring_up += [DriveCommand.ENABLE_OPERATION] * cycles
        for cycle, command in enumerate(bring_up):
            if cycle == 2:
                started_s = time.perf_counter()
                emulator.stats.syncs = emulator.stats.physics_steps = 0
                emulator.stats.protocol_s = emulator.stats.physics_s = 0.0
            counter = codec.next_sync_counter(counter)
            send(codec.SYNC_COB_ID, codec.encode_sync(counter))
            rpdo = (_ROBOTEQ_ZERO_COMMAND if roboteq  # no CiA 402: 0 ‰, driven as is
                    else codec.encode_rpdo(0, command.value))
            for node_id in ids:
                send(0x200 + node_id, rpdo)
            emulator.service(0.0)
            while controller.recv(0.0) is not None:
                pass
        elapsed_s = time.perf_counter() - started_s
        protocol_us, physics_us = emulator.stats.per_sync_us()
        print(f"emulator bench: {cycles} SYNCs, {elapsed_s / cycles * 1e6:.1f} µs per cycle "
              f"(controller included); emulator per SYNC: protocol {protocol_us:.1f} µs, "
              f"physics {physics_us:.1f} µs (one period)", flush=True)
        emulator.close()
    finally:
        controller.shutdown()
        emulator_bus.shutdown()

