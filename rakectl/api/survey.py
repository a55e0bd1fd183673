"""``rakectl survey``: the site's surveyed surface (``descent.survey``), marked with the rake.

The descent limiter (``descent.enforce``, docs/safety.md "Not covered") lets the tines
down only a step below the highest soil beside them; where no pass has been, that soil
is the survey's, so each survey point must stand at or above the true surface. The
robot cannot find the surface by feel (in a soil soft to the tips the force rises only
millimetres in, or never), so the field engineer finds it by eye: jog the tines down
until they just touch the soil at a crest or a change of slope, stop, and mark.

``rakectl survey mark --error-mm E`` asks the daemon for its pose and appends a point
to the survey file: the highest the tines may stand there (the tip, plus the tine
mount's compression by the force read from the currents, plus that reading's margin:
:meth:`rakectl.core.control.TipController.tines_lift_m`), plus ``E``, how far the tines
may have gone into the soil before the engineer stopped. ``rakectl survey show`` prints
the points as the configuration's ``descent.survey``, sorted by reach (two marks at
one reach keep the higher), checked as the daemon checks them at load.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from rakectl.api.client import call, socket_path
from rakectl.config.descent import SurveyPoint, descent_checks
from rakectl.config.loader import load_settings
from rakectl.config.settings import Settings
from rakectl.errors import ApiError, ConfigError

STILL_STATES = ("armed", "hold")  # the pose is held: a mark taken while moving is not one
DEFAULT_FILE = Path("survey.yaml")
MAX_ERROR_MM = 50.0
SURVEY_DESCRIPTION = (
    "Survey the site's surface with the rake, for the descent limiter (descent.enforce): "
    "the tines go down only a step below the highest soil beside them, which, where no "
    "pass has been, is the survey's (descent.survey), so each point must stand at or "
    "above the true surface. The rake cannot find the surface by feel, so it is found by "
    "eye: with the daemon armed, jog the tines down over each crest and change of slope "
    "until they just touch the soil, stop, and run rakectl survey mark; then rakectl "
    "survey show prints the configuration's block (docs/installation.md, section 5).")
MARK_DESCRIPTION = (
    "Mark the surface where the tines stand now: ask the daemon for its pose and append "
    "a point to the survey file, the highest the tines may stand there (the tip, plus the "
    "tine mount's compression by the force read from the currents, plus "
    "descent.mount_force_margin_n) plus --error-mm, how far the tines may have gone into "
    "the soil before the rake came to rest. Use it while surveying a site, once a jog "
    "has brought the tines down to just touch the soil at a crest or a change of slope "
    "and has been stopped: refused while the rake moves (mark from "
    f"{' or '.join(STILL_STATES)}) or without a pose; nothing is written then.")
SHOW_DESCRIPTION = (
    "Print the survey file's marks as the configuration's descent.survey block: sorted by "
    "reach, the higher of two marks at one reach kept, heights rounded up to the "
    "micrometre, and checked as the daemon checks them at load (in increasing reach, none "
    "above --config's descent.ceiling_m). Use it once the site is marked: paste the "
    "block into the daemon's configuration (systemctl restart rakectl loads it). Every "
    "crest needs a mark: between two points the higher stands for the surface.")


@dataclasses.dataclass(frozen=True)
class Mark:
    """One marked point: where the tines were, and what was added to it."""

    reach_m: float
    tines_height_max_m: float  # the tip plus the mount's compression, from the daemon
    error_m: float  # the engineer's: how far the tines may have been in the soil

    @property
    def point(self) -> SurveyPoint:
        return SurveyPoint(self.reach_m, self.tines_height_max_m + self.error_m)


def error_in_range(error_m: float) -> bool:
    """Whether a mark's added error is one ``survey mark`` takes (never negative: that
    would lower the point below the tines)."""
    return math.isfinite(error_m) and 0.0 <= error_m <= MAX_ERROR_MM * 1e-3


def check_error(error_m: float) -> None:
    if not error_in_range(error_m):
        raise ConfigError(f"survey: --error-mm must be within 0–{MAX_ERROR_MM:g} mm, got "
                       f"{error_m * 1e3:g}")


def mark_from_status(reply: Mapping[str, Any], error_m: float) -> Mark:
    """The mark a ``status`` reply gives, or why it gives none (a ConfigError for the
    operator's --error-mm, an ApiError for the daemon's state)."""
    check_error(error_m)
    state = reply.get("state")
    if state not in STILL_STATES:
        raise ApiError(f"survey: the daemon is {state}: mark with the rake held still "
                       f"({' or '.join(STILL_STATES)}; stop the jog first)")
    tip = reply.get("tip") or {}
    reach_m, height_m = tip.get("reach_m"), tip.get("tines_height_max_m")
    if not (isinstance(reach_m, (int, float)) and isinstance(height_m, (int, float))
            and math.isfinite(reach_m) and math.isfinite(height_m)):
        raise ApiError("survey: the daemon reports no pose (no joint feedback, or a daemon "
                       "older than the survey): nothing marked")
    return Mark(float(reach_m), float(height_m), error_m)


def read_marks(path: Path) -> list[Mark]:
    """The marks in a survey file (none if it does not exist); a ConfigError naming the
    file and the mark if one is not a mark."""
    if not path.exists():
        return []
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__  # one line
        raise ConfigError(f"{path}: not a survey file: {first}") from None
    marks = data.get("marks") if isinstance(data, dict) else None
    if not isinstance(marks, list):
        raise ConfigError(f"{path}: not a survey file: no 'marks' list")
    out = []
    for i, item in enumerate(marks):
        try:
            values = [item[k] for k in ("reach_m", "tines_height_max_m", "error_m")]
            if any(isinstance(v, bool) or not isinstance(v, int | float) for v in values):
                raise TypeError  # YAML's true or '1.1' is no number of a mark
            mark = Mark(*(float(v) for v in values))
        except (TypeError, KeyError, ValueError, OverflowError):
            raise ConfigError(f"{path}: marks[{i}]: expected reach_m, tines_height_max_m and "
                              f"error_m numbers, got {item!r}") from None
        if not all(map(math.isfinite, dataclasses.astuple(mark))):
            raise ConfigError(f"{path}: marks[{i}]: a number is not finite: {item!r}")
        if not error_in_range(mark.error_m):
            raise ConfigError(f"{path}: marks[{i}]: error_m must be within 0–"
                              f"{MAX_ERROR_MM * 1e-3:g} m, as `survey mark` takes it, got "
                              f"{mark.error_m:g}")
        out.append(mark)
    return out


def append_mark(path: Path, mark: Mark) -> int:
    """Add ``mark`` to the file (written whole, then renamed: an interruption loses
    nothing already marked); returns how many marks it holds."""
    marks = [*read_marks(path), mark]
    text = ("# rakectl survey marks: `rakectl survey show` prints them as descent.survey\n"
            + yaml.safe_dump({"marks": [dataclasses.asdict(m) for m in marks]},
                             sort_keys=False))
    partial = path.with_name(path.name + ".partial")
    try:
        partial.write_text(text, encoding="utf-8")
        partial.replace(path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write the survey file: "
                          f"{exc.strerror or exc}") from None
    return len(marks)


def _up_to_um(value_m: float) -> float:
    """Rounded up to the micrometre (a height never printed lower than it is), the
    arithmetic's last bits forgiven."""
    return math.ceil(round(value_m * 1e6, 3)) / 1e6


