"""Closed-loop safety campaign: randomized scenarios through the full simulated chain.

Each case is a random ground (soil layers two decades of stiffness apart,
heterogeneity, slope and waves; stones, roots, mines with 80–100 N fuses), a
command and, in some cases, injected faults, run through the daemon's own
:class:`~rakectl.core.control.TipController`, the one-tick bus delay and drivers/
physics (:class:`~rakectl.sim.rake_plant.RakeLoop`). The ground truth says whether
the rake tip ever pressed down harder than 90 N and whether a mine fired.

Command kinds:

* ``lane``: rake a lane with the :class:`~rakectl.core.lane.LanePlanner`
  (random reach range, depth step, target depth, stroke speed from 1 cm/s up
  to the configuration's 1 m/s bound, plunge speed), stall detection included.
  Half of them are force-adaptive (``lane.adaptive``: the governed stroke and
  plunge and the adaptive depth of cut, with the case's speeds as the top
  ones where they are above the defaults), fed the same conservative estimate
  the daemon gives them; supervision's holds and stops stay off, as for every
  case.
* ``plunge`` (hostile): a straight reference down from above the ground to
  0.15 m deep at up to 0.25 m/s, half the time right above a mine, with the
  contact flag (impedance) on or off.
* ``stroke`` (hostile): one lane cycle at a fixed depth with a fast stroke.

Faults (per tick, seeded): lost feedback (the controller keeps the previous
measurement), lost command (the drive applies the previous voltages again),
and one drive fault episode (both motors at 0 V for 20–200 ms).

A :class:`FuzzCase` is frozen and holds everything the run depends on, so its
JSON (``to_dict``/``case_from_dict``) rebuilds the exact run.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import json
import math
import sys
import time
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.objects import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.soil import SoilLayer, SoilParams, SurfaceWave, original_surface_height_m
from rakectl.config.settings import LaneSettings
from rakectl.core.clamp import VoltageClamp
from rakectl.core.lane import LanePlanner
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim.parallel import fork_map
from rakectl.sim.progress import Progress
from rakectl.sim.rake_plant import RakeLoop
from rakectl.sim.scenario import PlantKind, PlantSettings, Scenario, TrajectoryKind
from rakectl.sim.simulate import HOLD_AFTER_DONE_S, Reference

PLUNGE_END_DEPTH_M = 0.15
LANE_DURATION_S = 12.0  # cap of one lane or stroke case (simulated)
WORST_CASE_FILE = "worst-case.json"


class CommandKind(enum.StrEnum):
    LANE = "lane"  # rake a lane (normal operation)
    PLUNGE = "plunge"  # hostile: straight down at up to 0.25 m/s
    STROKE = "stroke"  # hostile: one fast stroke at depth


@dataclass(frozen=True)
class Command:
    """What the tip is told to do. For ``plunge``: straight down at ``reach_far_m`` from
    ``start_height_m`` above level 0 to ``target_depth_m`` at ``speed_m_per_s``."""

    kind: CommandKind
    reach_far_m: float
    reach_near_m: float
    depth_step_m: float
    target_depth_m: float
    speed_m_per_s: float  # stroke speed (lane, stroke) or plunge speed (plunge)
    plunge_speed_m_per_s: float
    start_height_m: float
    contact: bool  # plunge only: impedance on (α > 0) or pure position control
    adaptive: bool = False  # lane only: force-adaptive (rakectl.core.governor; see scenario_of)


@dataclass(frozen=True)
class Faults:
    """Injected faults; probabilities are per tick, the drive fault is one episode."""

    seed: int = 0
    feedback_loss_probability: float = 0.0
    command_loss_probability: float = 0.0
    drive_fault_start_s: float = 0.0
    drive_fault_s: float = 0.0  # 0: none

    def kinds(self) -> tuple[str, ...]:
        names = ("feedback", "command", "drive")
        active = (self.feedback_loss_probability > 0, self.command_loss_probability > 0,
                  self.drive_fault_s > 0)
        return tuple(n for n, a in zip(names, active, strict=True) if a)


@dataclass(frozen=True)
class FuzzCase:
    seed: int
    index: int
    ground: GroundParams
    ground_seed: int
    command: Command
    faults: Faults
    duration_s: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def describe(self) -> str:
        c, o = self.command, self.ground.objects
        speed = f"{c.speed_m_per_s:.3f} m/s"
        where = (f"reach {c.reach_far_m:.3f} m" if c.kind is CommandKind.PLUNGE
                 else f"reach {c.reach_far_m:.3f}→{c.reach_near_m:.3f} m")
        layers = ", ".join(f"K_e {la.stiffness_n_per_m:.3g} N/m F_c {la.collapse_force_n:.3g} N"
                           for la in self.ground.soil.layers)
        kind = f"{c.kind} (adaptive)" if c.adaptive else str(c.kind)
        return (f"case {self.seed}/{self.index}: {kind} at {speed}, {where}, depth "
                f"{c.target_depth_m:.3f} m, contact={c.contact}; soil [{layers}]; "
                f"{len(o.stones)} stones, {len(o.roots)} roots, {len(o.mines)} mines; "
                f"faults {list(self.faults.kinds()) or 'none'}")


@dataclass(frozen=True)
class CaseResult:
    seed: int
    index: int
    kind: str
    f_true_z_max_n: float  # largest per-tick peak of the true vertical force
    f_true_z_max_t_s: float
    ticks_over_limit: int  # ticks whose true vertical force peak exceeds 90 N
    mine_activated: bool
    object_found: bool
    duration_s: float
    faults: tuple[str, ...]
    feedback_lost_ticks: int
    commands_lost_ticks: int
    drive_fault_ticks: int
    clamped_ticks: int
    controller_fault: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------- generation


def _loguniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _soil(rng: np.random.Generator) -> SoilParams:
    n = int(rng.integers(1, 4))
    tops = [0.0, *sorted(float(d) for d in rng.uniform(0.02, 0.12, n - 1))]
    layers = tuple(SoilLayer(from_depth_m=round(top, 4),
                             stiffness_n_per_m=_loguniform(rng, 2e4, 2e6),
                             collapse_force_n=_loguniform(rng, 3.0, 60.0),
                             cohesion_pa=float(rng.uniform(2e3, 15e3)))
                   for top in sorted(set(round(t, 4) for t in tops)))
    waves = tuple(SurfaceWave(float(rng.uniform(0.0, 0.01)), float(rng.uniform(0.1, 1.0)),
                              float(rng.uniform(-3.0, 3.0)))
                  for _ in range(int(rng.integers(0, 3))))
    return SoilParams(layers=layers, surface_slope=float(rng.uniform(-0.1, 0.1)),
                      surface_waves=waves, stiffness_rel_std=float(rng.uniform(0.0, 0.5)),
                      strength_rel_std=float(rng.uniform(0.0, 0.5)))


def _objects(rng: np.random.Generator, near_m: float, far_m: float) -> BuriedObjects:
    def reach() -> float:
        return float(rng.uniform(near_m - 0.03, far_m + 0.03))

    def count() -> int:
        return int(rng.integers(0, 3))

    stones = tuple(StoneParams(reach(), float(rng.uniform(0.0, 0.12)),
                               float(rng.uniform(0.03, 0.15)), float(rng.uniform(0.03, 0.1)))
                   for _ in range(count()))
    roots = tuple(RootParams(reach(), float(rng.uniform(0.01, 0.1))) for _ in range(count()))
    mines = tuple(MineParams(reach(), float(rng.uniform(0.01, 0.1)),
                             float(rng.uniform(0.06, 0.12)), float(rng.uniform(0.03, 0.08)),
                             activation_force_n=float(rng.uniform(80.0, 100.0)))
                  for _ in range(count()))
    return BuriedObjects(stones, roots, mines)


def _command(rng: np.random.Generator, kind: CommandKind) -> Command:
    far_m = float(rng.uniform(0.95, 1.35))
    near_m = far_m - float(rng.uniform(0.15, 0.45))
    if kind is CommandKind.PLUNGE:
        return Command(kind, far_m, far_m, PLUNGE_END_DEPTH_M, PLUNGE_END_DEPTH_M,
                       float(rng.uniform(0.05, 0.25)), 0.0, float(rng.uniform(0.02, 0.1)),
                       bool(rng.integers(0, 2)))
    depth_m = float(rng.uniform(0.02, 0.12))
    step_m = depth_m if kind is CommandKind.STROKE else float(rng.uniform(0.005, 0.03))
    low_speed = 0.01 if kind is CommandKind.LANE else 0.1
    return Command(kind, far_m, near_m, step_m, depth_m, _loguniform(rng, low_speed, 1.0),
                   _loguniform(rng, 0.002, 0.1), float(rng.uniform(0.02, 0.06)), True)


def _faults(rng: np.random.Generator, forced: int, duration_s: float) -> Faults:
    """``forced``: 0 none, 1 feedback, 2 command, 3 drive fault; others at 20 %. The drive
    fault starts in the first 70 % of the case (a lane that ends early may miss it)."""
    on = [forced == k or rng.uniform() < 0.2 for k in (1, 2, 3)]
    return Faults(seed=int(rng.integers(0, 2**32)),
                  feedback_loss_probability=float(rng.uniform(0.01, 0.3)) if on[0] else 0.0,
                  command_loss_probability=float(rng.uniform(0.01, 0.3)) if on[1] else 0.0,
                  drive_fault_start_s=float(rng.uniform(0.05, 0.7)) * duration_s,
                  drive_fault_s=float(rng.uniform(0.02, 0.2)) if on[2] else 0.0)


def generate(seed: int, index: int) -> FuzzCase:
    """The ``index``-th case of campaign ``seed`` (pure, deterministic). Kinds and fault
    kinds cycle with the index, so any 12 consecutive cases cover them all."""
    rng = np.random.default_rng([seed, index])
    kind = list(CommandKind)[index % 3]
    command = _command(rng, kind)
    if kind is CommandKind.PLUNGE:
        objects = _objects(rng, command.reach_far_m - 0.08, command.reach_far_m + 0.08)
        if objects.mines and rng.uniform() < 0.5:  # right above a mine
            command = dataclasses.replace(command, reach_far_m=objects.mines[0].reach_m,
                                          reach_near_m=objects.mines[0].reach_m)
    else:
        objects = _objects(rng, command.reach_near_m, command.reach_far_m)
    ground = GroundParams(_soil(rng), objects)
    travel_m = command.start_height_m + PLUNGE_END_DEPTH_M + 0.1
    duration_s = (travel_m / command.speed_m_per_s + 1.0 if kind is CommandKind.PLUNGE
                  else LANE_DURATION_S)
    faults = _faults(rng, (index // 3) % 4, duration_s)
    ground_seed = int(rng.integers(0, 2**32))
    if kind is CommandKind.LANE:  # half the lanes adaptive, drawn apart: the rest unchanged
        adaptive = bool(np.random.default_rng([seed, index, 1]).integers(0, 2))
        command = dataclasses.replace(command, adaptive=adaptive)
    return FuzzCase(seed, index, ground, ground_seed, command, faults, duration_s)


# --------------------------------------------------------------------------- serialization


def _from_plain(tp: Any, value: Any) -> Any:
    """Rebuild a value of type ``tp`` from its ``dataclasses.asdict`` / JSON form."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        hints = typing.get_type_hints(tp)  # a field missing (older JSON) takes its default
        return tp(**{f.name: _from_plain(hints[f.name], value[f.name])
                     for f in dataclasses.fields(tp) if f.init and f.name in value})
    if typing.get_origin(tp) is tuple:
        item = typing.get_args(tp)[0]
        return tuple(_from_plain(item, v) for v in value)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tp(value)
    return tp(value) if tp in (float, int, bool, str) else value


