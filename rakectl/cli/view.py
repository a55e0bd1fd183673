"""``rakectl view`` (the live view) and ``rakectl mcap`` (recordings as MCAP)."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from rakectl.errors import ConfigError, RakeError

DEFAULT_PORT = 8765


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    view = sub.add_parser("view", help="the live view: the daemon's state on a Foxglove "
                          "WebSocket server (the [view] extra; docs/viewer.md)")
    view.add_argument("--socket", help="the daemon's command socket")
    view.add_argument("--host", default="127.0.0.1", help="address to serve on (default "
                      "127.0.0.1; any other exposes the robot's state to the network, "
                      "unauthenticated: docs/viewer.md)")
    view.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port (default "
                      f"{DEFAULT_PORT}; 0: any free one, printed)")
    view.add_argument("--rate-hz", type=float, default=50.0, help="status polls per second "
                      "(1-200, default 50)")
    view.add_argument("--truth", type=Path, help="an emulator's truth CSV to stream too "
                      "(emulated bench)")
    view.add_argument("--emulator-config", type=Path, help="an emulator's YAML: its buried "
                      "objects are drawn")
    view.add_argument("--lane", type=float, nargs=2, metavar=("NEAR_M", "FAR_M"),
                      help="the lane's reach, for the depth reached (default: the lane the "
                      "daemon's status names)")
    view.add_argument("--record", type=Path, help="also write what is served to this MCAP")
    view.add_argument("--seconds", type=float, help="stop after this long (default: until "
                      "interrupted)")
    view.add_argument("--write-layout", type=Path, metavar="FILE", help="write the Foxglove "
                      "layout (docs/foxglove-layout.json) to FILE and exit")
    mcap = sub.add_parser("mcap", help="a flight-recorder dump, an emulator truth CSV or a "
                          "simulation's telemetry as MCAP (the [view] extra)")
    mcap.add_argument("csv", type=Path, help="the CSV: a flight-recorder dump, truth.csv or "
                      "telemetry.csv (rakectl simulate, plant rake)")
    mcap.add_argument("-o", "--out", type=Path, help="the MCAP (default: next to the CSV)")
    mcap.add_argument("--every", type=int, default=1, help="one row in EVERY (default 1)")
    mcap.add_argument("--emulator-config", type=Path, help="an emulator's YAML: its buried "
                      "objects are drawn")


def objects_of(emulator_config: Path | None) -> list[Any]:
    """The buried objects of an emulator's configuration, as the viewer draws them."""
    if emulator_config is None:
        return []
    from drivers.cli import load_config

    return boxes(load_config(emulator_config).physics.ground.objects)


def boxes(objects: Any) -> list[Any]:
    """drivers.ground_params.BuriedObjects as the viewer draws them."""
    from rakectl.view.topics import Box

    return ([Box(m.reach_m, m.depth_m, m.width_m, m.thickness_m, "mine")
             for m in objects.mines]
            + [Box(s.reach_m, s.depth_m, s.width_m, s.thickness_m, "stone")
               for s in objects.stones]
            + [Box(r.reach_m, r.depth_m, r.width_m, r.thickness_m, "root")
               for r in objects.roots])


