"""``rakectl demo``: the whole system on an emulated bench, in about a minute.

Starts the emulated drives (with a buried mine) and the daemon as separate
processes on one bus (rakectl.sim.rig), arms, rakes a demo lane deeper
each cycle until the rake finds the mine, stops, and reports what the
controller saw next to the emulator's ground truth; the run is recorded as
demo.mcap (the daemon's status at 50 Hz and the truth at 100 Hz, for Foxglove).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rakectl.api.motion import follow_excavation
from rakectl.config.files import config_dir
from rakectl.errors import RakeError
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.rig import emulated_bench, namespaces_unavailable
from rakectl.view.record import recording, truth_rows_to
from rakectl.view.stream import StatusStream
from rakectl.view.topics import Box, Publisher

# The demo lane: strokes from 1.25 m to 0.92 m reach, 15 mm deeper each cycle,
# down to 60 mm at most; the mine's top is at 25 mm, centred at 1.08 m.
LANE = {"reach_far_m": 1.25, "reach_near_m": 0.92, "target_depth_m": 0.06,
        "depth_step_m": 0.015, "stroke_speed_m_per_s": 0.06}
MINE = (1.08, 0.025, 0.08, 0.05)  # reach, top depth, width, thickness (config/emulator-demo.yaml)
STREAM_HZ = 50.0  # the daemon's status into demo.mcap


def _config(name: str) -> Path:
    path = config_dir() / name
    if not path.is_file():
        raise RakeError(f"{path} is missing: run the demo from a checkout of rakectl")
    return path


def truth_figures(truth_csv: Path) -> dict[str, Any]:
    """From the emulator: the largest true vertical force on the ground (sampled every
    1 ms), the largest force on a mine's plate and on its side, and mine activation."""
    f_max = plate_n = side_n = 0.0
    activated, rows = False, 0
    with open(truth_csv, newline="") as f:
        for row in csv.DictReader(f):
            rows += 1
            f_max = max(f_max, float(row["force_down_n"]))
            plate_n = max(plate_n, float(row["mine_plate_max_n"]))
            side_n = max(side_n, float(row["mine_side_max_n"]))
            activated = activated or row["mine_activated"] == "1"
    return {"f_true_z_max_n": f_max, "f_mine_plate_max_n": plate_n,
            "f_mine_side_max_n": side_n, "mine_activated": activated, "truth_rows": rows}


def run_demo(out: Path, as_json: bool, drive_profile: str = "cia402") -> int:
    """``drive_profile``: ``drives.profile`` of the emulator and the daemon alike."""
    reason = namespaces_unavailable()
    if reason:
        raise RakeError(f"the demo needs a private network namespace for its bus: {reason}")
    status_out = sys.stderr
    profile = [f"--set drives.profile={drive_profile}"]
    with recording(out / "demo.mcap") as pub:
        with emulated_bench(out, _config("emulator-demo.yaml"),
                            _config("rakectl-emulated.yaml"), emulator_args=profile,
                            daemon_args=profile) as bench:
            print(f"demo: starting the emulated drives ({drive_profile}) and the daemon "
                  f"(logs in {out})", file=status_out)
            bench.wait_for_state(["disarmed"], 60.0)
            with _streaming(bench.socket, pub):
                bench.request("arm")
                armed: dict[str, Any] = bench.wait_for_state(["armed", "fault"], 30.0)
                print(f"demo: {armed['weight_check']['message']}", file=status_out)
                if armed["state"] != "armed":
                    raise RakeError(f"the demo could not arm: {armed['fault']}")
                print("demo: armed; raking the demo lane", file=status_out)
                bench.request("excavate", **LANE)
                final = follow_excavation(bench.socket, status_out, timeout_s=600.0)
                bench.request("disarm")
        truth_rows_to(pub, out / "truth.csv", every=10, objects=[Box(*MINE)])
    summary = _summary(final, truth_figures(out / "truth.csv"))
    summary["drive_profile"] = drive_profile
    _plot(out)
    _report(summary, out, as_json)
    return 0 if summary["object_found"] and not summary["mine_activated"] else 1


@contextlib.contextmanager
def _streaming(socket: Path, pub: Publisher) -> Iterator[StatusStream]:
    """The daemon's status recorded at 50 Hz while the block runs (a thread)."""
    stream = StatusStream(socket, pub, STREAM_HZ, [Box(*MINE)],
                          (LANE["reach_near_m"], LANE["reach_far_m"]))
    stop = threading.Event()
    failed: list[BaseException] = []

    def record() -> None:
        try:
            stream.run(lambda: not stop.is_set())
        except BaseException as exc:  # handed to the demo's own thread below
            failed.append(exc)

    thread = threading.Thread(target=record, name="demo-recording", daemon=True)
    thread.start()
    try:
        yield stream
    finally:
        stop.set()
        thread.join(timeout=10.0)
    if thread.is_alive():
        raise RakeError("demo: the recording thread did not stop within 10 s")
    if failed:
        raise RakeError(f"demo: recording demo.mcap failed: {failed[0]}") from failed[0]


def _summary(final: dict[str, Any], truth: dict[str, Any]) -> dict[str, Any]:
    ex = final.get("excavation") or {}
    found = ex.get("object_found")
    reached = max(ex.get("depth_m", 0.0), found["depth_m"] if found else 0.0)
    return {
        "state": final["state"],
        "depth_reached_m": reached,  # the stroke that met the object counts
        "cycles": ex.get("cycle", 0),
        "f_hat_z_max_n": final["force"]["f_hat_max_n"],
        "f_true_z_max_n": truth["f_true_z_max_n"],
        "f_mine_plate_max_n": truth["f_mine_plate_max_n"],
        "f_mine_side_max_n": truth["f_mine_side_max_n"],
        "object_found": found,
        "mine_activated": truth["mine_activated"],
        "clamped_ticks": final["force"]["clamped_ticks"],
    }


def _plot(out: Path) -> None:
    try:
        from rakectl.sim.plot import plot_bench_run
    except RakeError:
        return
    plot_bench_run(out / "truth.csv", out / "demo.png", [MINE])


def _report(summary: dict[str, Any], out: Path, as_json: bool) -> None:
    found = summary["object_found"]
    where = (f"at reach {found['reach_m']:.3f} m, depth {1e3 * found['depth_m']:.0f} mm"
             if found else "no")
    lines = [
        f"drives             {summary.get('drive_profile', 'cia402')} (drives.profile)",
        f"depth reached      {1e3 * summary['depth_reached_m']:.0f} mm in {summary['cycles']} "
        f"cycle(s)",
        f"object found       {where}",
        f"max vertical force estimated {summary['f_hat_z_max_n']:.1f} N, true "
        f"{summary['f_true_z_max_n']:.1f} N (limit {FORCE_LIMIT_N:g} N)",
        f"force on the mine  plate {summary['f_mine_plate_max_n']:.1f} N, side "
        f"{summary['f_mine_side_max_n']:.1f} N (limit {FORCE_LIMIT_N:g} N)",
        f"mine activated     {'YES' if summary['mine_activated'] else 'no'}",
        f"plot               {out / 'demo.png'}",
        f"recording          {out / 'demo.mcap'} (Foxglove; layout docs/foxglove-layout.json)",
    ]
    print("\n".join(lines))
    if as_json:
        print(json.dumps({k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                          for k, v in summary.items()}))