def case_from_dict(data: dict[str, Any]) -> FuzzCase:
    case: FuzzCase = _from_plain(FuzzCase, data)
    return case


def result_from_dict(data: dict[str, Any]) -> CaseResult:
    result: CaseResult = _from_plain(CaseResult, data)
    return result


# --------------------------------------------------------------------------- running


def scenario_of(case: FuzzCase) -> Scenario:
    c = case.command
    base = Scenario()
    lane = LaneSettings(reach_far_m=c.reach_far_m, reach_near_m=min(c.reach_near_m,
                                                                      c.reach_far_m - 0.01),
                        depth_step_m=c.depth_step_m, target_depth_m=c.target_depth_m,
                        clearance_m=c.start_height_m,
                        stroke_speed_m_per_s=min(c.speed_m_per_s, 1.0),
                        plunge_speed_m_per_s=max(c.plunge_speed_m_per_s, 1e-3))
    if c.adaptive:  # the case's speed is the top one, if above the default's
        defaults = LaneSettings()
        lane = dataclasses.replace(
            lane, adaptive=True,
            max_stroke_speed_m_per_s=max(defaults.max_stroke_speed_m_per_s,
                                         lane.stroke_speed_m_per_s),
            max_plunge_speed_m_per_s=max(defaults.max_plunge_speed_m_per_s,
                                         lane.plunge_speed_m_per_s),
            max_depth_step_m=max(defaults.max_depth_step_m, lane.depth_step_m))
    emulator = dataclasses.replace(base.emulator, ground=case.ground, seed=case.ground_seed)
    return dataclasses.replace(base, plant=PlantSettings(kind=PlantKind.RAKE), lane=lane,
                               trajectory=dataclasses.replace(base.trajectory,
                                                              kind=TrajectoryKind.LANE),
                               duration_s=case.duration_s, emulator=emulator)


