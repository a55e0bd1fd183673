"""The safety campaign's cases: what each one commands, on what ground, under which faults.

A :class:`FuzzCase` is frozen and holds everything its run depends on, so its
JSON (``to_dict``, read back by ``case_from_dict``) rebuilds the exact run;
regression cases are such files (:mod:`rakectl.sim.case_files`, tests/data/fuzz/).
:func:`generate` draws the ``index``-th case of a campaign ``seed``, deterministically. What an
operator can command is covered at its bounds:

* ``lane``: rake a lane with the :class:`~rakectl.core.lane.LanePlanner`
  (random reach range, depth step, target depth, stroke and plunge speed; a
  quarter of them with the most aggressive parameters the command API accepts:
  1 m/s strokes and plunges, 0.1 m steps, 2 m/s travel). Half of them are
  force-adaptive (``lane.adaptive``).
* ``plunge`` (hostile): a straight reference down from above the ground to
  0.15 m deep at up to 0.25 m/s, half the time right above a mine, with the
  impedance on or off.
* ``stroke`` (hostile): one lane cycle at a fixed depth with a fast stroke.
* ``jog``: the operator's jog at the highest speed the jog admits, in task or
  joint space, in any direction (mostly into the ground), from above or within
  the soil (at least 10 mm from any object: a rake cannot start inside one; the
  other kinds start at least 10 mm above whatever sticks out of a sloped ground),
  for 0.3–3 s, then silence (the dead-man stops it).

Grounds: one to three soil layers two decades of stiffness apart; a fifth
of them a hard crust over soft soil, a sixth of them out of the reference
range (ten times softer or stiffer, weaker or stronger); heterogeneity, slope,
waves; stones, roots and mines (80–100 N fuses) anywhere along the lane, their
depths drawn below the surface where each lies (:mod:`rakectl.sim.scene`: nothing
floats), some stones and mines partly exposed (up to 20 mm out of the soil); and in
half of the lanes and strokes a mine whose plate is at one of the cut depths or
up to 5 mm above it (sunk, if need be, until its bottom is 10 mm in the soil).

Two more families aim where random placement rarely does
(``generate(seed, index, family)``): ``edge`` (:mod:`rakectl.sim.edge`),
plunges along an object's side, and ``mapped`` (:mod:`rakectl.sim.mapped`),
lanes with the descent limiter on, down beside a buried object.

Faults: lost feedback and lost commands (per tick), a drive fault episode
(both motors at 0 V for 20–200 ms), a controller stall (no tick for 5–60 ms:
the drives hold the last command until their watchdog, then 0 V and fault),
and a SIGKILL (no tick from then on: the same watchdog). Half the cases run the
daemon's force supervision (caution holds the reference, the hard level backs
off), half do not: the clamp alone must hold.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.ground_params import BuriedObjects, GroundParams, MineParams, RootParams, StoneParams
from drivers.soil import original_surface_height_m
from drivers.soil_params import SoilLayer, SoilParams, SurfaceWave
from rakectl.sim.scene import apart, laid_in, standing

PLUNGE_END_DEPTH_M = 0.15
LANE_DURATION_S = 12.0  # cap of one lane or stroke case (simulated)
JOG_HOLD_S = 1.0  # simulated after the jog's last command
START_CLEARANCE_M = 0.01  # a jog that starts in the soil starts this far from any object
FAULT_KINDS = ("feedback", "command", "drive", "stall", "kill")


class Family(enum.StrEnum):
    """How a campaign's cases are drawn."""

    RANDOM = "random"  # everything an operator can command, objects anywhere
    EDGE = "edge"  # descents along an object's side, into its rounded top edge
    MAPPED = "mapped"  # lanes with the descent limiter on, down beside a buried object


class CommandKind(enum.StrEnum):
    LANE = "lane"  # rake a lane (normal operation)
    PLUNGE = "plunge"  # hostile: straight down at up to 0.25 m/s
    STROKE = "stroke"  # hostile: one fast stroke at depth
    JOG = "jog"  # the operator's jog at its highest speed, any direction