def survey_points(marks: Sequence[Mark]) -> tuple[SurveyPoint, ...]:
    """The points in increasing reach, to the micrometre (heights rounded up); marks at
    one reach keep the highest."""
    highest: dict[float, float] = {}
    for mark in marks:
        point = mark.point
        reach_m, height_m = round(point.reach_m, 6), _up_to_um(point.height_m)
        highest[reach_m] = max(height_m, highest.get(reach_m, -math.inf))
    return tuple(SurveyPoint(r, highest[r]) for r in sorted(highest))


def survey_yaml(points: Sequence[SurveyPoint]) -> str:
    """The configuration's ``descent.survey`` block, with how to paste it."""
    lines = ["# descent.survey: paste as it is, or, where the configuration has a descent:",
             "# section already, the survey: lines alone into that section",
             "descent:", "  survey:"]
    lines += [f"    - {{reach_m: {p.reach_m:.6f}, height_m: {p.height_m:.6f}}}" for p in points]
    return "\n".join(lines) + "\n"


def mark(args: argparse.Namespace) -> int:
    check_error(args.error_mm * 1e-3)  # before anything is asked of the daemon
    read_marks(args.file)  # a file that is not a survey: said now, not after the daemon
    if not args.file.parent.is_dir():
        raise ConfigError(f"{args.file}: cannot write the survey file: no directory "
                          f"{args.file.parent}")
    reply = call(socket_path(args.socket), {"cmd": "status"})
    new = mark_from_status(reply, args.error_mm * 1e-3)
    count = append_mark(args.file, new)
    if args.json:
        print(json.dumps({**dataclasses.asdict(new), "height_m": new.point.height_m,
                          "marks": count, "file": str(args.file)}))
        return 0
    print(f"survey: mark {count} in {args.file}: reach {new.reach_m:.4f} m, surface at most "
          f"{1e3 * new.point.height_m:+.1f} mm (the tines at most "
          f"{1e3 * new.tines_height_max_m:+.1f} mm, {args.error_mm:g} mm added)")
    return 0