class PlungeReference:
    """Straight down at a fixed reach and constant speed, then hold (a hostile command)."""

    def __init__(self, reach_m: float, start_depth_m: float, end_depth_m: float,
                 speed_m_per_s: float, dt_s: float, contact: bool) -> None:
        self.reach_m, self.depth_m = reach_m, start_depth_m
        self._end_m, self._step_m, self._contact = end_depth_m, speed_m_per_s * dt_s, contact

    @property
    def contact(self) -> bool:
        return self._contact

    @property
    def done(self) -> bool:
        return self.depth_m >= self._end_m

    def observe(self, reach_m: float, depth_m: float) -> None:
        pass

    def step(self) -> None:
        self.depth_m = min(self._end_m, self.depth_m + self._step_m)


class FaultyRakeLoop(RakeLoop):
    """RakeLoop with lost feedback, lost commands and a drive fault episode, once armed."""

    def __init__(self, settings: Scenario, start_reach_m: float, start_depth_m: float,
                 faults: Faults, clamp: VoltageClamp | None = None) -> None:
        super().__init__(settings, start_reach_m, start_depth_m, clamp)
        self.faults = faults
        self._rng = np.random.default_rng(faults.seed)
        self._armed = False
        self._tick_index = 0
        self._last = self.arm.measure()
        self.feedback_lost = self.commands_lost = self.drive_fault_ticks = 0

    def arm_faults(self) -> None:
        self._armed = True

    def _tick(self, reach_ref_m: float, depth_ref_m: float) -> None:
        f = self.faults
        m = self.arm.measure()
        if self._armed and self._rng.uniform() < f.feedback_loss_probability:
            m, self.feedback_lost = self._last, self.feedback_lost + 1
        self._last = m
        voltages = self.controller.step(reach_ref_m, depth_ref_m, m.r_m, m.theta_rad,
                                        m.r_vel_m_per_s, m.theta_vel_rad_per_s)
        self.contact.peak_down_n = 0.0
        applied = self._pending_v
        t_s = self._tick_index * self.dt_s
        if self._armed and f.drive_fault_start_s <= t_s < f.drive_fault_start_s + f.drive_fault_s:
            applied, self.drive_fault_ticks = (0.0, 0.0), self.drive_fault_ticks + 1
        self.arm.step(applied[0], applied[1], self.contact, self.dt_s)
        if self._armed and self._rng.uniform() < f.command_loss_probability:
            self.commands_lost += 1  # the drive keeps applying the previous voltages
        else:
            self._pending_v = voltages
        if self._armed:
            self._tick_index += 1