@dataclass(frozen=True)
class MotionCommand:
    """What the tip is told to do. For ``plunge``: straight down at ``reach_far_m`` from
    ``start_height_m`` above the ground to ``target_depth_m`` at ``speed_m_per_s``. For
    ``jog``: from ``start_height_m`` above the ground at ``reach_far_m`` (< 0: that deep
    in it), velocity direction ``jog_angle_rad`` (0: straight down; task space: of the
    tip, (reach, height) = (−sin, −cos); joint space: of (r, θ) as (cos, sin)) at the
    highest jog speed, for ``jog_s``."""

    kind: CommandKind
    reach_far_m: float
    reach_near_m: float
    depth_step_m: float
    target_depth_m: float
    speed_m_per_s: float  # stroke speed (lane, stroke) or plunge speed (plunge)
    plunge_speed_m_per_s: float
    start_height_m: float
    contact: bool  # plunge only: impedance on (α > 0) or pure position control
    adaptive: bool = False  # lane only: force-adaptive (rakectl.core.governor)
    travel_speed_m_per_s: float = 0.0  # lane only; 0: the configuration's
    jog_space: str = "task"  # jog only: "task" or "joint"
    jog_angle_rad: float = 0.0
    jog_s: float = 0.0


@dataclass(frozen=True)
class Faults:
    """Injected faults; probabilities are per tick, the others one episode each."""

    seed: int = 0
    feedback_loss_probability: float = 0.0
    command_loss_probability: float = 0.0
    drive_fault_start_s: float = 0.0
    drive_fault_s: float = 0.0  # 0: none
    stall_start_s: float = 0.0
    stall_s: float = 0.0  # 0: none; the controller runs no tick this long
    kill_at_s: float = -1.0  # < 0: none; the controller runs no tick from then on

    def kinds(self) -> tuple[str, ...]:
        active = (self.feedback_loss_probability > 0, self.command_loss_probability > 0,
                  self.drive_fault_s > 0, self.stall_s > 0, self.kill_at_s >= 0)
        return tuple(n for n, a in zip(FAULT_KINDS, active, strict=True) if a)


@dataclass(frozen=True)
class FuzzCase:
    seed: int
    index: int
    ground: GroundParams
    ground_seed: int
    command: MotionCommand
    faults: Faults
    duration_s: float
    supervised: bool = False  # the daemon's force supervision acts (holds, back-off)
    family: Family = Family.RANDOM
    declared_site: bool = False  # its soil and surface declared: the descent limiter on

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def describe(self) -> str:
        c, o = self.command, self.ground.objects
        speed = f"{c.speed_m_per_s:.3f} m/s"
        if c.kind is CommandKind.JOG:
            where = (f"reach {c.reach_far_m:.3f} m, {c.jog_space} space at "
                     f"{math.degrees(c.jog_angle_rad):.0f}° for {c.jog_s:.2f} s")
        elif c.kind is CommandKind.PLUNGE:
            where = f"reach {c.reach_far_m:.3f} m"
        else:
            where = f"reach {c.reach_far_m:.3f}→{c.reach_near_m:.3f} m"
        layers = ", ".join(f"K_e {la.stiffness_n_per_m:.3g} N/m F_c {la.collapse_force_n:.3g} N"
                           for la in self.ground.soil.layers)
        kind = f"{c.kind} (adaptive)" if c.adaptive else str(c.kind)
        return (f"case {self.seed}/{self.index}: {kind} at {speed}, {where}, depth "
                f"{c.target_depth_m:.3f} m, contact={c.contact}; soil [{layers}]; "
                f"{len(o.stones)} stones, {len(o.roots)} roots, {len(o.mines)} mines; "
                f"faults {list(self.faults.kinds()) or 'none'}; "
                f"supervision {'on' if self.supervised else 'off'}"
                + ("; site declared, descent limiter on" if self.declared_site else ""))


# --------------------------------------------------------------------------- generation


def loguniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _layer(rng: np.random.Generator, top_m: float, stiffness: tuple[float, float],
           strength: tuple[float, float]) -> SoilLayer:
    return SoilLayer(from_depth_m=round(top_m, 4), stiffness_n_per_m=loguniform(rng, *stiffness),
                     collapse_force_n=loguniform(rng, *strength),
                     cohesion_pa=float(rng.uniform(2e3, 15e3)))


