"""The ground as the rake's tip meets it: the soil and the buried objects combined (pure
model), one substep at a time.

:class:`Ground` asks each object (:class:`drivers.objects.Body`) and the soil
(:class:`drivers.soil.Soil`) for its force on the tip and records what really happened
in :class:`GroundTruth`. Above its bottom and within its extent an object shields the
soil below its top: the soil never sees the tip lower than the object's top, except
a tine in it through its bottom (under it, it presses the soil under it at its own
height) or through a side (beside it, in the soil there); shielded, a tine under an
object was seen on its top, 40 mm higher, and the soil under it pushed it up again
with a fresh interface (20261128/2199). For the arm's compliant tine mount it also
gives the laws the tines may meet (:meth:`Ground.vertical_laws`,
:meth:`Ground.normal_laws`, :meth:`Ground.bottom_laws`) and takes what the mount
carried (:meth:`Ground.transmitted`, :meth:`Ground.lifted`).
"""

from __future__ import annotations

import math

from drivers.ground_params import GroundParams
from drivers.objects import Contact, NormalLaw, make_bodies
from drivers.soil import Soil, VerticalLaw
from rakectl.errors import NonFiniteError


class GroundTruth:
    """What really happened at the tip, updated in place by every :meth:`Ground.step`.

    ``force_down_n``: vertical force the tip applies on the ground (> 0 pressing
    down); ``force_drag_n``: horizontal force the tip applies on the ground,
    > 0 toward the robot (a contact stroke); ``interface_height_m``: undeformed
    soil interface x_e under the tip; ``surface_height_m``: top of the soil just
    ahead of the tip; ``cut_depth_m``; ``contact``; ``mine_activated`` (latched);
    ``max_force_down_n``: the largest vertical force so far, peaks inside a step
    included; ``lift_n``: the upward force the tip puts on objects' bottoms (≥ 0: a
    tine under an object, rising into it).
    """

    __slots__ = ("contact", "cut_depth_m", "force_down_n", "force_drag_n",
                 "interface_height_m", "lift_n", "max_force_down_n", "mine_activated",
                 "surface_height_m")

    def __init__(self) -> None:
        self.force_down_n = self.force_drag_n = self.max_force_down_n = self.lift_n = 0.0
        self.interface_height_m = self.surface_height_m = self.cut_depth_m = 0.0
        self.contact = Contact.NONE
        self.mine_activated = False


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
        truth, shield_m, f_reach_n, f_up_n, lift_n = self.truth, -math.inf, 0.0, 0.0, 0.0
        contact = Contact.NONE
        for body in self.bodies:
            if (not body.broken and body.left_m < reach_m < body.right_m
                    and height_m > body.bottom_m and body.hides_soil_from(reach_m, height_m)):
                shield_m = max(shield_m, body.shield_m(reach_m))
            if body.touch(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, dt_s):
                f_reach_n += body.force_reach_n
                if body.force_up_n >= 0.0:
                    f_up_n += body.force_up_n
                else:
                    lift_n -= body.force_up_n
                contact = body.kind
                if body.activated:
                    truth.mine_activated = True
        soil = self.soil
        soil.step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, shield_m)
        self._record(truth, contact, f_reach_n + soil.force_reach_n, f_up_n)
        truth.lift_n = lift_n
        return truth.force_drag_n, truth.force_down_n - lift_n

    def vertical_laws(self, reach_m: float, height_m: float, face_height_m: float,
                      step_s: float, reach_vel_m_per_s: float = 0.0, edges: bool = True
                      ) -> list[VerticalLaw]:
        """The vertical laws a tip at reach_m could meet from ``height_m`` up: the soil's
        (Soil.vertical_law) and any buried object's top or rounded edge (which, judged
        where the tines were: ``face_height_m``; an edge's law depends on the tip's reach
        speed too; ``edges=False`` leaves edges to a mount that gives sideways); used by
        the arm's compliant tine mount, solved over ``step_s``."""
        laws = []
        for body in self.bodies:
            law = body.vertical_law(reach_m, height_m, face_height_m, step_s,
                                    reach_vel_m_per_s, edges)
            if law is not None:
                laws.append(law)
        law = self.soil.vertical_law(reach_m, height_m)
        if law is not None:
            laws.append(law)
        return laws

    def normal_laws(self, reach_m: float, height_m: float, step_s: float
                    ) -> list[tuple[int, NormalLaw]]:
        """(body index, law) of every object whose side or rounded edge holds this point,
        as solved over ``step_s``."""
        laws = []
        for i, body in enumerate(self.bodies):
            law = body.normal_law(reach_m, height_m, step_s)
            if law is not None:
                laws.append((i, law))
        return laws

    def bottom_laws(self, reach_m: float, height_m: float, step_s: float
                    ) -> list[tuple[int, float, float, float]]:
        """(body index, bottom height, K, B) of every object whose bottom a tine at this
        point presses, as solved over ``step_s``."""
        laws = []
        for i, body in enumerate(self.bodies):
            law = body.bottom_law(reach_m, height_m, step_s)
            if law is not None:
                laws.append((i, *law))
        return laws

    def lifted(self, index: int, mount_n: float) -> None:
        """Body ``index``'s bottom held the tines this substep, the mount carrying
        ``mount_n`` (< 0: pulling them up): massless, they are held down with what the
        ground below pushes them up with (this step's reading) less that, and the body's
        record is at least that (tines resting on its bottom face, where its own law reads
        0, as :meth:`transmitted` does for the ground)."""
        force_n = self.truth.force_down_n - mount_n
        self.bodies[index]._record_side(force_n)
        if force_n > self.truth.lift_n:
            self.truth.lift_n = force_n

    def drag_law(self, reach_m: float, height_m: float, reach_vel_m_per_s: float
                 ) -> tuple[float, float]:
        """The soil's drag a tip here would meet (Soil.drag_law: as :meth:`step` computes it)."""
        return self.soil.drag_law(reach_m, height_m, reach_vel_m_per_s)

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
