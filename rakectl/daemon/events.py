"""The loop's log lines, queued in the tick and written in its slack.

The tick never formats or writes a log line: it appends (name, fields) to a
bounded queue, and the slack writes a few at a time through structlog. Events
that repeat every tick or so (timing summaries) are written at most once per
``every_s``.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable, Iterable
from typing import Any

QUEUE_LENGTH = 256  # events kept while the slack is too short to write them (oldest dropped)
LOG_EVERY_S = 1.0  # a rate-limited event is written at most this often


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
            self._log.info(name, state=state, **fields)