def draw_soil(rng: np.random.Generator) -> SoilParams:
    """Reference soils (2e4–2e6 N/m, 3–60 N); a fifth a hard crust over soft soil; a sixth
    out of that range."""
    draw = rng.uniform()
    if draw < 0.2:  # a crust 5–30 mm thick
        layers: tuple[SoilLayer, ...] = (
            _layer(rng, 0.0, (1e6, 1e7), (60.0, 250.0)),
            _layer(rng, float(rng.uniform(0.005, 0.03)), (5e3, 1e5), (1.0, 15.0)))
    else:
        stiffness, strength = ((2e3, 2e7), (0.5, 400.0)) if draw < 0.37 else \
            ((2e4, 2e6), (3.0, 60.0))
        n = int(rng.integers(1, 4))
        tops = sorted({0.0, *(round(float(d), 4) for d in rng.uniform(0.02, 0.12, n - 1))})
        layers = tuple(_layer(rng, top, stiffness, strength) for top in tops)
    waves = tuple(SurfaceWave(float(rng.uniform(0.0, 0.01)), float(rng.uniform(0.1, 1.0)),
                              float(rng.uniform(-3.0, 3.0)))
                  for _ in range(int(rng.integers(0, 3))))
    return SoilParams(layers=layers, surface_slope=float(rng.uniform(-0.1, 0.1)),
                      surface_waves=waves, stiffness_rel_std=float(rng.uniform(0.0, 0.5)),
                      strength_rel_std=float(rng.uniform(0.0, 0.5)))


def draw_mine(rng: np.random.Generator, reach_m: float, depth_m: float) -> MineParams:
    """A mine at ``reach_m``, its top ``depth_m`` below level 0, its fuse 80–100 N."""
    return MineParams(reach_m, depth_m, float(rng.uniform(0.06, 0.12)),
                      float(rng.uniform(0.03, 0.08)),
                      activation_force_n=float(rng.uniform(80.0, 100.0)))


def _objects(rng: np.random.Generator, near_m: float, far_m: float,
             cut_depths_m: tuple[float, ...] = ()) -> tuple[BuriedObjects, MineParams | None]:
    """Stones, roots and mines between ``near_m`` and ``far_m``, their depths below the
    surface where they will lie (:func:`rakectl.sim.scene.laid_in`); with ``cut_depths_m``,
    half the time one more mine with its plate at one of them (from level 0, as the lane
    counts them) or up to 5 mm above, apart."""
    def reach() -> float:
        return float(rng.uniform(near_m - 0.03, far_m + 0.03))

    def count() -> int:
        return int(rng.integers(0, 3))

    def mine_depth() -> float:  # a sixth of them partly exposed
        return float(rng.uniform(-0.02, 0.0)) if rng.uniform() < 1 / 6 else \
            float(rng.uniform(0.01, 0.1))

    # a stone's top up to 20 mm out of the soil (a seventh of them), as a mine's
    stones = tuple(StoneParams(reach(), float(rng.uniform(-0.02, 0.12)),
                               float(rng.uniform(0.03, 0.15)), float(rng.uniform(0.03, 0.1)))
                   for _ in range(count()))
    roots = tuple(RootParams(reach(), float(rng.uniform(0.01, 0.1))) for _ in range(count()))
    mines = tuple(draw_mine(rng, reach(), mine_depth()) for _ in range(count()))
    at_cut = None
    if cut_depths_m and rng.uniform() < 0.5:
        depth_m = float(rng.choice(cut_depths_m)) - float(rng.uniform(0.0, 0.005))
        at_cut = draw_mine(rng, float(rng.uniform(near_m, far_m)), depth_m)
    return BuriedObjects(stones, roots, mines), at_cut


def _clear_of(objects: BuriedObjects, reach_m: float, depth_m: float,
              margin_m: float = START_CLEARANCE_M) -> BuriedObjects:
    """``objects`` less those within ``margin_m`` of a tip at (reach, depth): a rake
    cannot start inside a stone or a mine."""
    def clear(o: StoneParams | RootParams | MineParams) -> bool:
        beside = abs(reach_m - o.reach_m) > 0.5 * o.width_m + margin_m
        above_or_below = not (o.depth_m - margin_m < depth_m
                              < o.depth_m + o.thickness_m + margin_m)
        return beside or above_or_below

    return BuriedObjects(tuple(o for o in objects.stones if clear(o)),
                         tuple(o for o in objects.roots if clear(o)),
                         tuple(o for o in objects.mines if clear(o)))


