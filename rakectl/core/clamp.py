"""The voltage clamp: no voltage reaches the bus without passing here (pure).

It bounds the two motor voltages so that the force of the rake tip on anything
it meets — the ground from above, a buried object's top, side or rounded edge —
cannot exceed F_L (``force_limit_n`` less the model margin: 0.8 × 90 = 72 N),
in any direction, whatever the controller asked for and whatever the force
estimator believes: when a contact is met suddenly, at the speed the tip is
moving, and when it is pressed on afterwards. It uses only the measured joint
positions and velocities and the configured models (motors, transmissions,
arm masses, the tines' mount); nothing estimated.

Contact directions. The ground pushes the tine along an outward normal n with
n_z ≥ 0 (a top, a side, an edge between them); the tine pushes it along u = −n,
anywhere in the lower half-plane. u(φ) = (−sin φ, −cos φ) in (reach, height),
φ from straight down, −90° (away from the robot) … 90° (toward it).

What the tip can push with. The joint loads Q = (F_r, τ_θ) of the motors plus
the generalized gravity forces G act on the tip through J (rakectl.core.kinematics).
Each motor's load is bounded through its current: steady state i = (V − k_e ω_m)/R
within the drive's current limit, the measured speed taken with an uncertainty
δω toward the side that makes the load larger (a back-driven motor draws MORE
than V/R); through the transmission a joint pushes at most (k_t i + τ_c)/(η k)
(friction and efficiency both working the worst way: the stick band's far edge)
and pulls back at least (k_t i + τ_c)·η/k, k the joint motion per motor radian.
So for any weights a_j, the worst case of Σ a_j Q_j is a sum of one nondecreasing
function of s_j·V_j per joint (s_j = sign a_j, ``_Joint.share_n``), inverted in
closed form (``_Joint.voltage_for``).

Impact along u. The tines hang on a compliant mount, vertically k_v (and c_v),
horizontally k_h (and c_h), in series with whatever they press, so along u no
contact is stiffer than k_u = 1/(u_x²/k_h + u_z²/k_v); with proportional damping
(c/k equal on both axes, τ) the mount along u is a spring-damper (k_u, τ k_u);
with unequal ratios the clamp takes the larger τ in every direction. A force f along u on the
tip slows its speed along u as a mass m_u = 1/(g_uᵀ M⁻¹ g_u), g_u = Jᵀu, M the
joints' (diagonal) mass matrix; what the motors and gravity add to that motion
is F_u = m_u g_uᵀ M⁻¹ (Q + G): the push along u as the contact feels it, its
weights a = m_u M⁻¹ g_u (a push across u still moves the tip along u where the
arm's inertia couples the axes). A contact met at speed v_u along u, with F_u
held, peaks at

    f_peak ≤ F_u + √(F_u² + k_u m_u v_u²) + τ k_u v_u     (undamped spring, plus c·v)

(at v_u = 0 a contact met suddenly still doubles F_u). Requiring f_peak ≤ F_L
gives the budget along u, with D = F_L − τ k_u v_u:

    F_u ≤ B_u(v_u) = (D² − k_u m_u v_u²) / (2 D),

F_L/2 at rest, shrinking with speed, negative (the motors must brake) once
√(k_u m_u)·v_u + τ k_u v_u ≥ F_L: with the defaults at r = 1.2 m, from 0.56 m/s
straight down (m_u ≈ 1.9 kg) and 0.23 m/s toward the robot (m_u ≈ 14 kg).

Energy envelope. A rounded edge can turn the tine's motion along u into motion
along another direction u′ (a side met while the edge lifts the tine): what the
mount stored along u, f²/(2 k_u), reads √(k_u′/k_u)·f along u′. So each
direction's limit is F_L·√(k_u/k_max), k_max the stiffest direction's. With the
isotropic mount the defaults declare (k_v = k_h = 5 kN/m, c = 7.5 N·s/m both,
a hardware requirement) the factor is 1 in every direction; a mount ten times
stiffer vertically than sideways would cut the side budgets by √10, to about
10 N, too little to hold the rake's weight near the robot.

v_u is the measured speed along u, plus its uncertainty (the joints'
velocity margins through g_u), plus what a push of F_u ≤ F_L/2 adds during the
reaction latency (F_L/2 /m_u · t); only approach counts (a tip moving away is
judged again each tick, before it can come back). Since F_u(P̂) = |P| for a push
P, the budget also bounds a press held afterwards: F_L/2 in every direction at rest.

Every direction, sampled. Since F_u = (uᵀ w)/(uᵀ A u), with A = J M⁻¹ Jᵀ and
w = J M⁻¹ (Q + G) the tip's acceleration under the push, the condition F_u ≤ B_u
reads uᵀ w ≤ B_u·uᵀAu: linear in the joint loads, so its worst case over the
loads' uncertainty is at a corner of their box. The clamp checks it at N = 37
directions, 5° apart. Between two samples the left-hand side of f_peak ≤ F_L can
exceed its larger sampled value by at most 1.5 % over the workspace and every
push and speed (tests/core/test_clamp.py measures it against 7201 directions);
the budgets are taken at F_L/(1 + ``SAMPLING_MARGIN``), 3 %, so the bound holds
in every direction, not only the sampled ones.

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
against the motion (of ½ to 8 × F_L/2: braking a descent pushes up, which no
contact resists, while braking a sideways motion pushes toward the other side);
when none is safe, the one over budget by least, or a point toward the request
over by less still (a lift that relieves a bound the weight is at), counted in
``saturated``, and, if the tip is not moving toward anything (the rake's own
weight over budget at rest), ``infeasible``, which the caller must treat as a
fault. Braking while moving is not a fault: 0 V would let the rake fall.

What it does not cover: the current's electrical transient after a command drops
(L/R ≈ 0.3 ms), which the margin absorbs; a mount stiffer than configured (the
clamp is only as true as ``contact_stiffness_n_per_m`` and
``side_contact_stiffness_n_per_m``, and of the counterweight: nothing on the
robot measures them yet, they are hardware requirements to verify at assembly); the
tines' own mass below the mount (its impulse is ignored). A non-finite input
gives 0 V and sets ``non_finite`` (the caller must fault): it is never silently
replaced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rakectl.config.settings import ClampSettings
from rakectl.core.motor_model import (
    MotorParams,
    joint_per_motor_rad,
    joint_resolution,
    reflected_inertia,
)
from rakectl.limits import FORCE_LIMIT_N

DIRECTIONS = 37  # contact directions sampled from −90° to 90° (every 5°)
SAMPLING_MARGIN = 0.03  # kept back for directions between the samples (1.5 % measured)
BRAKE_SHARES = (0.5, 1.0, 2.0, 4.0, 8.0)  # brakes tried, as shares of F_L/2
SATURATED_STEPS = 10  # points tried toward the request when even the anchor is over


@dataclass(frozen=True)
class _Joint:
    """Precomputed constants of one motor and transmission."""

    kt_nm_per_a: float
    resistance_ohm: float
    current_limit_a: float
    coulomb_nm: float
    efficiency: float
    joint_per_motor_rad: float
    supply_v: float
    velocity_margin: float  # joint units per second, absolute part

    @property
    def centring(self) -> float:
        """A nominal load L is held as anything between η·L and L/η: commanding L times
        this puts that band's middle on L."""
        return 2.0 / (self.efficiency + 1.0 / self.efficiency)

    @classmethod
    def of(cls, p: MotorParams, clamp: ClampSettings, dt_s: float) -> _Joint:
        return cls(p.torque_constant_nm_per_a, p.resistance_ohm, p.current_limit_a,
                   p.coulomb_friction_nm, p.gear_efficiency, joint_per_motor_rad(p),
                   p.supply_voltage_v, clamp.velocity_margin_counts * joint_resolution(p) / dt_s)

    def load_n(self, s: float, voltage_v: float, emf_v: float) -> float:
        """Worst case of s·Q for this joint at ``voltage_v`` (< 0: at least that much the
        other way); ``emf_v`` = k_e·(s·ω − δω) (see :meth:`emf_v`)."""
        limit_a = self.current_limit_a  # the drive limits both directions
        current_a = max(-limit_a, min(limit_a, (s * voltage_v - emf_v) / self.resistance_ohm))
        torque_nm = self.kt_nm_per_a * current_a + self.coulomb_nm
        if torque_nm >= 0.0:
            return torque_nm / (self.efficiency * self.joint_per_motor_rad)
        return torque_nm * self.efficiency / self.joint_per_motor_rad

    def emf_v(self, s: float, velocity: float, margin: float) -> float:
        """k_e·(s·ω_m − δω): back-EMF seen from the pushing side, with the uncertainty."""
        return self.kt_nm_per_a * (s * velocity - margin) / self.joint_per_motor_rad

    @property
    def load_per_volt(self) -> float:
        """Nominal joint load per volt at a fixed speed (η and friction left out)."""
        return self.kt_nm_per_a / (self.resistance_ohm * self.joint_per_motor_rad)

    def voltage_for(self, load: float, velocity: float) -> float:
        """Voltage at which this joint exerts ``load`` (N or N·m) nominally at ``velocity``
        (η and friction left out), within the supply."""
        torque_nm = load * self.joint_per_motor_rad
        emf_v = self.kt_nm_per_a * velocity / self.joint_per_motor_rad
        voltage_v = self.resistance_ohm * torque_nm / self.kt_nm_per_a + emf_v
        return max(-self.supply_v, min(self.supply_v, voltage_v))


