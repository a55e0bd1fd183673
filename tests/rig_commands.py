"""A lock-step rig's daemon brought up to DISARMED, and a command handed to it as the
socket hands it over in the loop."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rakectl.api.schema import Request, decode_request
from rakectl.bench.tick import LockstepRig
from rakectl.config.settings import Settings
from rakectl.daemon.handlers import make_handler
from rakectl.daemon.states import DaemonState


@contextlib.contextmanager
def disarmed_rig(directory: Path, defaults: Settings | None = None) -> Iterator[LockstepRig]:
    """The daemon (its settings ``defaults``, else the default ones) and emulated drives in
    lock-step, brought up to DISARMED; closed on the way out."""
    rig = LockstepRig(directory, defaults)
    try:
        rig.bring_up()
        rig.until(DaemonState.DISARMED, 3000)
        yield rig
    finally:
        rig.close()


def command(rig: LockstepRig, line: bytes) -> dict[str, Any]:
    """``line`` decoded as the server decodes it (a refusal fails the test) and answered
    by the daemon's handler; a refused command raises its CommandRejected."""
    request = decode_request(line)
    assert isinstance(request, Request), request
    return dict(make_handler(rig.daemon)(request))