def height_clear_of(objects: BuriedObjects, reach_m: float, surface_m: float,
                     margin_m: float = START_CLEARANCE_M) -> float:
    """The least height above the surface at ``surface_m`` from which a tip at ``reach_m``
    is ``margin_m`` above every object under it (objects' depths are from level 0)."""
    bodies: tuple[StoneParams | RootParams | MineParams, ...] = (
        *objects.stones, *objects.roots, *objects.mines)
    tops = [-o.depth_m for o in bodies if abs(reach_m - o.reach_m) <= 0.5 * o.width_m + margin_m]
    return max((top + margin_m - surface_m for top in tops), default=-math.inf)


def _cut_depths(command: MotionCommand) -> tuple[float, ...]:
    """The depths a lane's (or stroke's) strokes cut at, first to last."""
    step, target = command.depth_step_m, command.target_depth_m
    n = max(1, math.ceil(target / step - 1e-9))
    return tuple(min(target, step * (k + 1)) for k in range(n))


def _command(rng: np.random.Generator, kind: CommandKind) -> MotionCommand:
    far_m = float(rng.uniform(0.95, 1.35))
    near_m = far_m - float(rng.uniform(0.15, 0.45))
    if kind is CommandKind.PLUNGE:
        return MotionCommand(kind, far_m, far_m, PLUNGE_END_DEPTH_M, PLUNGE_END_DEPTH_M,
                             float(rng.uniform(0.05, 0.25)), 0.0,
                             float(rng.uniform(0.02, 0.1)), bool(rng.integers(0, 2)))
    if kind is CommandKind.JOG:
        space = "joint" if rng.uniform() < 0.5 else "task"
        # mostly into the ground: within ±100° of straight down three times in four
        angle = float(rng.uniform(-1.75, 1.75) if rng.uniform() < 0.75
                      else rng.uniform(-math.pi, math.pi))
        start_m = float(rng.uniform(-0.06, 0.05))  # < 0: starts that deep in the soil
        return MotionCommand(kind, far_m, far_m, 0.0, 0.0, 0.0, 0.0, start_m, True,
                             jog_space=space, jog_angle_rad=angle,
                             jog_s=float(rng.uniform(0.3, 3.0)))
    depth_m = float(rng.uniform(0.02, 0.12))
    step_m = depth_m if kind is CommandKind.STROKE else float(rng.uniform(0.005, 0.03))
    low_speed = 0.01 if kind is CommandKind.LANE else 0.1
    command = MotionCommand(kind, far_m, near_m, step_m, depth_m,
                            loguniform(rng, low_speed, 1.0), loguniform(rng, 0.002, 0.1),
                            float(rng.uniform(0.02, 0.06)), True)
    if kind is CommandKind.LANE and rng.uniform() < 0.25:  # the API's bounds
        command = dataclasses.replace(command, speed_m_per_s=1.0, plunge_speed_m_per_s=1.0,
                                      depth_step_m=min(0.1, depth_m),
                                      travel_speed_m_per_s=2.0)
    return command


def draw_faults(rng: np.random.Generator, forced: int, duration_s: float) -> Faults:
    """``forced``: 0 none, else 1 + the index of a kind in FAULT_KINDS; the per-tick losses
    and the drive fault also at 20 % each. Episodes start in the first 70 % of the case
    (a lane that ends early may miss them)."""
    kinds = FAULT_KINDS
    on = [forced == k + 1 or (k < 3 and rng.uniform() < 0.2) for k in range(len(kinds))]
    start = float(rng.uniform(0.05, 0.7)) * duration_s
    return Faults(seed=int(rng.integers(0, 2**32)),
                  feedback_loss_probability=float(rng.uniform(0.01, 0.3)) if on[0] else 0.0,
                  command_loss_probability=float(rng.uniform(0.01, 0.3)) if on[1] else 0.0,
                  drive_fault_start_s=start,
                  drive_fault_s=float(rng.uniform(0.02, 0.2)) if on[2] else 0.0,
                  stall_start_s=start,
                  stall_s=float(rng.uniform(0.005, 0.06)) if on[3] else 0.0,
                  kill_at_s=start if on[4] else -1.0)