def _reference(case: FuzzCase, settings: Scenario) -> tuple[Reference, float, float]:
    """The reference and the start pose (reach, depth) above the local surface."""
    c, dt_s = case.command, 1.0 / settings.rate_hz
    surface_m = original_surface_height_m(case.ground.soil, c.reach_far_m)
    start_depth_m = -(surface_m + c.start_height_m)
    if c.kind is CommandKind.PLUNGE:
        ref: Reference = PlungeReference(c.reach_far_m, start_depth_m, c.target_depth_m,
                                         c.speed_m_per_s, dt_s, c.contact)
        return ref, c.reach_far_m, start_depth_m
    lane = settings.lane
    planner = LanePlanner(lane, dt_s, lane.reach_far_m, start_depth_m)
    return planner, lane.reach_far_m, start_depth_m


def run_case(case: FuzzCase, clamp: VoltageClamp | None = None) -> CaseResult:
    """Run one case through the full chain; ``clamp`` replaces the real one (tests)."""
    settings = scenario_of(case)
    reference, reach_m, depth_m = _reference(case, settings)
    loop = FaultyRakeLoop(settings, reach_m, depth_m, case.faults, clamp)
    loop.reset()
    loop.arm_faults()
    dt_s = loop.dt_s
    peak_n, peak_t_s, over, hold = 0.0, 0.0, 0, round(HOLD_AFTER_DONE_S / dt_s)
    ticks = round(case.duration_s / dt_s)
    for k in range(ticks):
        loop.step(reference.reach_m, reference.depth_m, reference.contact)
        f_n = loop.contact.peak_down_n
        over += f_n > FORCE_LIMIT_N
        if f_n > peak_n:
            peak_n, peak_t_s = f_n, k * dt_s
        if loop.fault:
            ticks = k + 1
            break
        reference.observe(*loop.measured_tip())
        if isinstance(reference, LanePlanner):  # an adaptive lane's governor (else: nothing)
            reference.govern(loop.force_estimate_n, loop.caution_n)
        reference.step()
        hold -= reference.done
        if hold < 0:
            ticks = k + 1
            break
    return _result(case, loop, reference, (peak_n, peak_t_s, over, ticks * dt_s))


