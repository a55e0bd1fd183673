"""``rakectl replay TRACE.log``: a recorded bus trace fed back through the controller,
offline (rakectl.daemon.replay), to see whether it reproduces every frame the daemon
sent. Exit status 0 when it does, 1 naming the first frame that differs, 2 for a trace,
inputs file or configuration that cannot be replayed (missing, garbled, another run's,
incomplete: then with the frames reproduced up to where it stops being complete)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

EXIT_MISMATCH = 1


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    p = sub.add_parser("replay", help="feed a recorded bus trace (bus.trace_path) back "
                       "through the controller offline and compare the frames it sends "
                       "with the recorded ones (exit status 1 on the first difference)")
    p.add_argument("trace", type=Path, help="the candump .log the daemon wrote "
                   "(bus.trace_path); its inputs file TRACE.inputs.jsonl must be next to it")
    p.add_argument("--config", type=Path, help="the YAML configuration the daemon ran with")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="an override the daemon ran with (repeatable)")
    p.add_argument("--inputs", type=Path, default=None, help="the trace's inputs file, if "
                   "not next to it")


def cmd_replay(args: argparse.Namespace) -> int:
    from rakectl.config.loader import load_settings
    from rakectl.config.settings import Settings
    from rakectl.daemon.replay import replay
    from rakectl.errors import TraceError

    settings = load_settings(args.config, args.overrides, root=Settings)
    result = replay(args.trace, settings, args.inputs)
    if result.incomplete and not result.mismatch:
        raise TraceError(result.message())  # one line on stderr, exit status 2
    print(result.message())
    return 0 if result.ok else EXIT_MISMATCH