def generate(seed: int, index: int, family: Family = Family.RANDOM) -> FuzzCase:
    """The ``index``-th case of campaign ``seed`` (pure, deterministic). Kinds cycle with
    the index, fault kinds with index // 4, supervision with index // 24: any 48
    consecutive cases cover every kind under every fault, with and without supervision."""
    if family is Family.EDGE:  # each family's module draws with this module's parts
        from rakectl.sim.edge import edge_case

        return edge_case(seed, index)
    if family is Family.MAPPED:
        from rakectl.sim.mapped import mapped_case

        return mapped_case(seed, index)
    rng = np.random.default_rng([seed, index])
    kind = list(CommandKind)[index % 4]
    command = _command(rng, kind)
    if kind is CommandKind.PLUNGE:
        objects, at_cut = _objects(rng, command.reach_far_m - 0.08, command.reach_far_m + 0.08)
        if objects.mines and rng.uniform() < 0.5:  # right above a mine
            command = dataclasses.replace(command, reach_far_m=objects.mines[0].reach_m,
                                          reach_near_m=objects.mines[0].reach_m)
    elif kind is CommandKind.JOG:
        objects, at_cut = _objects(rng, command.reach_far_m - 0.15, command.reach_far_m + 0.15)
    else:
        objects, at_cut = _objects(rng, command.reach_near_m, command.reach_far_m,
                                   _cut_depths(command))
    soil = draw_soil(rng)
    objects = laid_in(objects, soil)  # a scene that can stand: nothing floats
    if at_cut is not None:
        at_cut = standing(at_cut, soil)
        objects = dataclasses.replace(objects, mines=(*objects.mines, at_cut))
    surface_m = original_surface_height_m(soil, command.reach_far_m)
    in_soil = kind is CommandKind.JOG and command.start_height_m < 0.0  # it starts there
    if in_soil:
        objects = _clear_of(objects, command.reach_far_m, -(surface_m + command.start_height_m))
    objects = apart(objects, first=at_cut)  # nor two bodies in one place
    if not in_soil:  # above the ground, and above whatever sticks out of it (a slope)
        command = dataclasses.replace(command, start_height_m=max(
            command.start_height_m, height_clear_of(objects, command.reach_far_m, surface_m)))
    ground = GroundParams(soil, objects)
    if kind is CommandKind.PLUNGE:
        travel_m = command.start_height_m + PLUNGE_END_DEPTH_M + 0.1
        duration_s = travel_m / command.speed_m_per_s + 1.0
    elif kind is CommandKind.JOG:
        duration_s = command.jog_s + JOG_HOLD_S
    else:
        duration_s = LANE_DURATION_S
    faults = draw_faults(rng, (index // 4) % (len(FAULT_KINDS) + 1), duration_s)
    ground_seed = int(rng.integers(0, 2**32))
    if kind is CommandKind.LANE:  # half the lanes adaptive, drawn apart: the rest unchanged
        adaptive = bool(np.random.default_rng([seed, index, 1]).integers(0, 2))
        command = dataclasses.replace(command, adaptive=adaptive)
    supervised = (index // 24) % 2 == 1
    return FuzzCase(seed, index, ground, ground_seed, command, faults, duration_s, supervised)


# --------------------------------------------------------------------------- serialization


def from_plain(tp: Any, value: Any) -> Any:
    """Rebuild a value of type ``tp`` from its ``dataclasses.asdict`` / JSON form."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        hints = typing.get_type_hints(tp)  # a field missing (older JSON) takes its default
        return tp(**{f.name: from_plain(hints[f.name], value[f.name])
                     for f in dataclasses.fields(tp) if f.init and f.name in value})
    if typing.get_origin(tp) is tuple:
        item = typing.get_args(tp)[0]
        return tuple(from_plain(item, v) for v in value)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tp(value)
    return tp(value) if tp in (float, int, bool, str) else value


def case_from_dict(data: dict[str, Any]) -> FuzzCase:
    """The case a :meth:`FuzzCase.to_dict` (or its JSON) describes; a field an older file
    lacks takes its default."""
    case: FuzzCase = from_plain(FuzzCase, data)
    return case
