"""What the viewer logs: the daemon's status, the emulator's ground truth and the
flight recorder's rows, each mapped onto the topics of :mod:`rakectl.view.topics`.

The daemon is read through its command socket's ``status`` only (read-only, served in
the loop's slack like any status request): at 50 Hz it costs the loop what a status
client costs (bench/BENCHMARKS.md measures the loop with one at 100 Hz).
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

from rakectl.api.client import Client
from rakectl.errors import ApiError, ConfigError
from rakectl.view.topics import Box, Publisher

NS = 1_000_000_000


def _f(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) else math.nan


def log_status(pub: Publisher, reply: Mapping[str, Any], time_ns: int,
               objects: Iterable[Box] = (), lane_m: tuple[float, float] | None = None) -> None:
    """One status reply (rakectl.daemon.handlers.status) as the topics at ``time_ns``;
    without ``lane_m``, the lane's reach span is the status's (``excavation.lane``)."""
    joints, tip = reply.get("joints", {}), reply.get("tip", {})
    force, volts = reply.get("force", {}), reply.get("voltages", {})
    r_m, theta_rad = _f(joints.get("r_m")), _f(joints.get("theta_rad"))
    reach_m, depth_m = _f(tip.get("reach_m")), _f(tip.get("depth_m"))
    pub.rake(time_ns, -depth_m + r_m * math.sin(theta_rad), reach_m, -depth_m)
    ex = reply.get("excavation") or {}
    found, lane = ex.get("object_found"), ex.get("lane") or {}
    if lane_m is None and "reach_near_m" in lane:  # the lane as the daemon says it
        lane_m = (_f(lane["reach_near_m"]), _f(lane.get("reach_far_m")))
    pub.ground(time_ns, lane_m, ex.get("depth_m"), objects,
               (found["reach_m"], found["depth_m"]) if found else None)
    pub.json("/force", time_ns, {
        "f_hat_n": _f(force.get("f_hat_n")), "f_current_n": _f(force.get("f_current_n")),
        "clamp_worst_case_n": _f(force.get("clamp_worst_case_n")),
        "clamp_budget_n": _f(force.get("clamp_budget_n")),
        "clamp_limit_n": _f(force.get("clamp_limit_n"))})
    pub.json("/voltage", time_ns, {k: _f(volts.get(k)) for k in (
        "requested_r_v", "requested_theta_v", "applied_r_v", "applied_theta_v")})
    pub.json("/state", time_ns, {
        "state": reply.get("state", ""), "level": force.get("level"),
        "fault": reply.get("fault"), "phase": ex.get("phase"), "cycle": ex.get("cycle"),
        "lane": lane.get("number")})
    latency = (reply.get("timing") or {}).get("latency_ns") or {}
    pub.json("/timing", time_ns, {
        "latency_p50_us": _f(latency.get("p50")) * 1e-3,
        "latency_p99_us": _f(latency.get("p99")) * 1e-3,
        "latency_max_us": _f(latency.get("max")) * 1e-3,
        "late_ticks": _f((reply.get("timing") or {}).get("overruns")),
        "ticks": _f(reply.get("ticks"))})


def log_truth_row(pub: Publisher, row: Mapping[str, str], time_ns: int) -> None:
    """One row of the emulator's ground truth (drivers.records.TRUTH_COLUMNS)."""
    pub.json("/truth", time_ns, {
        "force_down_n": float(row["force_down_n"]), "force_drag_n": float(row["force_drag_n"]),
        "mine_plate_max_n": float(row["mine_plate_max_n"]),
        "mine_side_max_n": float(row["mine_side_max_n"]),
        "tip_reach_m": float(row["tip_reach_m"]), "tip_height_m": float(row["tip_height_m"]),
        "contact": row["contact"], "mine_activated": row["mine_activated"] == "1"})


