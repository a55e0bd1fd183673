"""Buried objects and the :class:`Ground` that combines them with the soil (pure model).

Each object is a rectangle in the (reach, height) plane: ``width_m`` along the
reach centred on ``reach_m``, from its top at ``−depth_m`` (below ground level
0) down ``thickness_m``; it is assumed to span the rake's width. It is felt
only while the tip is strictly inside that rectangle. The face pressed is the
one the tip is least deep behind (top, robot side, far side): a penalty
contact F = K·penetration + K·τ·(approach speed), clipped at 0 (no pulling).
Above its bottom and within its extent an object shields the soil below its
top: the soil model never sees the tip lower than the object's top.

* STONE: rigid (K = 1e7 N/m), never yields or collapses.
* ROOT: round, not a rectangle: an ellipse (``width_m`` × ``thickness_m``)
  inscribed in it. On its upper half the tip meets a curved surface: the
  penetration is taken vertically below it, the force acts along the
  surface's normal (vertical K·p/(1 + s²), horizontal −s times that, s the
  slope), so a tine that meets it just under its top rides up it gradually
  instead of being pushed sideways into it and then, past a corner, upward by
  its whole overlap at once (which read 110–140 N on the ground for a tick
  in the safety campaign). The damping of a rise that the slope alone makes
  (B·s·v_reach/(1 + s²), ≤ 3.5 N at 0.25 m/s) is left out. Below its
  middle the push is horizontal, from the nearer side.
  Elastic–perfectly plastic: K from a 2 cm wooden root bent over
  0.3 m (48EI/L³ with E = 10 GPa ≈ 1.4e5 N/m), force capped at the yield force
  (M_y = σ_y I/(d/2) with σ_y = 40 MPa, F = 4M_y/L ≈ 400 N); beyond it the root
  is pushed along (permanent set) and, once moved by ``break_displacement_m``,
  it has broken or been torn aside and is felt no more. While it is pushed
  down, the soil under it is squeezed as under the tip (the soil's saw-tooth,
  ≤ its collapse force, adds to the yield force).
* MINE: rigid body (K = 5e6 N/m, a plastic casing) whose whole top is the
  pressure plate (conservative). It is activated — latched — the first step
  the vertical force on its top exceeds ``activation_force_n``; a push on its
  side does not activate it (side forces are recorded as ``peak_side_n``).
  Force passed down through covering soil is not counted: it never exceeds the
  tip's total vertical force, which :class:`GroundTruth` records as
  ``max_force_down_n``, so the 90 N criterion on that total is the
  conservative check.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from drivers.soil import Soil, SoilParams, VerticalLaw
from rakectl.declare import section, setting
from rakectl.errors import NonFiniteError


class Contact(enum.Enum):
    """What the tip is touching (objects take precedence over soil)."""

    NONE = "none"
    SOIL = "soil"
    STONE = "stone"
    ROOT = "root"
    MINE = "mine"


@dataclass(frozen=True)
class StoneParams:
    """A stone: rigid, never yields."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.08, "Depth of its top below ground level 0 (< 0 protrudes).",
                             unit="m", ge=-0.5, le=2)
    width_m: float = setting(0.10, "Extent along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.08, "Extent below its top.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(1.0e7, "Contact stiffness.", unit="N/m", gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)


@dataclass(frozen=True)
class RootParams:
    """A root crossing the lane: elastic, then plastic above its yield force."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.06, "Depth of its top below ground level 0.", unit="m",
                             ge=-0.5, le=2)
    width_m: float = setting(0.02, "Diameter along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.02, "Diameter, vertically.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(1.4e5, "Bending stiffness 48EI/L³.", unit="N/m",
                                       gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)
    yield_force_n: float = setting(400.0, "Force above which it bends permanently.",
                                   unit="N", gt=0, le=1e5)
    break_displacement_m: float = setting(0.03, "Permanent set at which it breaks.", unit="m",
                                          gt=0, le=2)


@dataclass(frozen=True)
class MineParams:
    """A pressure-fused anti-personnel mine; its whole top is the pressure plate."""

    reach_m: float = setting(1.0, "Centre along the reach.", unit="m", ge=0, le=20)
    depth_m: float = setting(0.05, "Depth of its top (the plate) below ground level 0.",
                             unit="m", ge=-0.5, le=2)
    width_m: float = setting(0.08, "Diameter along the reach.", unit="m", gt=0, le=2)
    thickness_m: float = setting(0.05, "Height of the body.", unit="m", gt=0, le=2)
    stiffness_n_per_m: float = setting(5.0e6, "Contact stiffness.", unit="N/m", gt=0, le=1e9)
    damping_time_s: float = setting(2.0e-4, "Contact dashpot as a time constant: B = K·τ.",
                                    unit="s", ge=0, le=0.1)
    activation_force_n: float = setting(
        90.0, "Plate force that fires it (typical AP mines: 80–100 N).", unit="N",
        gt=0, le=1e4)


@dataclass(frozen=True)
class BuriedObjects:
    """The objects buried in the lane."""

    stones: tuple[StoneParams, ...] = setting((), "Stones.")
    roots: tuple[RootParams, ...] = setting((), "Roots.")
    mines: tuple[MineParams, ...] = setting((), "Mines.")


class Body:
    """Runtime state of one buried object; ``touch`` writes the forces on the tip."""

    __slots__ = ("activated", "activation_force_n", "bottom_m", "break_m", "broken",
                 "damping_s", "force_reach_n", "force_up_n", "kind", "left_m", "moved_m",
                 "peak_down_n", "peak_side_n", "right_m", "round", "stiffness_n_per_m",
                 "top_m", "yield_force_n")

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
        self.round = kind is Contact.ROOT

    def _upper_surface(self, reach_m: float) -> tuple[float, float]:
        """A round body's upper surface above ``reach_m`` (inside its extent): (height, slope
        d height / d reach)."""
        a, b = 0.5 * (self.right_m - self.left_m), 0.5 * (self.top_m - self.bottom_m)
        u = (reach_m - self.left_m - a) / a
        root = math.sqrt(max(1.0 - u * u, 1e-12))
        return self.bottom_m + b + b * root, -b * u / (a * root)

    def shield_m(self, reach_m: float) -> float:
        """The height below which it hides the soil from a tip at ``reach_m`` (inside its
        extent): its top, or a round body's surface there."""
        return self._upper_surface(reach_m)[0] if self.round else self.top_m

    def touch(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
              height_vel_m_per_s: float) -> bool:
        """Forces on the tip at this position; False (and zero forces) if not touching."""
        self.force_reach_n = self.force_up_n = 0.0
        if self.broken or not (self.left_m < reach_m < self.right_m
                               and self.bottom_m < height_m < self.top_m):
            return False
        if self.round:
            return self._touch_round(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s)
        top_m, near_m, far_m = self.top_m - height_m, reach_m - self.left_m, self.right_m - reach_m
        if top_m <= near_m and top_m <= far_m:
            self.force_up_n = self._resist(top_m, -height_vel_m_per_s, 0.0, -1.0)
            self._record_top(self.force_up_n)
        else:
            self._push_side(near_m, far_m, reach_vel_m_per_s)
        return True

    def _push_side(self, near_m: float, far_m: float, reach_vel_m_per_s: float) -> None:
        """A horizontal push from the side the tip is nearer (inside by near_m from the
        robot's side, far_m from the other)."""
        if near_m < far_m:
            self.force_reach_n = -self._resist(near_m, reach_vel_m_per_s, 1.0, 0.0)
            self._record_side(-self.force_reach_n)
        else:
            self.force_reach_n = self._resist(far_m, -reach_vel_m_per_s, -1.0, 0.0)
            self._record_side(self.force_reach_n)

    def _touch_round(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
                     height_vel_m_per_s: float) -> bool:
        middle_m = 0.5 * (self.top_m + self.bottom_m)
        if height_m >= middle_m:  # the upper half: a curved surface above the tip
            surface_m, slope = self._upper_surface(reach_m)
            if height_m >= surface_m:
                return False
            n2 = 1.0 + slope * slope
            elastic_n = self.stiffness_n_per_m * (surface_m - height_m) / math.sqrt(n2)
            if elastic_n > self.yield_force_n:  # pushed down and aside, along the normal
                set_m = (elastic_n - self.yield_force_n) / self.stiffness_n_per_m
                self._yield(set_m, slope / math.sqrt(n2), -1.0 / math.sqrt(n2))
                elastic_n = self.yield_force_n
            damping_n = self.stiffness_n_per_m * self.damping_s * -height_vel_m_per_s
            up_n = max(0.0, (elastic_n * math.sqrt(n2) + damping_n) / n2)
            self.force_up_n, self.force_reach_n = up_n, -slope * up_n
            self._record_top(up_n)
            return True
        a, b = 0.5 * (self.right_m - self.left_m), 0.5 * (self.top_m - self.bottom_m)
        w = (height_m - middle_m) / b
        half_m = a * math.sqrt(max(1.0 - w * w, 0.0))  # half its width at this height
        centre_m = self.left_m + a
        near_m, far_m = reach_m - (centre_m - half_m), centre_m + half_m - reach_m
        if near_m <= 0.0 or far_m <= 0.0:
            return False
        self._push_side(near_m, far_m, reach_vel_m_per_s)
        return True

    def vertical_law(self, reach_m: float, height_m: float, face_height_m: float
                     ) -> VerticalLaw | None:
        """Its top face's law (top, K, B, yield force) if a tip at ``height_m`` is inside
        and, judged at ``face_height_m`` (where the tines were), presses on the top. A round
        body's is its surface above ``reach_m``, with the vertical parts of K, B and the
        yield force there."""
        if self.broken or not (self.left_m < reach_m < self.right_m
                               and self.bottom_m < height_m < self.top_m):
            return None
        if self.round:
            if face_height_m < 0.5 * (self.top_m + self.bottom_m):
                return None  # below its middle: that push is horizontal
            surface_m, slope = self._upper_surface(reach_m)
            n2 = 1.0 + slope * slope
            return VerticalLaw(surface_m, self.stiffness_n_per_m / n2,
                               self.stiffness_n_per_m * self.damping_s / n2,
                               self.yield_force_n / math.sqrt(n2), False)
        below_top_m = self.top_m - min(face_height_m, self.top_m)
        if below_top_m > min(reach_m - self.left_m, self.right_m - reach_m):
            return None  # nearer a side face: that push is horizontal
        return VerticalLaw(self.top_m, self.stiffness_n_per_m,
                           self.stiffness_n_per_m * self.damping_s, self.yield_force_n, False)

    def _resist(self, depth_m: float, approach_m_per_s: float, dx: float, dz: float) -> float:
        """Penalty force of a face; a root yields, moving along (dx, dz)."""
        elastic_n = self.stiffness_n_per_m * depth_m
        if elastic_n > self.yield_force_n:
            self._yield((elastic_n - self.yield_force_n) / self.stiffness_n_per_m, dx, dz)
            elastic_n = self.yield_force_n
        force_n = elastic_n + self.stiffness_n_per_m * self.damping_s * approach_m_per_s
        return force_n if force_n > 0.0 else 0.0

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


