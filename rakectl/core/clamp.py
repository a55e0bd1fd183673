"""The voltage clamp: no voltage reaches the bus without passing here (pure).

It bounds the two motor voltages so that the force of the rake tip on anything
it meets — the ground from above, a buried object's top, side, rounded edge or,
lifted from under it, its bottom —
cannot exceed F_L (``force_limit_n`` less the model margin: 0.8 × 90 = 72 N),
in any direction, whatever the controller asked for and whatever the force
estimator believes: when a contact is met suddenly, at the speed the tip is
moving, and when it is pressed on afterwards. It uses only the measured joint
positions and velocities and the configured models (motors, transmissions,
arm masses, the tines' mount); nothing estimated.

The bound. :mod:`rakectl.core.envelope` derives it and computes it each tick: in
N = 72 sampled contact directions u (every direction, 5° apart), the budget B_u of
the worst-case push F_u of the motors along u, from the
impact at the tip's speed through the tine mount, the energy envelope a rounded edge
imposes and the margin for the directions between the samples.

Cutting. A request whose worst case is within every budget passes unchanged.
Otherwise the clamp takes the voltages on the segment from a safe anchor to the
request that are as close to the request as the budgets allow: every worst-case
load is piecewise linear along the segment, so the first crossing of a bound is
found exactly (and the result checked, never assumed). Along that segment the
nominal push the motors add to the anchor's scales with the distance (voltage
over the anchor's, back-EMF included, is current): the cut keeps the direction of
the push the controller asked for and shortens it, so a lift stays a lift. The anchor is
the voltage pair that holds the rake's weight with no other push (its friction
band centred on the weight, or nominal, whichever is further from every bound); when the tip
moves too fast toward some direction for that to be safe, the same plus a brake
against the motion (of ½ to 8 × F_L/2, judged by the budgets like any push:
braking a descent pushes up, where only the bottom of an object the tines are
under could be met, and braking a sideways motion toward the other side);
when none is safe, the one over budget by least, or a point toward the request
over by less still (a lift that relieves a bound the weight is at), counted in
``saturated``, and, if the tip is not moving toward anything (the rake's own
weight over budget at rest), ``infeasible``, which the caller must treat as a
fault. Braking while moving is not a fault: 0 V would let the rake fall.

What it does not cover: the current's electrical transient after a command drops
(L/R ≈ 0.3 ms), which the margin absorbs; a mount stiffer than configured (the
clamp is only as true as ``contact_stiffness_n_per_m`` and
``side_contact_stiffness_n_per_m``, and of the counterweight: hardware requirements,
the mount each way and the weight checked before arming, rakectl.core.mount_check and
rakectl.core.selftest, the ratio of the two stiffnesses within a factor 1.85, closer at
assembly); the tines' own mass below the mount (its impulse is ignored). A non-finite input
gives 0 V and sets ``non_finite`` (the caller must fault): it is never silently
replaced.
"""

from __future__ import annotations

import math

import numpy as np

from rakectl.config.settings import ClampSettings
from rakectl.core.envelope import DIRECTIONS, ContactEnvelope
from rakectl.core.motor_model import MotorParams
from rakectl.limits import FORCE_LIMIT_N

BRAKE_SHARES = (0.5, 1.0, 2.0, 4.0, 8.0)  # brakes tried, as shares of F_L/2
SATURATED_STEPS = 10  # points tried toward the request when even the anchor is over