def _result(case: FuzzCase, loop: FaultyRakeLoop, reference: Reference,
            figures: tuple[float, float, int, float]) -> CaseResult:
    found = isinstance(reference, LanePlanner) and reference.found_at is not None
    kind = str(case.command.kind) + (" (adaptive)" if case.command.adaptive else "")
    return CaseResult(case.seed, case.index, kind, figures[0], figures[1],
                      figures[2], loop.ground.truth.mine_activated, found, figures[3],
                      case.faults.kinds(), loop.feedback_lost, loop.commands_lost,
                      loop.drive_fault_ticks, loop.controller.clamp.clamped, loop.fault)


# --------------------------------------------------------------------------- campaign


@dataclass(frozen=True)
class Report:
    scenarios: int
    f_true_z_max_n: float
    ticks_over_limit: int
    cases_over_limit: int
    mine_activations: int
    controller_faults: int
    worst: CaseResult
    worst_case: FuzzCase
    results: tuple[CaseResult, ...]
    wall_time_s: float
    worst_case_path: str = ""

    @property
    def safe(self) -> bool:
        return self.ticks_over_limit == 0 and self.mine_activations == 0

    def by_kind(self) -> dict[str, dict[str, float | int]]:
        out: dict[str, dict[str, float | int]] = {}
        for r in self.results:
            k = out.setdefault(r.kind, {"cases": 0, "f_true_z_max_n": 0.0,
                                        "cases_over_limit": 0, "mine_activations": 0})
            k["cases"] += 1
            k["f_true_z_max_n"] = max(k["f_true_z_max_n"], r.f_true_z_max_n)
            k["cases_over_limit"] += r.ticks_over_limit > 0
            k["mine_activations"] += r.mine_activated
        return out

    def over_limit(self) -> list[str]:
        """Every case over the limit or that fired a mine: 'seed/index kind F N [mine]'."""
        return [f"{self.worst_case.seed}/{r.index} {r.kind} {r.f_true_z_max_n:.1f} N"
                + (" mine fired" if r.mine_activated else "")
                for r in self.results if r.ticks_over_limit or r.mine_activated]

    def summary(self) -> dict[str, Any]:
        return {"scenarios": self.scenarios, "f_true_z_max_n": self.f_true_z_max_n,
                "ticks_over_limit": self.ticks_over_limit,
                "cases_over_limit": self.cases_over_limit, "over_limit": self.over_limit(),
                "mine_activations": self.mine_activations,
                "controller_faults": self.controller_faults, "by_kind": self.by_kind(),
                "worst": self.worst.to_dict(), "worst_case": self.worst_case.describe(),
                "worst_case_path": self.worst_case_path, "wall_time_s": self.wall_time_s,
                "scenarios_per_min": 60.0 * self.scenarios / max(self.wall_time_s, 1e-9)}


def _run_index(job: tuple[int, int]) -> CaseResult:
    return run_case(generate(*job))