class GroundTruth:
    """What really happened at the tip, updated in place by every :meth:`Ground.step`.

    ``force_down_n``: vertical force the tip applies on the ground (> 0 pressing
    down); ``force_drag_n``: horizontal force the tip applies on the ground,
    > 0 toward the robot (a contact stroke); ``interface_height_m``: undeformed
    soil interface x_e under the tip; ``surface_height_m``: top of the soil just
    ahead of the tip; ``cut_depth_m``; ``contact``; ``mine_activated`` (latched);
    ``max_force_down_n``: the largest vertical force so far, peaks inside a step
    included.
    """

    __slots__ = ("contact", "cut_depth_m", "force_down_n", "force_drag_n",
                 "interface_height_m", "max_force_down_n", "mine_activated",
                 "surface_height_m")

    def __init__(self) -> None:
        self.force_down_n = self.force_drag_n = self.max_force_down_n = 0.0
        self.interface_height_m = self.surface_height_m = self.cut_depth_m = 0.0
        self.contact = Contact.NONE
        self.mine_activated = False


@dataclass(frozen=True)
class GroundParams:
    """Soil and buried objects of a lane."""

    soil: SoilParams = section(SoilParams)
    objects: BuriedObjects = section(BuriedObjects)


class Ground:
    """Soil plus buried objects: the force on the rake tip, one substep at a time."""

    __slots__ = ("bodies", "soil", "truth")

    def __init__(self, params: GroundParams, seed: int) -> None:
        self.soil = Soil(params.soil, seed)
        self.bodies = make_bodies(params.objects)
        self.truth = GroundTruth()

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        """Force ON the tip BY the ground, (f_reach_n, f_height_n); advances the ground's state.

        The models are quasi-static, so ``dt_s`` only has to be finite.
        """
        if not math.isfinite(reach_m + height_m + reach_vel_m_per_s + height_vel_m_per_s + dt_s):
            raise NonFiniteError("Ground.step: non-finite tip state or time step")
        truth, shield_m, f_reach_n, f_up_n = self.truth, -math.inf, 0.0, 0.0
        contact = Contact.NONE
        for body in self.bodies:
            if (not body.broken and body.left_m < reach_m < body.right_m
                    and height_m > body.bottom_m and body.shield_m(reach_m) > shield_m):
                shield_m = body.shield_m(reach_m)
            if body.touch(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s):
                f_reach_n += body.force_reach_n
                f_up_n += body.force_up_n
                contact = body.kind
                if body.activated:
                    truth.mine_activated = True
        soil = self.soil
        soil.step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, shield_m)
        self._record(truth, contact, f_reach_n + soil.force_reach_n, f_up_n)
        return truth.force_drag_n, truth.force_down_n

    def vertical_laws(self, reach_m: float, height_m: float, face_height_m: float
                      ) -> list[VerticalLaw]:
        """The vertical laws a tip at reach_m could meet from ``height_m`` up: the soil's
        (Soil.vertical_law) and any buried object's top (which face, judged where the
        tines were: ``face_height_m``); used by the arm's compliant tine mount."""
        laws = []
        for body in self.bodies:
            law = body.vertical_law(reach_m, height_m, face_height_m)
            if law is not None:
                laws.append(law)
        law = self.soil.vertical_law(reach_m, height_m)
        if law is not None:
            laws.append(law)
        return laws

    def transmitted(self, force_down_n: float) -> None:
        """What a compliant tine mount carried into the ground this substep: the truth's
        vertical force is at least that (the arm's implicit solve can rest the tines on a
        surface, where the soil's own law reads nothing)."""
        truth = self.truth
        if force_down_n > truth.force_down_n:
            truth.force_down_n = force_down_n
            if force_down_n > truth.max_force_down_n:
                truth.max_force_down_n = force_down_n

    def _record(self, truth: GroundTruth, contact: Contact, f_reach_n: float,
                f_up_objects_n: float) -> None:
        soil = self.soil
        truth.force_drag_n = f_reach_n
        truth.force_down_n = f_up_objects_n + soil.force_up_n
        peak_n = f_up_objects_n + soil.peak_up_n
        if peak_n > truth.max_force_down_n:
            truth.max_force_down_n = peak_n
        truth.contact = Contact.SOIL if contact is Contact.NONE and soil.touching else contact
        truth.interface_height_m = soil.interface_height_m
        truth.surface_height_m = soil.surface_height_m
        truth.cut_depth_m = soil.cut_depth_m
