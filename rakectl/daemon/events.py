"""The loop's log lines, queued in the tick and written in its slack.

The tick never formats or writes a log line: it appends (name, fields) to a
bounded queue, and the slack writes a few at a time through structlog. Events
that repeat every tick or so (timing summaries) are written at most once per
``every_s``. Faults are logged as errors, refusals and failures as warnings.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable, Iterable
from typing import Any

from rakectl.drive.joints import DriveInfo

QUEUE_LENGTH = 256  # events kept while the slack is too short to write them (oldest dropped)
LOG_EVERY_S = 1.0  # a rate-limited event is written at most this often


WARNINGS = frozenset({"arm_refused", "timing_warning", "clamp_warning", "recorder_dump_failed",
                      "reset_failed", "force_limit", "object_found", "trace_failed",
                      "descent_limit", "drive_rpdo_kept_valid"})
ERROR_STATES = frozenset({"FAULT", "ESTOP"})


def level_of(name: str, fields: dict[str, Any]) -> str:
    """The log level of an event: entering FAULT or ESTOP and a failed check before arming are
    errors, refusals and failures warnings (``journalctl -p warning`` shows them), the
    rest info."""
    if name == "state" and fields.get("new") in ERROR_STATES:
        return "error"
    if name in ("weight_check", "mount_check") and not fields.get("passed", True):
        return "error"
    return "warning" if name in WARNINGS else "info"


class EventLog:
    """A bounded queue of log events, written off the hot path to ``log`` (a structlog logger)."""

    def __init__(self, log: Any, rate_limited: Iterable[str] = (),
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._queue: collections.deque[tuple[str, dict[str, Any]]] = collections.deque(
            maxlen=QUEUE_LENGTH)
        self._rate_limited = frozenset(rate_limited)
        self._last_s: dict[str, float] = {}
        self._clock_s = clock_s

    def __len__(self) -> int:
        return len(self._queue)

    def add(self, name: str, fields: dict[str, Any]) -> None:
        """Queue one event (O(1), no formatting)."""
        self._queue.append((name, fields))

    def flush(self, state: str, count: int | None = None) -> None:
        """Write up to ``count`` queued events (all if None), each with the loop's ``state``."""
        now = self._clock_s()
        queue = self._queue
        for _ in range(len(queue) if count is None else min(count, len(queue))):
            name, fields = queue.popleft()
            if name in self._rate_limited and \
                    now - self._last_s.get(name, -math.inf) < LOG_EVERY_S:
                continue
            self._last_s[name] = now
            getattr(self._log, level_of(name, fields))(name, state=state, **fields)


def drive_summary(info: DriveInfo) -> dict[str, Any]:
    """A drive after bring-up, as the fields of
    ``drives_configured``."""
    return {"node": info.node_id, "serial": info.identity.serial,
            "max_voltage_mv": info.limits.max_voltage_mv,
            "cleared_fault": f"0x{info.cleared_fault:04X}" if info.cleared_fault else None,
            "pdos_made_not_valid": [p.name for p in info.extra if not p.kept]}


def kept_rpdos(infos: Iterable[DriveInfo]) -> list[dict[str, Any]]:
    """The fields of a ``drive_rpdo_kept_valid`` warning for each RPDO beyond the EDS's
    that a drive keeps valid (rakectl.drive.pdos)."""
    return [{"node": info.node_id, "pdo": pdo.name, "can_id": f"0x{pdo.cob_id & 0x7FF:03X}",
             "why": pdo.kept} for info in infos for pdo in info.extra if pdo.kept]
