"""Recordings as MCAP, with the live view's topics (:mod:`rakectl.view.topics`): the
flight recorder's dumps, the emulator's ground truth and ``rakectl simulate``'s
telemetry (``rakectl mcap``, ``rakectl simulate --mcap``), and the demo's run
(:func:`recording`, fed by a :class:`~rakectl.view.stream.StatusStream`).
CSV stays: these are written next to it, from it.
"""

from __future__ import annotations

import contextlib
import csv
import math
from collections.abc import Iterable, Iterator
from pathlib import Path

from rakectl.core.supervision import ForceLevel
from rakectl.daemon.states import DaemonState
from rakectl.errors import ConfigError, RakeError
from rakectl.view.stream import NS, log_truth_row, truth_time_ns
from rakectl.view.topics import Box, Publisher, require_foxglove

DUMP_KEYS = ("t_s", "state", "reach_m", "depth_m", "f_hat_n", "voltage_r_req_v",
             "voltage_theta_req_v", "voltage_r_v", "voltage_theta_v", "clamp_worst_case_n",
             "r_m", "theta_rad", "f_current_n", "force_level")
TELEMETRY_KEYS = ("t_s", "f_hat_n", "r_m", "theta_rad", "tip_reach_m", "tip_depth_m",
                  "voltage_r_req_v", "voltage_theta_req_v", "voltage_r_v", "voltage_theta_v",
                  "f_true_z_n", "f_current_n", "force_level", "mine_activated")
TRUTH_KEYS = ("t_s", "force_down_n", "force_drag_n", "tip_reach_m", "tip_height_m", "r_m",
              "theta_rad", "voltage_r_v", "voltage_theta_v", "contact", "mine_activated",
              "mine_plate_max_n", "mine_side_max_n")


@contextlib.contextmanager
def recording(path: Path) -> Iterator[Publisher]:
    """A publisher whose messages go to the MCAP file ``path`` only (its own context:
    never to a live server); the file is complete when the block ends."""
    foxglove = require_foxglove()
    partial = path.with_name(path.name + ".partial")
    context = foxglove.Context()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        writer = foxglove.open_mcap(partial, allow_overwrite=True, context=context)
    except Exception as exc:  # the SDK raises its own error types for I/O
        raise RakeError(f"mcap: cannot write {path}: {exc}") from exc
    try:
        yield Publisher(context)
    except BaseException:
        writer.close()
        partial.unlink(missing_ok=True)  # a failed recording replaces nothing
        raise
    writer.close()
    partial.replace(path)  # whole, or not there: an earlier file stays until then


MCAP_MAGIC = b"\x89MCAP"  # the first bytes of every MCAP file


def check_output(path: Path, option: str, source: Path | None = None,
                 replace_mcap: bool = True) -> None:
    """ConfigError naming ``option`` unless ``path`` can take a new file: not a directory,
    not ``source`` (the file read), not an existing file other than an MCAP (which, made
    from the file it is read from, is made again; ``replace_mcap`` False: not that
    either); a directory that does not exist is made."""
    if path.name in ("", ".", "..") or path.is_dir():
        raise ConfigError(f"{option} {path} is a directory, not a file")
    if source is not None and path.resolve() == source.resolve():
        raise ConfigError(f"{option} {path} is the file it reads: it would be replaced")
    if path.exists():
        with path.open("rb") as f:
            mcap = f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
        if not (mcap and replace_mcap):
            raise ConfigError(f"{option} {path} exists" + (" and is not an MCAP file" if not
                              mcap else "") + ": it is never replaced; choose another name")


def check_columns(path: Path, needed: Iterable[str]) -> None:
    """Refuse a CSV without these columns, naming the first missing ones."""
    try:
        with path.open(newline="") as f:
            header = next(csv.reader(f), [])
    except OSError as exc:
        raise ConfigError(f"mcap: cannot read {path}: {exc.strerror or exc}") from exc
    missing = [k for k in needed if k not in header]
    if missing:
        raise ConfigError(f"mcap: {path} is not a flight-recorder dump, an emulator truth "
                          f"file or a simulated rake's telemetry: no column "
                          f"{', '.join(missing)}")


def _rows(path: Path, needed: Iterable[str]) -> Iterator[dict[str, str]]:
    """The rows of a CSV with these columns; a row cut short (a file still being
    written) ends it, any other bad row is refused naming its line."""
    check_columns(path, needed)
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        for row in reader:
            if None in row.values():  # fewer fields than the header: cut short
                return
            try:
                for key in needed:
                    if key not in ("contact", "state", "force_level"):
                        float(row[key])
            except ValueError as exc:
                raise ConfigError(f"mcap: {path}, line {reader.line_num}: {exc}") from exc
            yield row


def _name(enum_type: type[DaemonState] | type[ForceLevel], code: str) -> str:
    try:
        return enum_type(int(float(code))).name.lower()
    except ValueError:
        return f"code {code}"


