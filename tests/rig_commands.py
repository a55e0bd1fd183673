"""A command handed to a lock-step rig's daemon as the socket hands it over in the loop."""

from __future__ import annotations

from typing import Any

from rakectl.api.schema import Request, decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.daemon.handlers import make_handler


def command(rig: LockstepRig, line: bytes) -> dict[str, Any]:
    """``line`` decoded as the server decodes it (a refusal fails the test) and answered
    by the daemon's handler; a refused command raises its CommandRejected."""
    request = decode_request(line)
    assert isinstance(request, Request), request
    return dict(make_handler(rig.daemon)(request))
