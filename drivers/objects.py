"""Buried objects and the :class:`Ground` that combines them with the soil (pure model).

Each object is a rectangle in the (reach, height) plane: ``width_m`` along
the reach centred on ``reach_m``, from its top at ``−depth_m`` (below ground
level 0) down ``thickness_m``; it is assumed to span the rake's width. Its
top edges are rounded: a root's by half its size, a stone's and a mine's by
``edge_radius_m`` (5 and 3 mm: a round tine tip, 4.7 mm in radius, meets a
square corner as a point meets a corner rounded by that radius). It is felt
only while the tip is inside it. The face pressed is the one the tip is
least deep behind (top, robot side, far side, bottom; the top on a tie,
then a side), or, by a rounded edge, the edge: a penalty contact along the
normal, F = K·penetration + K·τ·(approach speed along the normal), clipped
at 0 (no pulling). Square, a tine dragged into just under a top was pushed
sideways until the top was the nearer face, then read the whole overlap
upward at once (110–190 N on the ground for a tick or two in the safety
campaign; a mine's rim, 106 N, fired it). Without a bottom, a tine that
slid down a mine's side and under it read it, rising back, through the
nearest side: 4.8 mm deep at once, 180 N (20261125/2993). The law the tine
mount solves folds in the reach speed only toward an edge (see
``vertical_law``); a bottom pushes the tines down and the mount extends
(``Ground.bottom_laws``). What an object hides of the soil below it is
:class:`drivers.ground.Ground`'s to judge (:meth:`Body.hides_soil_from`).

* STONE: rigid (K = 1e7 N/m), never yields or collapses.
* ROOT: round (its top edges' radius is half its size): a tine that meets it
  under its top rides up it.
  Elastic–perfectly plastic: K from a 2 cm wooden root bent over
  0.3 m (48EI/L³ with E = 10 GPa ≈ 1.4e5 N/m), force capped at the yield force
  (M_y = σ_y I/(d/2) with σ_y = 40 MPa, F = 4M_y/L ≈ 400 N); beyond it the root
  is pushed along (permanent set) and, once moved by ``break_displacement_m``,
  it has broken or been torn aside and is felt no more. While it is pushed
  down, the soil under it is squeezed as under the tip (the soil's saw-tooth,
  ≤ its collapse force, adds to the yield force).
* MINE: rigid body (K = 5e6 N/m, a plastic casing) whose whole top is the
  pressure plate (conservative). It is activated — latched — the first step
  the vertical force on its top (its rounded rim included) exceeds
  ``activation_force_n``; a push on its
  side or bottom does not activate it (those forces are recorded as
  ``peak_side_n``).
  Force passed down through covering soil is not counted: it never exceeds the
  tip's total vertical force, which :class:`drivers.ground.GroundTruth` records as
  ``max_force_down_n``, so the 90 N criterion on that total is the
  conservative check.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

from drivers.ground_params import (
    BuriedObjects,
    MineParams,
    RootParams,
    StoneParams,
)
from drivers.soil import VerticalLaw


class NormalLaw(NamedTuple):
    """An object's contact along its outward normal (n_reach, n_up) where the tine is:
    F = K·penetration + B·(approach speed along n), ≥ 0, its elastic part at most
    ``cap_n`` (a root yields; infinite for the rigid ones)."""

    depth_m: float
    n_reach: float
    n_up: float
    stiffness_n_per_m: float
    damping_ns_per_m: float
    cap_n: float


class Contact(enum.Enum):
    """What the tip is touching (objects take precedence over soil)."""

    NONE = "none"
    SOIL = "soil"
    STONE = "stone"
    ROOT = "root"
    MINE = "mine"


class Body:
    """Runtime state of one buried object; ``touch`` writes the forces on the tip."""

    __slots__ = ("activated", "activation_force_n", "bottom_m", "break_m", "broken",
                 "damping_s", "force_reach_n", "force_up_n", "kind", "left_m", "moved_m",
                 "peak_down_n", "peak_side_n", "radius_m", "right_m", "stiffness_n_per_m",
                 "top_m", "touching", "yield_force_n")

    def __init__(self, kind: Contact, p: StoneParams | RootParams | MineParams) -> None:
        self.kind = kind
        self.left_m, self.right_m = p.reach_m - 0.5 * p.width_m, p.reach_m + 0.5 * p.width_m
        self.top_m, self.bottom_m = -p.depth_m, -p.depth_m - p.thickness_m
        self.stiffness_n_per_m, self.damping_s = p.stiffness_n_per_m, p.damping_time_s
        self.yield_force_n = p.yield_force_n if isinstance(p, RootParams) else math.inf
        self.break_m = p.break_displacement_m if isinstance(p, RootParams) else math.inf
        self.activation_force_n = (p.activation_force_n if isinstance(p, MineParams)
                                   else math.inf)
        self.moved_m = self.force_reach_n = self.force_up_n = 0.0
        self.peak_down_n = self.peak_side_n = 0.0
        self.broken = self.activated = False
        self.touching = False  # the tip was in it at the last reading (touch)
        half_m = 0.5 * min(p.width_m, p.thickness_m)
        self.radius_m = half_m if isinstance(p, RootParams) else min(p.edge_radius_m, half_m)

    def _contact(self, reach_m: float, height_m: float) -> tuple[float, float, float] | None:
        """(penetration, outward normal (n_reach, n_height)) of a tip at this point, or None
        outside: the nearest of the top, the sides and the bottom (the top on a tie, then
        a side), or, within ``radius_m`` of a top corner, the rounded edge there."""
        if self.broken or not (self.left_m < reach_m < self.right_m
                               and self.bottom_m < height_m < self.top_m):
            return None
        half_x, rho = 0.5 * (self.right_m - self.left_m), self.radius_m
        x = reach_m - self.left_m - half_x
        q_x = abs(x) - (half_x - rho)  # > 0: beside the flat part of the top
        q_z = height_m - (self.top_m - rho)  # > 0: above the sides' straight part
        if q_x > 0.0 and q_z > 0.0:  # by a top corner: its rounded edge
            d = math.hypot(q_x, q_z)
            if d >= rho:
                return None
            return rho - d, math.copysign(q_x / d, x), q_z / d
        above_bottom_m = height_m - self.bottom_m  # a tine under it that rose into it
        if above_bottom_m < rho - max(q_x, q_z):
            return above_bottom_m, 0.0, -1.0
        if q_z >= q_x:
            return (rho - q_z, 0.0, 1.0) if q_z < rho else None
        return (rho - q_x, math.copysign(1.0, x), 0.0) if q_x < rho else None

    def hides_soil_from(self, reach_m: float, height_m: float) -> bool:
        """Whether it hides the soil below its top from a tip here (within its extent):
        not from a tip in it through its bottom (a tine under it that rose into it presses
        the soil under it) nor through a side (a tine beside it, in the soil there, meets
        that soil at its own height, as the tine mount's solve takes it)."""
        contact = self._contact(reach_m, height_m)
        return contact is None or contact[2] > 0.0

    def shield_m(self, reach_m: float) -> float:
        """The height below which it hides the soil from a tip at ``reach_m`` (inside its
        extent): its top, lower by the rounded edges near its sides."""
        half_x = 0.5 * (self.right_m - self.left_m)
        q_x = abs(reach_m - self.left_m - half_x) - (half_x - self.radius_m)
        if q_x <= 0.0:
            return self.top_m
        return self.top_m - self.radius_m + math.sqrt(max(self.radius_m ** 2 - q_x * q_x, 0.0))

    def touch(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
              height_vel_m_per_s: float, dt_s: float) -> bool:
        """Forces on the tip at this position after a step of ``dt_s``; False (and zero
        forces) if not touching. The force acts along the normal: K·penetration (a root's
        capped at its yield force, the rest a permanent set along the normal) plus B times
        the approach speed along it, with K and B as :meth:`_damping_law` gives them (a
        tip that was not in it at the last reading meets it elastically)."""
        self.force_reach_n = self.force_up_n = 0.0
        contact = self._contact(reach_m, height_m)
        if contact is None:
            self.touching = False
            return False
        stiffness, damping = self._damping_law(dt_s)  # before touching says "in it"
        self.touching = True
        depth_m, n_reach, n_up = contact
        elastic_n = stiffness * depth_m
        if elastic_n > self.yield_force_n:
            self._yield((elastic_n - self.yield_force_n) / stiffness, -n_reach, -n_up)
            elastic_n = self.yield_force_n
        approach_m_per_s = -(reach_vel_m_per_s * n_reach + height_vel_m_per_s * n_up)
        normal_n = elastic_n + damping * approach_m_per_s
        normal_n = normal_n if normal_n > 0.0 else 0.0
        self.force_reach_n, self.force_up_n = normal_n * n_reach, normal_n * n_up
        if n_up > 0.0:
            self._record_top(self.force_up_n)
        elif n_up < 0.0:  # its bottom, lifted: a force on its body, not on its plate
            self._record_side(normal_n)
        if n_reach != 0.0:
            self._record_side(abs(self.force_reach_n))
        return True

    def _damping_law(self, step_s: float) -> tuple[float, float]:
        """(K, B) as a reading or a solve over a step of ``step_s`` takes them. Met anew
        (the tip was not in it at the last reading), its damping acts on the penetration
        gained since the touch, B·p/h, not on the speed the tip arrived at: K + B/h, no
        damping on the speed. Massless tines cannot carry the Kelvin–Voigt jump B·v at
        first touch: what stops them is what the mount pushes with (read at the speed of
        their fall, a mine's rounded edge met at 0.09 m/s read 84.6 N with the mount
        carrying 12.3 N, 20261129 edge 345)."""
        damping = self.stiffness_n_per_m * self.damping_s
        if self.touching:
            return self.stiffness_n_per_m, damping
        return self.stiffness_n_per_m + damping / step_s, 0.0

    def bottom_law(self, reach_m: float, height_m: float, step_s: float
                   ) -> tuple[float, float, float] | None:
        """(its bottom's height, K, B) if a tine here presses its bottom from under it (the
        tine mount solves it over ``step_s``: it extends), else None."""
        contact = self._contact(reach_m, height_m)
        if contact is None or contact[2] >= 0.0:
            return None
        return (self.bottom_m, *self._damping_law(step_s))

    def normal_law(self, reach_m: float, height_m: float, step_s: float) -> NormalLaw | None:
        """The law along the normal at this point, if it is inside and the normal leans
        sideways (a side or a rounded edge): what the tine mount's coupled solve over
        ``step_s`` needs."""
        contact = self._contact(reach_m, height_m)
        if contact is None or contact[1] == 0.0:
            return None
        depth_m, n_reach, n_up = contact
        return NormalLaw(depth_m, n_reach, n_up, *self._damping_law(step_s),
                         self.yield_force_n)

    def vertical_law(self, reach_m: float, height_m: float, face_height_m: float,
                     step_s: float, reach_vel_m_per_s: float = 0.0, edges: bool = True
                     ) -> VerticalLaw | None:
        """The law of the face the tines press from above, if any, as the tine mount solves
        it over ``step_s``, if the tip at ``height_m`` is inside: linearized where the tines were
        (``face_height_m``; on its surface if they were above it), along the normal
        there: K·n², B·n² and the yield force·n on the height, the approach the reach
        speed makes along the normal folded into the reference. None on a side (that
        push is horizontal) or outside."""
        if self.broken or not (self.left_m < reach_m < self.right_m
                               and self.bottom_m < height_m < self.top_m):
            return None
        # judged where the tines were; tines above it press where its surface is
        at_m = min(face_height_m, self.shield_m(reach_m) - 1e-9)
        contact = self._contact(reach_m, at_m)
        if contact is None or contact[2] <= 0.0:
            return None
        depth_m, n_reach, n_up = contact
        if n_reach != 0.0 and not edges:  # a mount that gives sideways solves it coupled
            return None
        stiffness, damping = self._damping_law(step_s)
        # Only a reach speed INTO an edge is folded into the reference (it raises it: the
        # tines ride up sooner). One away from it would lower the reference below the
        # surface, and the mount rests its tines on the reference: sliding off an edge,
        # they would sit inside it by B·n_reach·v/(K·n_up) (≈10 µm at 0.1 m/s), a force
        # the mount never carried (seed 7's plunges 277, 442, 514, 595, 688: 97-120 N).
        reach_approach_m_per_s = max(0.0, -n_reach * reach_vel_m_per_s)
        ref_m = (at_m + depth_m / n_up
                 + damping * reach_approach_m_per_s / (stiffness * n_up))
        if n_reach == 0.0:  # a flat top's surface is its top exactly: at_m + depth_m can
            # round a bit below it, where tines put on the reference would be inside by
            # 1e-18 m and read the damping at their arrival speed (20261125/5: 238 N on a
            # plate the mount carried nothing to)
            ref_m = max(ref_m, self.top_m)
        return VerticalLaw(ref_m, stiffness * n_up * n_up, damping * n_up * n_up,
                           self.yield_force_n * n_up, False)

    def _yield(self, set_m: float, dx: float, dz: float) -> None:
        self.left_m += dx * set_m
        self.right_m += dx * set_m
        self.top_m += dz * set_m
        self.bottom_m += dz * set_m
        self.moved_m += set_m
        if self.moved_m > self.break_m:
            self.broken = True

    def _record_top(self, force_n: float) -> None:
        if force_n > self.peak_down_n:
            self.peak_down_n = force_n
        if force_n > self.activation_force_n:
            self.activated = True

    def _record_side(self, force_n: float) -> None:
        if force_n > self.peak_side_n:
            self.peak_side_n = force_n


def make_bodies(objects: BuriedObjects) -> tuple[Body, ...]:
    return (tuple(Body(Contact.STONE, p) for p in objects.stones)
            + tuple(Body(Contact.ROOT, p) for p in objects.roots)
            + tuple(Body(Contact.MINE, p) for p in objects.mines))
