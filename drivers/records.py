"""What the emulator records and counts: its ground truth as CSV (one row per physics
step, :data:`TRUTH_COLUMNS`), the bus edge's counters and time per part, and a log that
reports a growing count at most once per interval."""

from __future__ import annotations

import math
from typing import Any, Final, TextIO

from drivers.stats import InputStats

LOG_INTERVAL_S: Final = 1.0  # at most one log event per kind per this
TRUTH_COLUMNS: Final = (
    "t_s", "sync_counter", "r_m", "theta_rad", "voltage_r_v", "voltage_theta_v", "current_r_a",
    "current_theta_a", "tip_reach_m", "tip_height_m", "force_down_n", "force_drag_n",
    "contact", "mine_activated", "r_state", "r_nmt", "theta_state", "theta_nmt",
    "mine_plate_max_n", "mine_side_max_n", "wall_time_s",
)
TRUTH_ROW: Final = ("%.6f,%d,%.7f,%.7f,%.4f,%.4f,%.5f,%.5f,%.6f,%.6f,%.4f,%.4f,%s,%d,%s,%s,%s,%s,"
                     "%.4f,%.4f,%.6f\n")


class EmulatorStats:
    """Counters of the bus edge and the time spent per part (summarized off the hot path)."""

    __slots__ = ("bad", "dropped_periods", "frames_in", "frames_out", "physics_s",
                 "physics_steps", "protocol_s", "rx_dropped", "syncs", "tx_dropped",
                 "tx_errors", "tx_silenced")

    def __init__(self) -> None:
        self.bad = InputStats()
        self.frames_in = self.frames_out = self.syncs = self.physics_steps = 0
        self.rx_dropped = self.tx_dropped = self.tx_silenced = self.tx_errors = 0
        self.dropped_periods = 0
        self.protocol_s = self.physics_s = 0.0  # handling frames (physics excluded); physics

    def per_sync_us(self) -> tuple[float, float]:
        """Mean µs of the protocol per SYNC and of the physics per control period.

        The protocol part is all frame handling (decoding, the drives, sending) over the
        SYNCs received; the physics part one period of arm, soil and drive sampling.
        """
        return (self.protocol_s / max(self.syncs, 1) * 1e6,
                self.physics_s / max(self.physics_steps, 1) * 1e6)


class TruthRecorder:
    """Ground truth as CSV, one row per physics step, written in batches."""

    def __init__(self, out: TextIO, batch_rows: int = 500) -> None:
        self._out, self._batch_rows, self._rows = out, batch_rows, list[str]()
        out.write(",".join(TRUTH_COLUMNS) + "\n")

    def add(self, row: str) -> None:
        self._rows.append(row)
        if len(self._rows) >= self._batch_rows:
            self._out.write("".join(self._rows))
            self._rows.clear()

    def flush(self) -> None:
        self._out.write("".join(self._rows))
        self._rows.clear()
        self._out.flush()


class RateLimitedLog:
    """Logs a growing count at most once per interval per key, with the count."""

    def __init__(self, log: Any, interval_s: float = LOG_INTERVAL_S) -> None:
        self._log, self._interval_s = log, interval_s
        self._last: dict[str, tuple[float, int]] = {}

    def update(self, event: str, key: str, count: int, now_s: float, **fields: Any) -> None:
        last_s, last_count = self._last.get(key, (-math.inf, 0))
        if count != last_count and now_s - last_s >= self._interval_s:
            self._last[key] = (now_s, count)
            self._log.warning(event, count=count, new=count - last_count, **fields)