class VoltageClamp:
    """Bounds the two motor voltages each tick; see the module docstring."""

    def __init__(self, clamp: ClampSettings, motor_r: MotorParams, motor_theta: MotorParams,
                 dt_s: float, *, directions: int = DIRECTIONS) -> None:
        """``directions=1`` checks straight down only (the clamp before side contacts were
        bounded): a test-only switch that shows what the other directions hold."""
        if clamp.force_limit_n > FORCE_LIMIT_N:
            raise ValueError(f"clamp.force_limit_n may not exceed {FORCE_LIMIT_N:g} N")
        if directions != 1 and (directions < 4 or directions % 4):
            raise ValueError("directions must be 1 or a multiple of 4")
        self._envelope = envelope = ContactEnvelope(clamp, motor_r, motor_theta, dt_s,
                                                    directions)
        self.limit_n = envelope.limit_n
        self.angles_rad = envelope.angles_rad
        # the constants the anchor and the cut use
        self._r, self._theta = envelope.r, envelope.theta
        self._weight_n, self._half_length_m = envelope.weight_n, envelope.half_length_m
        self.clamped = 0  # ticks on which a request was cut
        self.saturated = 0  # ticks on which even the anchor could not meet every budget
        self.non_finite = False
        self.infeasible = False  # latched: the budgets could not be met at rest at least once
        self.worst_case_n = 0.0  # the largest worst-case push F_u of the voltages returned
        self.worst_direction_rad = 0.0  # the direction φ it is along

    def clear_latched(self) -> None:
        """Forget ``non_finite`` and ``infeasible`` once the fault they raised was handled
        (a new arming starts from a clean clamp)."""
        self.non_finite = self.infeasible = False

    @property
    def budget_n(self) -> float:
        """This tick's smallest budget over the directions."""
        return self._envelope.budget_n

    # ------------------------------------------------------------------ per tick

    def apply(self, r_m: float, theta_rad: float, r_vel_m_per_s: float,
              theta_vel_rad_per_s: float, voltage_r_v: float, voltage_theta_v: float
              ) -> tuple[float, float]:
        """The voltages to send: the request, cut where it could push too hard."""
        total = (r_m + theta_rad + r_vel_m_per_s + theta_vel_rad_per_s + voltage_r_v
                 + voltage_theta_v)
        if not math.isfinite(total) or r_m <= 0.0:  # one check: inf/nan anywhere poisons the sum
            self.non_finite = True
            return 0.0, 0.0
        approaching = self._envelope.prepare(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s)
        voltage_r_v = max(-self._r.supply_v, min(self._r.supply_v, voltage_r_v))
        voltage_theta_v = max(-self._theta.supply_v, min(self._theta.supply_v, voltage_theta_v))
        if self._envelope.excess(voltage_r_v, voltage_theta_v) <= 0.0:
            self._report(voltage_r_v, voltage_theta_v)
            return voltage_r_v, voltage_theta_v
        self.clamped += 1
        anchor, excess = self._anchor(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s)
        if excess > 0.0:
            self.saturated += 1
            if not approaching:  # not braking toward anything: the weight alone is too much
                self.infeasible = True
            out = self._least_over(anchor, (voltage_r_v, voltage_theta_v), excess)
        else:
            request = (voltage_r_v, voltage_theta_v)
            depth = self._vertical_part(anchor, request, theta_rad)
            if self._envelope.excess(*depth) > 0.0:  # the push up or down alone does not fit
                out = self._search(anchor, request)
            else:
                out = self._search(depth, request)
        supply_r, supply_theta = self._r.supply_v, self._theta.supply_v  # rounding of a lerp
        out = (max(-supply_r, min(supply_r, out[0])),
               max(-supply_theta, min(supply_theta, out[1])))
        self._report(*out)
        return out

    def _least_over(self, anchor: tuple[float, float], request: tuple[float, float],
                    excess: float) -> tuple[float, float]:
        """When even the anchor is over a bound: the point of the segment toward the request
        (tenths) over by least, the furthest on a tie, so a request that relieves the bound
        (a lift where the weight is at its limit) is followed instead of held at the anchor."""
        best, least = anchor, excess
        for k in range(1, SATURATED_STEPS + 1):
            point = _lerp(anchor, request, k / SATURATED_STEPS)
            over = self._envelope.excess(*point)
            if over <= least:
                best, least = point, over
        return best

    def _vertical_part(self, anchor: tuple[float, float], request: tuple[float, float],
                       theta_rad: float) -> tuple[float, float]:
        """The anchor plus the vertical part of the push the request adds to it (nominal
        loads, back-EMF cancelling in the difference): what a cut keeps first, so that a
        stroke slowed by its budget slows along its path instead of rising or sinking."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        r_gain, theta_gain = self._r.load_per_volt, self._theta.load_per_volt
        load_r = (request[0] - anchor[0]) * r_gain
        load_theta = (request[1] - anchor[1]) * theta_gain
        # Q = Jᵀ f with J's rows (cos θ, −r sin θ), (−sin θ, −r cos θ): f_z = −sin θ Q_r
        # − cos θ Q_θ / r; the vertical push alone is Q = (−sin θ, −r cos θ) f_z
        r_m = self._envelope.r_m
        f_z = -sin_t * load_r - cos_t * load_theta / r_m
        supply_r, supply_theta = self._r.supply_v, self._theta.supply_v
        return (max(-supply_r, min(supply_r, anchor[0] - sin_t * f_z / r_gain)),
                max(-supply_theta, min(supply_theta, anchor[1] - r_m * cos_t * f_z / theta_gain)))

    def _report(self, voltage_r_v: float, voltage_theta_v: float) -> None:
        """``worst_case_n``: the largest worst-case push F_u of the voltages returned."""
        self.worst_case_n, self.worst_direction_rad = self._envelope.worst_push(
            voltage_r_v, voltage_theta_v)

    def _anchor(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float
                ) -> tuple[tuple[float, float], float]:
        """The safe end of the search and how far it is over its bound: the voltages that
        hold the rake's weight; if that is over a bound (the tip moves toward something too
        fast), the same plus a brake against the motion, the least over of
        ``BRAKE_SHARES`` × F_L/2."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        hold_r = -self._weight_n * sin_t
        hold_theta = -self._weight_n * (r_m - self._half_length_m) * cos_t
        best, least = (0.0, 0.0), math.inf
        for centred in (True, False):  # the friction band centred on the weight, or nominal
            scale_r = self._r.centring if centred else 1.0
            scale_theta = self._theta.centring if centred else 1.0
            hold = (self._r.voltage_for(scale_r * hold_r, r_vel),
                    self._theta.voltage_for(scale_theta * hold_theta, theta_vel))
            excess = self._envelope.excess(*hold)
            if excess < least:
                best, least = hold, excess
        hold_r, hold_theta = self._r.centring * hold_r, self._theta.centring * hold_theta
        reach_vel = cos_t * r_vel - r_m * sin_t * theta_vel
        height_vel = -sin_t * r_vel - r_m * cos_t * theta_vel
        speed = math.hypot(reach_vel, height_vel)
        if least <= 0.0 or speed <= 0.0:
            return best, least
        for share in BRAKE_SHARES:  # a push against the motion, as joint loads Jᵀ F
            push = share * 0.5 * self.limit_n / speed
            f_reach, f_height = -push * reach_vel, -push * height_vel
            load_r = cos_t * f_reach - sin_t * f_height
            load_theta = -r_m * (sin_t * f_reach + cos_t * f_height)
            brake = (self._r.voltage_for(hold_r + load_r, r_vel),
                     self._theta.voltage_for(hold_theta + load_theta, theta_vel))
            excess = self._envelope.excess(*brake)
            if excess < least:
                best, least = brake, excess
        return best, least

    def _search(self, anchor: tuple[float, float], request: tuple[float, float]
                ) -> tuple[float, float]:
        """The point nearest the request on the segment from the (safe) anchor whose worst
        case meets every bound. Each worst-case load is piecewise linear along the segment
        (kinks where a current limit or the friction band's sign is crossed), so each
        direction's excess is linear between the kinks: the first crossing is exact."""
        envelope = self._envelope
        if anchor == request or envelope.excess(*request) <= 0.0:
            return request if envelope.excess(*request) <= 0.0 else anchor
        kinks = sorted({0.0, 1.0, *self._kinks(anchor, request)})
        loads = [envelope.loads(*_lerp(anchor, request, t)) for t in kinks]
        excess = envelope.weights @ np.array(loads).T - envelope.bound[:, None]  # direction × kink
        over = (excess[:, 1:] > 0.0).any(axis=0)
        j = int(over.argmax())  # the first stretch whose end is over some bound
        now, nxt = excess[:, j], excess[:, j + 1]
        crossing = nxt > 0.0
        # the first crossing, within the stretch (min and a clip to [0, 1] commute)
        fraction = min(1.0, max(0.0, float((-now[crossing] / (nxt[crossing] - now[crossing])
                                            ).min())))
        t = (kinks[j] + fraction * (kinks[j + 1] - kinks[j])) * (1.0 - 1e-9)
        out = _lerp(anchor, request, t)
        while t > 0.0 and envelope.excess(*out) > 0.0:  # rounding at the crossing: step back
            t = max(0.0, t - 1e-6)
            out = _lerp(anchor, request, t)
        return out

    def _kinks(self, anchor: tuple[float, float], request: tuple[float, float]
               ) -> list[float]:
        """Where along the segment a worst-case load changes slope: a current limit or a
        zero torque (the friction band's sides) is crossed, in (0, 1)."""
        out = []
        emf = self._envelope.emf
        for joint, k, emfs in ((self._r, 0, emf[0:2]), (self._theta, 1, emf[2:4])):
            # Python floats (the caller's may be numpy's): a step dv of a few ulps sends t
            # to inf, outside (0, 1), without numpy's overflow warning
            v0 = float(anchor[k])
            dv = float(request[k]) - v0
            if dv == 0.0:
                continue
            for s, e in ((1.0, float(emfs[0])), (-1.0, float(emfs[1]))):
                # s·V − emf = R·i at i = ±I_lim and at k_t·i = −τ_c
                for current_a in (joint.current_limit_a, -joint.current_limit_a,
                                  -joint.coulomb_nm / joint.kt_nm_per_a):
                    t = ((joint.resistance_ohm * current_a + e) / s - v0) / dv
                    if 0.0 < t < 1.0:
                        out.append(t)
        return out

    # ------------------------------------------------------------------ inspection

    def budgets_n(self, r_m: float, theta_rad: float, r_vel_m_per_s: float,
                  theta_vel_rad_per_s: float) -> np.ndarray:
        """B_u of every sampled direction at this measured motion (tests, plots)."""
        self._envelope.prepare(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s)
        return self._envelope.budget.copy()

    def tip_mass_kg(self, r_m: float, theta_rad: float, angle_rad: float = 0.0) -> float:
        """Apparent mass of the tip along u(φ), 1/(g_uᵀ M⁻¹ g_u); φ = 0 is straight down."""
        return self._envelope.tip_mass_kg(r_m, theta_rad, angle_rad)


def _lerp(a: tuple[float, float], b: tuple[float, float], t: float) -> tuple[float, float]:
    return a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