def show(args: argparse.Namespace) -> int:
    marks = read_marks(args.file)
    for i, one in enumerate(marks):  # each option's declared bounds, as the loader's,
        point = one.point  # named by the file's mark
        for f in dataclasses.fields(SurveyPoint):
            problem = f.metadata["bounds"].violation(getattr(point, f.name))
            if problem:
                raise ConfigError(f"{args.file}: marks[{i}]: descent.survey's {f.name} "
                                  f"{problem}")
    points = survey_points(marks)
    if not points:
        raise ConfigError(f"{args.file}: no marks: `rakectl survey mark` adds them")
    settings: Settings = load_settings(args.config)
    descent = dataclasses.replace(settings.descent, survey=points)
    for dotted, message in descent_checks(descent, settings.clamp.force_limit_n,
                                          settings.clamp.model_margin):
        if dotted.startswith("descent.survey"):
            raise ConfigError(f"{args.file}: {dotted} {message}")
    sys.stdout.write(survey_yaml(points))
    gaps = [b.reach_m - a.reach_m for a, b in itertools.pairwise(points)]
    plural = "s" if len(points) != 1 else ""
    print(f"survey: {len(points)} point{plural}, reach {points[0].reach_m:.3f}–"
          f"{points[-1].reach_m:.3f} m, widest gap {1e3 * max(gaps, default=0.0):.0f} mm "
          "(between two points the higher stands for the surface: mark every crest)",
          file=sys.stderr)
    return 0


def add_parser(sub: Any, parent: argparse.ArgumentParser) -> dict[str, Any]:
    """``rakectl survey mark|show``; returns the command's function by name."""
    p = sub.add_parser("survey", help="mark the site's surface with the rake, and print it "
                       "as descent.survey (the descent limiter's input)",
                       description=SURVEY_DESCRIPTION)
    actions = p.add_subparsers(dest="survey_action", required=True, metavar="mark|show")
    m = actions.add_parser("mark", parents=[parent], help="mark where the tines just touch "
                           "the soil (the rake held still)", description=MARK_DESCRIPTION)
    m.add_argument("--error-mm", type=float, required=True,
                   help="how far the tines may have gone into the soil before the jog "
                   "stopped, mm (added to the point)")
    m.add_argument("--file", type=Path, default=DEFAULT_FILE,
                   help=f"survey file to add to (default {DEFAULT_FILE})")
    s = actions.add_parser("show", help="print the marks as the configuration's "
                           "descent.survey, checked", description=SHOW_DESCRIPTION)
    s.add_argument("--file", type=Path, default=DEFAULT_FILE,
                   help=f"survey file (default {DEFAULT_FILE})")
    s.add_argument("--config", type=Path, default=None,
                   help="the daemon's configuration, whose descent.ceiling_m the points "
                   "must not exceed (default: the defaults)")

    def run(args: argparse.Namespace) -> int:
        return mark(args) if args.survey_action == "mark" else show(args)

    return {"survey": run}
