"""What the operator's commands share (rakectl.api.operator, rakectl.api.motion): the
daemon's socket from ``--socket``, a reply printed as text or as JSON, a line on stderr
that survives a closed terminal, and the requests they poll with."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from rakectl.api.client import socket_path
from rakectl.api.schema import ApiCommand

POLL_S = 0.2
STATE_TIMEOUT_S = 1.0  # a status asked on the side (the next step after a refusal, a stop)
STATUS: Mapping[str, str] = types.MappingProxyType({"cmd": ApiCommand.STATUS.value})
STOP: Mapping[str, str] = types.MappingProxyType({"cmd": ApiCommand.STOP.value})
Ops = Callable[[argparse.Namespace], int]


def socket_of(args: argparse.Namespace) -> Path:
    return socket_path(args.socket)


def print_reply(args: argparse.Namespace, reply: dict[str, Any], text: str) -> None:
    print(json.dumps(reply) if args.json else text)


def say(text: str) -> None:
    """A line on stderr, if it is still there (a closed terminal's is not)."""
    with contextlib.suppress(OSError):
        print(text, file=sys.stderr, flush=True)