def truth_time_ns(row: Mapping[str, str]) -> int:
    """A truth row's time: the wall clock the emulator wrote, else its own clock."""
    wall = row.get("wall_time_s")
    return round(float(wall if wall else row["t_s"]) * NS)


class TruthTail:
    """Reads the rows an emulator appends to its truth CSV from now on (a file of a long
    run is not read from its start), as they come."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file: TextIO | None = None
        self._header: list[str] | None = None
        self._partial = ""
        self.bad_rows = 0

    def rows(self) -> Iterator[dict[str, str]]:
        """The whole rows written since the last call (none before the file exists);
        a row that is not the header's shape is skipped and counted."""
        if self._file is None:
            if not self.path.is_file():
                return
            f = self.path.open(newline="")
            header = f.readline()
            if not header.endswith("\n"):  # created, its header not written yet
                f.close()
                return
            self._file, self._header = f, header.rstrip("\n").split(",")
            self._file.seek(0, 2)  # the end: what comes from now on
            return
        self._partial += self._file.read()
        *lines, self._partial = self._partial.split("\n")
        for line in lines:
            fields = next(csv.reader([line]), [])
            if self._header is None or len(fields) != len(self._header):
                self.bad_rows += 1
                continue
            yield dict(zip(self._header, fields, strict=True))

    def close(self) -> None:
        if self._file is not None:
            self._file.close()


class StatusStream:
    """Polls the daemon's status at ``rate_hz`` and logs each reply; with ``truth``, the
    emulator's new truth rows too (every ``truth_every``-th, to keep the rate down)."""

    def __init__(self, socket: Path, pub: Publisher, rate_hz: float,
                 objects: Iterable[Box] = (), lane_m: tuple[float, float] | None = None,
                 truth: Path | None = None, truth_every: int = 10) -> None:
        if not 1.0 <= rate_hz <= 200.0:
            raise ConfigError(f"view: rate_hz must be within 1..200, got {rate_hz:g}")
        self.socket, self.pub, self.period_s = socket, pub, 1.0 / rate_hz
        self.objects, self.lane_m = tuple(objects), lane_m
        self._truth = TruthTail(truth) if truth is not None else None
        self._truth_every, self._truth_seen = max(1, truth_every), 0
        self.replies = self.errors = self.truth_rows = 0
        self.last_error = ""

    def run(self, keep_going: Callable[[], bool], clock: Callable[[], float] = time.monotonic
            ) -> None:
        """Poll until ``keep_going()`` is false; an unreachable daemon is retried (logged
        as ``last_error``), never fatal: the viewer outlives daemon restarts."""
        client: Client | None = None
        next_s = clock()
        try:
            while keep_going():
                try:
                    if client is None:
                        client = Client(self.socket, timeout_s=1.0)
                    reply = client.request({"cmd": "status"})
                except (ApiError, OSError) as exc:
                    self.errors += 1
                    self.last_error = str(exc)
                    if client is not None:
                        client.close()
                    client = None
                else:
                    self.replies += 1
                    log_status(self.pub, reply, time.time_ns(), self.objects, self.lane_m)
                self._log_truth()
                next_s += self.period_s
                time.sleep(max(0.0, next_s - clock()))
                next_s = max(next_s, clock() - self.period_s)  # no burst after a stall
        finally:
            if client is not None:
                client.close()
            if self._truth is not None:
                self._truth.close()

    def _log_truth(self) -> None:
        if self._truth is None:
            return
        for row in self._truth.rows():
            self._truth_seen += 1
            if self._truth_seen % self._truth_every == 0:
                try:
                    log_truth_row(self.pub, row, truth_time_ns(row))
                    self.truth_rows += 1
                except (KeyError, ValueError) as exc:  # not a truth file's row: skipped
                    self._truth.bad_rows += 1
                    self.last_error = f"{self._truth.path}: {exc!r}"

    @property
    def truth_bad_rows(self) -> int:
        return self._truth.bad_rows if self._truth is not None else 0
