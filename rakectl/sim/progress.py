"""Progress reporting for long work, on stderr, only once the work has taken a while."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    """Callable ``(done, total)``: silent for ``quiet_s``, then a line at most every ``every_s``.

    On a terminal the line is redrawn in place; elsewhere (logs, CI) a new line
    is printed less often.
    """

    def __init__(self, label: str, stream: TextIO | None = None, quiet_s: float = 2.0,
                 every_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty()
        self.quiet_s = quiet_s
        self.every_s = every_s if every_s is not None else (0.25 if self.tty else 5.0)
        self._clock = clock
        self._start = clock()
        self._last = -float("inf")
        self._shown = False
        self._base = 0  # done before the start (resumed): not this run's pace

    def skip(self, done: int) -> None:
        """``done`` items were finished before this run (read back): the time left is
        judged by the pace of the rest alone."""
        self._base = done

    def __call__(self, done: int, total: int) -> None:
        now = self._clock()
        elapsed = now - self._start
        finished = done >= total
        if elapsed < self.quiet_s or (now - self._last < self.every_s and not finished):
            return
        if finished and not self._shown:
            return
        self._last = now
        self._shown = True
        share = done / total if total else 1.0
        here = done - self._base  # finished in this run
        eta = elapsed * (total - done) / here if here > 0 else float("inf")
        text = (f"{self.label}: {100 * share:5.1f}% ({done}/{total}), "
                f"{elapsed:.0f} s, ~{eta:.0f} s left")
        end = "\n" if finished or not self.tty else ""
        self.stream.write(("\r" if self.tty else "") + text + end)
        self.stream.flush()