def cmd_view(args: argparse.Namespace) -> int:
    from rakectl.api.client import socket_path
    from rakectl.view.stream import StatusStream
    from rakectl.view.topics import Publisher, require_foxglove

    foxglove = require_foxglove()

    if args.write_layout is not None:
        import json

        from rakectl.view.layout import build

        check_layout(args.write_layout)
        args.write_layout.write_text(json.dumps(json.loads(build()), indent=1,
                                                ensure_ascii=False) + "\n")
        print(f"view: layout written to {args.write_layout}", file=sys.stderr)
        return 0
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"view: --port must be within 0..65535, got {args.port}")
    if args.lane is not None and not args.lane[0] < args.lane[1]:
        raise ConfigError(f"view: --lane NEAR FAR needs NEAR < FAR, got {args.lane}")
    if not 1.0 <= args.rate_hz <= 200.0:
        raise ConfigError(f"view: --rate-hz must be within 1..200, got {args.rate_hz:g}")
    if args.seconds is not None and not args.seconds > 0.0:
        raise ConfigError(f"view: --seconds must be > 0, got {args.seconds:g}")
    if args.record is not None:  # an earlier recording is never replaced
        from rakectl.view.record import check_output

        check_output(args.record, "view: --record", replace_mcap=False)
    objects = objects_of(args.emulator_config)  # a bad file fails before anything starts
    context = foxglove.Context()
    stream = StatusStream(socket_path(args.socket), Publisher(context), args.rate_hz, objects,
                          tuple(args.lane) if args.lane else None, args.truth)
    with contextlib.ExitStack() as stack:
        if args.record is not None:
            try:
                writer = foxglove.open_mcap(args.record, allow_overwrite=True, context=context)
            except Exception as exc:  # the SDK's own error type
                raise RakeError(f"view: cannot write {args.record}: {exc}") from exc
            stack.callback(writer.close)
        try:
            server = foxglove.start_server(name="rakectl", host=args.host, port=args.port,
                                           context=context)
        except Exception as exc:  # the SDK's own error type: the address, taken or invalid
            raise RakeError(f"view: cannot serve on {args.host}:{args.port}: {exc}") from exc
        stack.callback(server.stop)
        stop = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):  # restored when the view ends
            stack.callback(signal.signal, sig, signal.signal(sig, lambda *_: stop.set()))
        if args.seconds is not None:
            timer = threading.Timer(args.seconds, stop.set)
            timer.start()
            stack.callback(timer.cancel)
        print(f"view: ws://{args.host}:{server.port} (Foxglove: Open connection → Foxglove "
              f"WebSocket; layout docs/foxglove-layout.json), status of {stream.socket} at "
              f"{args.rate_hz:g} Hz", file=sys.stderr, flush=True)
        stream.run(lambda: not stop.is_set())
    truth = (f"; truth: {stream.truth_rows} rows served, {stream.truth_bad_rows} skipped"
             if args.truth else "")
    if args.truth and not args.truth.is_file():
        truth += f" ({args.truth} never appeared: is the emulator writing it there?)"
    print(f"view: {stream.replies} status replies, {stream.errors} failed{truth}"
          + (f" (last: {stream.last_error})" if stream.last_error else ""), file=sys.stderr)
    return 0


def check_layout(path: Path) -> None:
    """ConfigError unless ``path`` can take the layout: not a directory, an existing file
    only if it is a layout written before (JSON with Foxglove's ``panelType``), in a
    directory that exists."""
    if path.is_dir():
        raise ConfigError(f"view: --write-layout {path} is a directory, not a file")
    if not path.parent.is_dir():
        raise ConfigError(f"view: --write-layout {path}: no directory {str(path.parent)!r}")
    if path.exists():
        try:
            earlier = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            earlier = ""
        if not (earlier.lstrip().startswith("{") and '"panelType"' in earlier):
            raise ConfigError(f"view: --write-layout {path} exists and is not a layout: it "
                              "is never replaced; choose another name")


def cmd_mcap(args: argparse.Namespace) -> int:
    import csv

    from rakectl.view.record import (
        DUMP_KEYS,
        TELEMETRY_KEYS,
        check_output,
        dump_to_mcap,
        telemetry_to_mcap,
        truth_to_mcap,
    )

    if args.every < 1:
        raise ConfigError(f"mcap: --every must be >= 1, got {args.every}")
    try:
        with args.csv.open(newline="") as f:
            header = next(csv.reader(f), [])
    except OSError as exc:
        raise ConfigError(f"mcap: cannot read {args.csv}: {exc.strerror or exc}") from exc
    out = args.out or args.csv.with_suffix(".mcap")
    check_output(out, "mcap: -o" if args.out else "mcap: the output", source=args.csv)
    objects = objects_of(args.emulator_config)
    if all(k in header for k in DUMP_KEYS):
        rows = dump_to_mcap(args.csv, out, args.every, objects)
    elif all(k in header for k in TELEMETRY_KEYS):
        rows = telemetry_to_mcap(args.csv, out, args.every, objects)
    else:
        rows = truth_to_mcap(args.csv, out, args.every, objects)
    print(f"mcap: {rows} rows of {args.csv} → {out}")
    return 0