def dump_to_mcap(dump: Path, out: Path, every: int = 1, objects: Iterable[Box] = ()) -> int:
    """A flight-recorder dump (rakectl.daemon.loop.RECORDER_COLUMNS) as MCAP, one row in
    ``every``; its clock is the daemon's (seconds since start). Returns the rows written."""
    written = 0
    check_columns(dump, DUMP_KEYS)
    with recording(out) as pub:
        for k, row in enumerate(_rows(dump, DUMP_KEYS)):
            if k % every:
                continue
            t_ns = round(float(row["t_s"]) * NS)
            r_m, theta_rad = float(row["r_m"]), float(row["theta_rad"])
            reach_m, depth_m = float(row["reach_m"]), float(row["depth_m"])
            pub.rake(t_ns, -depth_m + r_m * math.sin(theta_rad), reach_m, -depth_m)
            if written == 0:
                pub.ground(t_ns, None, None, objects, None)
            pub.json("/force", t_ns, {"f_hat_n": float(row["f_hat_n"]),
                                      "f_current_n": float(row["f_current_n"]),
                                      "clamp_worst_case_n": float(row["clamp_worst_case_n"])})
            pub.json("/voltage", t_ns, {
                "requested_r_v": float(row["voltage_r_req_v"]),
                "requested_theta_v": float(row["voltage_theta_req_v"]),
                "applied_r_v": float(row["voltage_r_v"]),
                "applied_theta_v": float(row["voltage_theta_v"])})
            pub.json("/state", t_ns, {"state": _name(DaemonState, row["state"]),
                                      "level": _name(ForceLevel, row["force_level"])})
            written += 1
    return written


def truth_rows_to(pub: Publisher, truth: Path, every: int = 10,
                  objects: Iterable[Box] = (), pivot_height_m: float | None = None) -> int:
    """The emulator's ground truth onto ``pub``, one row in ``every``: /truth, and /rake
    from the true pose when ``pivot_height_m`` is given. Returns the rows written."""
    written = 0
    for k, row in enumerate(_rows(truth, TRUTH_KEYS)):
        if k % every:
            continue
        t_ns = truth_time_ns(row)
        if written == 0:
            pub.ground(t_ns, None, None, objects, None)
        log_truth_row(pub, row, t_ns)
        if pivot_height_m is not None:
            pub.rake(t_ns, pivot_height_m, float(row["tip_reach_m"]), float(row["tip_height_m"]))
        written += 1
    return written


def truth_to_mcap(truth: Path, out: Path, every: int = 10, objects: Iterable[Box] = ()
                  ) -> int:
    """The emulator's ground truth (drivers.records.TRUTH_COLUMNS) alone as MCAP."""
    check_columns(truth, TRUTH_KEYS)
    with recording(out) as pub:
        first = next(_rows(truth, TRUTH_KEYS), None)
        pivot = (float(first["tip_height_m"]) + float(first["r_m"])
                 * math.sin(float(first["theta_rad"]))) if first else None
        return truth_rows_to(pub, truth, every, objects, pivot)


def telemetry_to_mcap(telemetry: Path, out: Path, every: int = 1,
                      objects: Iterable[Box] = ()) -> int:
    """``rakectl simulate``'s telemetry of the simulated rake (rakectl.sim.rake_plant) as
    MCAP, one row in ``every``; simulated time from 0. Returns the rows written."""
    written = 0
    check_columns(telemetry, TELEMETRY_KEYS)
    with recording(out) as pub:
        for k, row in enumerate(_rows(telemetry, TELEMETRY_KEYS)):
            if k % every:
                continue
            t_ns = round(float(row["t_s"]) * NS)
            r_m, theta_rad = float(row["r_m"]), float(row["theta_rad"])
            reach_m, depth_m = float(row["tip_reach_m"]), float(row["tip_depth_m"])
            pub.rake(t_ns, -depth_m + r_m * math.sin(theta_rad), reach_m, -depth_m)
            if written == 0:
                pub.ground(t_ns, None, None, objects, None)
            pub.json("/force", t_ns, {"f_hat_n": float(row["f_hat_n"]),
                                      "f_current_n": float(row["f_current_n"])})
            pub.json("/voltage", t_ns, {
                "requested_r_v": float(row["voltage_r_req_v"]),
                "requested_theta_v": float(row["voltage_theta_req_v"]),
                "applied_r_v": float(row["voltage_r_v"]),
                "applied_theta_v": float(row["voltage_theta_v"])})
            pub.json("/state", t_ns, {"state": "simulated",
                                      "level": _name(ForceLevel, row["force_level"])})
            pub.json("/truth", t_ns, {"force_down_n": float(row["f_true_z_n"]),
                                      "tip_reach_m": reach_m, "tip_height_m": -depth_m,
                                      "mine_activated": row["mine_activated"] not in ("0", "0.0")})
            written += 1
    return written