class VoltageClamp:
    """Bounds the two motor voltages each tick; see the module docstring."""

    def __init__(self, clamp: ClampSettings, motor_r: MotorParams, motor_theta: MotorParams,
                 dt_s: float, *, directions: int = DIRECTIONS) -> None:
        """``directions=1`` checks straight down only (the clamp before side contacts were
        bounded): a test-only switch that shows what the other directions hold."""
        if clamp.force_limit_n > FORCE_LIMIT_N:
            raise ValueError(f"clamp.force_limit_n may not exceed {FORCE_LIMIT_N:g} N")
        if directions != 1 and (directions < 3 or directions % 2 == 0):
            raise ValueError("directions must be 1 or an odd number >= 3")
        self.limit_n = clamp.force_limit_n * (1.0 - clamp.model_margin)
        self._sampled_limit_n = self.limit_n / (1.0 + SAMPLING_MARGIN) if directions > 1 \
            else self.limit_n
        self._r = _Joint.of(motor_r, clamp, dt_s)
        self._theta = _Joint.of(motor_theta, clamp, dt_s)
        share = clamp.counterbalance_share if clamp.counterweight_kg > 0.0 else 0.0
        self._weight_n = (1.0 - share) * clamp.rake_mass_kg * clamp.gravity_m_per_s2
        balancing_kg = ((share * clamp.rake_mass_kg) ** 2 / clamp.counterweight_kg
                        if clamp.counterweight_kg > 0.0 else 0.0)
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._velocity_share = clamp.velocity_margin_share
        self._latency_s = clamp.reaction_latency_s
        self._rake_mass_kg = clamp.rake_mass_kg + balancing_kg  # what moves along r
        self._mass_r = self._rake_mass_kg + reflected_inertia(motor_r)
        self._inertia_0 = (clamp.rake_mass_kg * clamp.rake_length_m ** 2 / 12.0
                           + clamp.platform_inertia_kgm2 + reflected_inertia(motor_theta))
        k_v, k_h = clamp.contact_stiffness_n_per_m, clamp.side_contact_stiffness_n_per_m
        tau_v_s, tau_h_s = clamp.contact_damping_ns_per_m / k_v, \
            clamp.side_contact_damping_ns_per_m / k_h
        angles = np.linspace(-0.5 * math.pi, 0.5 * math.pi, directions) if directions > 1 \
            else np.zeros(1)
        self.angles_rad = angles
        # rows (cos φ, −sin φ) and (cos φ, sin φ): Jᵀu = (sin(θ − φ), r cos(θ − φ))
        self._rotations = np.stack([np.stack([np.cos(angles), -np.sin(angles)], axis=1),
                                    np.stack([np.sin(angles), np.cos(angles)], axis=1)],
                                   axis=1)
        self._stiffness = 1.0 / (np.sin(angles) ** 2 / k_h + np.cos(angles) ** 2 / k_v)
        # the energy envelope: what the mount stores along u, F²/(2 k_u), a rounded edge
        # can turn into the stiffest direction, where it reads √(k_max/k_u)·F
        self._limit = self._sampled_limit_n * np.sqrt(self._stiffness / max(k_v, k_h))
        # the larger time constant in every direction: exact when both are equal (the
        # defaults), conservative otherwise, and continuous across the samples
        self._damping = max(tau_v_s, tau_h_s) * self._stiffness
        # this tick's terms per direction: uᵀw ≤ bound, uᵀw = c_r Q_r + c_θ Q_θ + gravity
        # uᵀw's worst case is weights @ (Q_r high, Q_r low, Q_θ high, Q_θ low)
        self._weights = np.zeros((directions, 4))
        self._pair = np.zeros(2)  # scratch: two numbers to multiply a (directions × 2) by
        self._ones = np.ones(2)
        self._bound = np.zeros(directions)
        self._budget = np.zeros(directions)
        self._gravity = np.zeros(directions)
        self._mass = np.zeros(directions)
        self._r_m = 1.0  # this tick's r
        self._emf = (0.0, 0.0, 0.0, 0.0)  # r for s = +1, s = −1; θ for s = +1, s = −1
        self._last = (math.nan, math.nan)  # the voltages _last_worst belongs to
        self._last_worst = np.zeros(directions)
        self.clamped = 0  # ticks on which a request was cut
        self.saturated = 0  # ticks on which even the anchor could not meet every budget
        self.non_finite = False
        self.infeasible = False  # latched: the budgets could not be met at rest at least once
        self.budget_n = 0.0  # this tick's smallest budget over the directions
        self.worst_case_n = 0.0  # the largest worst-case push F_u of the voltages returned
        self.worst_direction_rad = 0.0  # the direction φ it is along

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
        approaching = self._prepare(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s)
        voltage_r_v = max(-self._r.supply_v, min(self._r.supply_v, voltage_r_v))
        voltage_theta_v = max(-self._theta.supply_v, min(self._theta.supply_v, voltage_theta_v))
        if self._excess(voltage_r_v, voltage_theta_v) <= 0.0:
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
            if self._excess(*depth) > 0.0:  # the push up or down alone does not fit
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
            over = self._excess(*point)
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
        r_m = self._r_m
        f_z = -sin_t * load_r - cos_t * load_theta / r_m
        supply_r, supply_theta = self._r.supply_v, self._theta.supply_v
        return (max(-supply_r, min(supply_r, anchor[0] - sin_t * f_z / r_gain)),
                max(-supply_theta, min(supply_theta, anchor[1] - r_m * cos_t * f_z / theta_gain)))

    def _prepare(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float) -> bool:
        """This tick's weights and bounds in every direction; whether the tip moves toward
        any of them faster than its measurement's uncertainty."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        self._r_m = r_m
        com_m = r_m - self._half_length_m
        mass_r = self._mass_r
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        share = self._velocity_share
        margin_r = self._r.velocity_margin + share * abs(r_vel)
        margin_theta = self._theta.velocity_margin + share * abs(theta_vel)
        self._emf = (self._r.emf_v(1.0, r_vel, margin_r), self._r.emf_v(-1.0, r_vel, margin_r),
                     self._theta.emf_v(1.0, theta_vel, margin_theta),
                     self._theta.emf_v(-1.0, theta_vel, margin_theta))
        # g = Jᵀu = (sin(θ − φ), r cos(θ − φ)), one row per direction
        pair = self._pair
        pair[0], pair[1] = sin_t, cos_t
        g = self._rotations @ pair
        g[:, 1] *= r_m
        pair[0], pair[1] = 1.0 / mass_r, 1.0 / inertia
        c = g * pair  # uᵀw = uᵀ J M⁻¹ (Q + G) = c · (Q + G)
        weights = self._weights
        np.maximum(c, 0.0, out=weights[:, 0::2])
        np.minimum(c, 0.0, out=weights[:, 1::2])
        q = (g * c) @ self._ones  # uᵀ A u = 1/m_u
        self._mass = mass = 1.0 / q
        pair[0], pair[1] = r_vel, theta_vel
        measured = g @ pair
        pair[0], pair[1] = margin_r, margin_theta
        uncertain = np.abs(g) @ pair
        speed = measured + uncertain
        np.maximum(speed, 0.0, out=speed)
        speed += (0.5 * self.limit_n * self._latency_s) * q  # F_L/2 along u for the latency
        d_n = self._limit - self._damping * speed
        with np.errstate(divide="ignore", invalid="ignore"):
            budget = (d_n - self._stiffness * mass * speed * speed / d_n) * 0.5
        budget[d_n <= 0.0] = -np.inf
        self._budget = budget
        self.budget_n = float(budget.min())
        # gravity's part of uᵀw is fixed this tick: it is folded into the bound
        pair[0], pair[1] = self._weight_n * sin_t, self._weight_n * com_m * cos_t
        self._gravity = c @ pair
        self._bound = budget * q - self._gravity
        return bool((measured > uncertain).any())

    def _loads(self, voltage_r_v: float, voltage_theta_v: float) -> list[float]:
        """Worst-case joint loads (Q_r highest, lowest, Q_θ highest, lowest)."""
        emf = self._emf
        return [self._r.load_n(1.0, voltage_r_v, emf[0]),
                -self._r.load_n(-1.0, voltage_r_v, emf[1]),
                self._theta.load_n(1.0, voltage_theta_v, emf[2]),
                -self._theta.load_n(-1.0, voltage_theta_v, emf[3])]

    def _worst(self, voltage_r_v: float, voltage_theta_v: float) -> np.ndarray:
        """Worst case over the loads' box of uᵀ J M⁻¹ Q, in every direction (kept for
        :meth:`_report`)."""
        self._last = (voltage_r_v, voltage_theta_v)
        self._last_worst = self._weights @ self._loads(voltage_r_v, voltage_theta_v)
        return self._last_worst

    def _excess(self, voltage_r_v: float, voltage_theta_v: float) -> float:
        """How far the worst direction is over its bound, in m/s² (≤ 0: within all)."""
        return float((self._worst(voltage_r_v, voltage_theta_v) - self._bound).max())

    def _report(self, voltage_r_v: float, voltage_theta_v: float) -> None:
        """``worst_case_n``: the largest worst-case push F_u of the voltages returned."""
        worst = (self._last_worst if self._last == (voltage_r_v, voltage_theta_v)
                 else self._worst(voltage_r_v, voltage_theta_v))
        push = self._mass * (worst + self._gravity)
        i = int(np.argmax(push))
        self.worst_case_n = float(push[i])
        self.worst_direction_rad = float(self.angles_rad[i])

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
            excess = self._excess(*hold)
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
            excess = self._excess(*brake)
            if excess < least:
                best, least = brake, excess
        return best, least

    def _search(self, anchor: tuple[float, float], request: tuple[float, float]
                ) -> tuple[float, float]:
        """The point nearest the request on the segment from the (safe) anchor whose worst
        case meets every bound. Each worst-case load is piecewise linear along the segment
        (kinks where a current limit or the friction band's sign is crossed), so each
        direction's excess is linear between the kinks: the first crossing is exact."""
        if anchor == request or self._excess(*request) <= 0.0:
            return request if self._excess(*request) <= 0.0 else anchor
        kinks = sorted({0.0, 1.0, *self._kinks(anchor, request)})
        loads = [self._loads(*_lerp(anchor, request, t)) for t in kinks]
        excess = self._weights @ np.array(loads).T - self._bound[:, None]  # direction × kink
        over = (excess[:, 1:] > 0.0).any(axis=0)
        j = int(over.argmax())  # the first stretch whose end is over some bound
        now, nxt = excess[:, j], excess[:, j + 1]
        crossing = nxt > 0.0
        fraction = float(np.clip(-now[crossing] / (nxt[crossing] - now[crossing]), 0.0,
                                 1.0).min())
        t = (kinks[j] + fraction * (kinks[j + 1] - kinks[j])) * (1.0 - 1e-9)
        out = _lerp(anchor, request, t)
        while t > 0.0 and self._excess(*out) > 0.0:  # rounding at the crossing: step back
            t = max(0.0, t - 1e-6)
            out = _lerp(anchor, request, t)
        return out

    def _kinks(self, anchor: tuple[float, float], request: tuple[float, float]
               ) -> list[float]:
        """Where along the segment a worst-case load changes slope: a current limit or a
        zero torque (the friction band's sides) is crossed, in (0, 1)."""
        out = []
        emf = self._emf
        for joint, k, emfs in ((self._r, 0, emf[0:2]), (self._theta, 1, emf[2:4])):
            v0, v1 = anchor[k], request[k]
            dv = v1 - v0
            if dv == 0.0:
                continue
            for s, e in ((1.0, emfs[0]), (-1.0, emfs[1])):
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
        self._prepare(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s)
        return self._budget.copy()

    def tip_mass_kg(self, r_m: float, theta_rad: float, angle_rad: float = 0.0) -> float:
        """Apparent mass of the tip along u(φ), 1/(g_uᵀ M⁻¹ g_u); φ = 0 is straight down."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        ux, uz = -math.sin(angle_rad), -math.cos(angle_rad)
        com_m = r_m - self._half_length_m
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        g_r, g_theta = cos_t * ux - sin_t * uz, -r_m * (sin_t * ux + cos_t * uz)
        return 1.0 / (g_r * g_r / self._mass_r + g_theta * g_theta / inertia)


def _lerp(a: tuple[float, float], b: tuple[float, float], t: float) -> tuple[float, float]:
    return a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