def campaign(scenarios: int, seed: int, workers: int = 1, out_dir: Path | None = None,
             progress: Callable[[int, int], None] | None = None) -> Report:
    """Run cases 0 … scenarios−1 of ``seed``; write the worst one to ``out_dir``."""
    if scenarios < 1:
        raise ValueError("scenarios must be >= 1")
    started = time.perf_counter()
    results: list[CaseResult] = []
    jobs = [(seed, i) for i in range(scenarios)]
    for result in fork_map(_run_index, jobs, workers, ordered=False):
        results.append(result)
        if progress is not None:
            progress(len(results), scenarios)
    results.sort(key=lambda r: r.index)
    worst = max(results, key=lambda r: r.f_true_z_max_n)
    report = Report(scenarios, worst.f_true_z_max_n, sum(r.ticks_over_limit for r in results),
                    sum(r.ticks_over_limit > 0 for r in results),
                    sum(r.mine_activated for r in results),
                    sum(bool(r.controller_fault) for r in results), worst,
                    generate(seed, worst.index), tuple(results), time.perf_counter() - started)
    if out_dir is None:
        return report
    path = write_case(out_dir / WORST_CASE_FILE, report.worst_case, worst)
    return dataclasses.replace(report, worst_case_path=str(path))


def write_case(path: Path, case: FuzzCase, result: CaseResult) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"case": case.to_dict(), "result": result.to_dict()},
                               indent=2) + "\n")
    return path


def replay(path: Path) -> tuple[CaseResult, CaseResult]:
    """Re-run a case written by :func:`campaign`: (result now, result recorded)."""
    data = json.loads(Path(path).read_text())
    return run_case(case_from_dict(data["case"])), result_from_dict(data["result"])


# --------------------------------------------------------------------------- CLI


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rakectl fuzz",
        description="Closed-loop safety campaign: random grounds, commands (lane, hostile "
        "plunge, fast stroke) and faults through the simulated robot. Exit status 0 only if "
        "no tick's true vertical tip force exceeded 90 N and no mine fired; 1 otherwise "
        "(also when a replayed case does not reproduce); 2 on usage errors.")
    p.add_argument("--scenarios", type=int, default=100, help="number of cases (default 100)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument("--json", action="store_true", help="one JSON object on the last line")
    p.add_argument("--out", type=Path, default=None, help=f"directory for {WORST_CASE_FILE}")
    p.add_argument("--replay", type=Path, default=None, help="re-run a worst-case file")
    return p


def _human(report: Report) -> str:
    s = report.summary()
    lines = [f"{s['scenarios']} scenarios in {s['wall_time_s']:.0f} s "
             f"({s['scenarios_per_min']:.0f}/min)",
             f"largest true vertical force: {s['f_true_z_max_n']:.1f} N "
             f"(limit {FORCE_LIMIT_N:g} N)",
             f"ticks over the limit: {s['ticks_over_limit']} in {s['cases_over_limit']} cases",
             f"mine activations: {s['mine_activations']}",
             f"controller faults: {s['controller_faults']}"]
    lines += [f"  {kind}: {k}" for kind, k in s["by_kind"].items()]
    lines += [f"over the limit: {case}" for case in s["over_limit"]]
    lines.append(f"worst: {s['worst_case']} → {s['f_true_z_max_n']:.1f} N at "
                 f"t = {report.worst.f_true_z_max_t_s:.3f} s")
    if report.worst_case_path:
        lines.append(f"worst case written to {report.worst_case_path}")
    return "\n".join(lines)


def _replay_main(path: Path, as_json: bool) -> int:
    now, recorded = replay(path)
    same = now == recorded
    out = {"replayed": str(path), "same": same, **now.to_dict()}
    print(json.dumps(out) if as_json else
          f"replay {path}: {now.f_true_z_max_n:.1f} N, {now.ticks_over_limit} ticks over, "
          f"mine activated {now.mine_activated}; {'same' if same else 'DIFFERENT'} result")
    return 0 if same and now.ticks_over_limit == 0 and not now.mine_activated else 1


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.replay is not None:
        return _replay_main(args.replay, args.json)
    if args.scenarios < 1 or args.workers < 1:
        print("rakectl fuzz: --scenarios and --workers must be >= 1", file=sys.stderr)
        return 2
    report = campaign(args.scenarios, args.seed, args.workers, args.out, Progress("fuzz"))
    print(_human(report))
    if args.json:
        print(json.dumps(report.summary()))
    return 0 if report.safe else 1
