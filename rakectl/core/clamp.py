"""The voltage clamp: no voltage reaches the bus without passing here (pure).

It bounds each motor's voltage so that the vertical force of the rake on the
ground cannot exceed F_limit (90 N at most), whatever the controller asked for
and whatever the force estimator believes: statically, and when the tines
arrive on something stiff at the speed they are moving. It uses only the
measured joint positions and velocities and the configured models (motors,
transmissions, arm masses, the tines' mount); nothing estimated.

Static part. At rest the joint loads Q = (F_r, τ_θ) of the motors plus the
generalized gravity forces G balance the ground's force on the tip through
Jᵀ (rakectl.core.kinematics), so the tip presses on the ground with F = J⁻ᵀ(Q + G).
With θ below the horizontal, its downward component is

    F_down = sin θ · (F_r + G_r) + (cos θ / r) · (τ_θ + G_θ),
    G_r = m g sin θ,   G_θ = m g (r − L/2) cos θ.

Each motor's joint load is bounded through its current. Steady state
(L di/dt → 0): i = (V − k_e ω_m)/R, within the drive's current limit; a motor
back-driven against its voltage (ω_m opposite to V) draws MORE than V/R, so
the measured speed enters with an uncertainty δω toward the dangerous side.
Through the transmission, a joint presses at most (k_t i + τ_c)/(η k) (friction
and efficiency both working against the ground: the stick band's far edge)
and lifts at least (k_t i + τ_c)·η/k when that is negative, k the joint
motion per motor radian. With s_j = sign(c_j) the direction in which joint j
presses down (c_r = sin θ, c_θ = cos θ / r), joint j's worst-case share

    F_j(V_j) = |c_j| · T_j / (η k) if T_j ≥ 0 else |c_j| · T_j · η / k,
    T_j = k_t · clip((s_j V_j − k_e s_j ω_m + k_e δω)/R, ±I_lim) + τ_c,

is nondecreasing in s_j V_j and inverted in closed form.

Dynamic part. The tines hang on a compliant mount of stiffness k (and damping
c) in series with whatever they press, so no contact is stiffer than k. A
tip of apparent vertical mass m (from the arm's and rotors' inertia through
the Jacobian: m = 1/(uᵀ J M⁻¹ Jᵀ u), u vertical) meeting such a contact at
downward speed v, pushed by a constant F_s, peaks at

    F_peak ≤ F_s + √(F_s² + k m v²) + c v        (undamped spring, plus c v)

(at v = 0 a suddenly met contact still doubles F_s). Requiring F_peak ≤ F_L
(F_limit less the model margin) gives the force budget, with D = F_L − c v:

    F_s ≤ B(v) = (D² − k m v²) / (2 D),

F_L/2 at rest, shrinking with speed and negative (the motors must brake)
above √(k m)·v + c v ≈ F_L. v is the measured downward tip speed plus its
uncertainty (the joints' velocity margins through the Jacobian) plus what
gravity and the budget can add during the reaction latency (F_L/2m·t). A
budget below zero is met by lifting: the joints' shares are lowered toward
their fullest lift, the joint with the larger lifting authority first.

Requests within the budget pass unchanged; otherwise the pressing shares are
cut, in proportion to what each asked, down to zero, and then, if the budget
is negative, the lift is raised as far as the supply allows. Lifting
voltages are never weakened. What it does not cover: the current's
electrical transient after a command drops (L/R ≈ 0.3 ms), which the margin
absorbs, and a mount stiffer than configured (the clamp is only as true as
``contact_stiffness_n_per_m``). A non-finite input gives 0 V and sets
``non_finite`` (the caller must fault): it is never silently replaced. When
even the fullest lift cannot meet the budget, the clamp returns full lift and
counts the tick in ``saturated``; if that happens with the tip not moving
down (the rake's own weight over budget at rest) it also sets ``infeasible``,
which the caller must treat as a fault. Braking at full lift while moving
down is not a fault: 0 V would let the rake fall.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rakectl.config.settings import ClampSettings
from rakectl.core.motor_model import (
    MotorParams,
    joint_per_motor_rad,
    joint_resolution,
    reflected_inertia,
)
from rakectl.limits import FORCE_LIMIT_N


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

    @classmethod
    def of(cls, p: MotorParams, clamp: ClampSettings, dt_s: float) -> _Joint:
        return cls(p.torque_constant_nm_per_a, p.resistance_ohm, p.current_limit_a,
                   p.coulomb_friction_nm, p.gear_efficiency, joint_per_motor_rad(p),
                   p.supply_voltage_v, clamp.velocity_margin_counts * joint_resolution(p) / dt_s)

    def share_n(self, c: float, voltage_v: float, emf_v: float) -> float:
        """Worst-case downward force of this joint at ``voltage_v`` (< 0: it lifts at least
        that much); ``emf_v`` = k_e·(s·ω − δω)."""
        s = 1.0 if c >= 0.0 else -1.0
        limit_a = self.current_limit_a  # the drive limits both directions
        current_a = max(-limit_a, min(limit_a, (s * voltage_v - emf_v) / self.resistance_ohm))
        torque_nm = self.kt_nm_per_a * current_a + self.coulomb_nm
        if torque_nm >= 0.0:
            return abs(c) * torque_nm / (self.efficiency * self.joint_per_motor_rad)
        return abs(c) * torque_nm * self.efficiency / self.joint_per_motor_rad

    def voltage_for(self, c: float, share_n: float, emf_v: float) -> float:
        """Largest s·V whose share is ≤ ``share_n``, as a signed V (may exceed the supply;
        the caller clips)."""
        s = 1.0 if c >= 0.0 else -1.0
        if abs(c) < 1e-12:
            return s * self.supply_v if share_n >= 0.0 else -s * self.supply_v
        scale = self.joint_per_motor_rad / abs(c)
        torque_nm = (share_n * self.efficiency * scale if share_n >= 0.0
                     else share_n * scale / self.efficiency)
        current_a = (torque_nm - self.coulomb_nm) / self.kt_nm_per_a
        if current_a >= self.current_limit_a:
            return s * self.supply_v
        if current_a <= -self.current_limit_a * (1.0 - 1e-9):
            return -s * self.supply_v
        return s * (self.resistance_ohm * current_a + emf_v)


class VoltageClamp:
    """Bounds the two motor voltages each tick; see the module docstring."""

    __slots__ = ("_c_contact", "_g", "_half_length_m", "_inertia_0", "_k_contact",
                 "_latency_s", "_limit_n", "_mass_r", "_r", "_rake_mass_kg", "_theta",
                 "_v_measured_m_per_s", "_velocity_share", "budget_n", "clamped",
                 "gravity_down_n", "infeasible", "limit_n", "non_finite", "saturated",
                 "v_down_m_per_s", "worst_case_n")

    def __init__(self, clamp: ClampSettings, motor_r: MotorParams, motor_theta: MotorParams,
                 dt_s: float) -> None:
        if clamp.force_limit_n > FORCE_LIMIT_N:
            raise ValueError(f"clamp.force_limit_n may not exceed {FORCE_LIMIT_N:g} N")
        self._limit_n = clamp.force_limit_n * (1.0 - clamp.model_margin)
        self.limit_n = self._limit_n  # the bound on the worst case (limit less the margin)
        self._r = _Joint.of(motor_r, clamp, dt_s)
        self._theta = _Joint.of(motor_theta, clamp, dt_s)
        self._g = clamp.rake_mass_kg * clamp.gravity_m_per_s2
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._velocity_share = clamp.velocity_margin_share
        self._k_contact = clamp.contact_stiffness_n_per_m
        self._c_contact = clamp.contact_damping_ns_per_m
        self._latency_s = clamp.reaction_latency_s
        self._rake_mass_kg = clamp.rake_mass_kg
        self._mass_r = clamp.rake_mass_kg + reflected_inertia(motor_r)
        self._inertia_0 = (clamp.rake_mass_kg * clamp.rake_length_m ** 2 / 12.0
                           + clamp.platform_inertia_kgm2 + reflected_inertia(motor_theta))
        self.clamped = 0  # ticks on which a request was cut
        self.saturated = 0  # ticks on which even full lift could not meet the budget
        self.non_finite = False
        self.infeasible = False  # latched: the budget could not be met at rest at least once
        self.gravity_down_n = 0.0
        self.budget_n = 0.0  # this tick's allowed worst-case downward force
        self.v_down_m_per_s = 0.0  # the downward speed that budget allows for
        self._v_measured_m_per_s = 0.0
        self.worst_case_n = 0.0  # worst-case static downward force of the voltages returned

    def _emf_v(self, joint: _Joint, c: float, velocity: float) -> float:
        """k_e·(s·ω_m − δω): back-EMF seen toward the ground side, with the uncertainty."""
        s = 1.0 if c >= 0.0 else -1.0
        margin = joint.velocity_margin + self._velocity_share * abs(velocity)
        return joint.kt_nm_per_a * (s * velocity - margin) / joint.joint_per_motor_rad

    def tip_mass_kg(self, r_m: float, theta_rad: float) -> float:
        """Apparent mass of the tip along the vertical, 1/(uᵀ J M⁻¹ Jᵀ u)."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        com_m = r_m - self._half_length_m
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        return 1.0 / (sin_t * sin_t / self._mass_r + (r_m * cos_t) ** 2 / inertia)

    def dynamic_budget_n(self, r_m: float, theta_rad: float, r_vel_m_per_s: float,
                         theta_vel_rad_per_s: float) -> float:
        """B(v): the worst-case downward force allowed at this measured motion."""
        return self._budget_n(r_m, math.sin(theta_rad), math.cos(theta_rad), r_vel_m_per_s,
                              theta_vel_rad_per_s)

    def _budget_n(self, r_m: float, sin_t: float, cos_t: float, r_vel_m_per_s: float,
                  theta_vel_rad_per_s: float) -> float:
        r_cos_t = r_m * cos_t
        share = self._velocity_share
        uncertainty = (abs(sin_t) * (self._r.velocity_margin + share * abs(r_vel_m_per_s))
                       + abs(r_cos_t) * (self._theta.velocity_margin
                                         + share * abs(theta_vel_rad_per_s)))
        com_m = r_m - self._half_length_m
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        mass_kg = 1.0 / (sin_t * sin_t / self._mass_r + r_cos_t * r_cos_t / inertia)
        self._v_measured_m_per_s = sin_t * r_vel_m_per_s + r_cos_t * theta_vel_rad_per_s
        v_m_per_s = (self._v_measured_m_per_s + uncertainty
                     + 0.5 * self._limit_n / mass_kg * self._latency_s)
        v_m_per_s = v_m_per_s if v_m_per_s > 0.0 else 0.0
        self.v_down_m_per_s = v_m_per_s
        d_n = self._limit_n - self._c_contact * v_m_per_s
        if d_n <= 0.0:
            return -math.inf
        return (d_n * d_n - self._k_contact * mass_kg * v_m_per_s * v_m_per_s) / (2.0 * d_n)

    def apply(self, r_m: float, theta_rad: float, r_vel_m_per_s: float,
              theta_vel_rad_per_s: float, voltage_r_v: float, voltage_theta_v: float
              ) -> tuple[float, float]:
        """The voltages to send: the request, cut where it could press down too hard."""
        total = (r_m + theta_rad + r_vel_m_per_s + theta_vel_rad_per_s + voltage_r_v
                 + voltage_theta_v)
        if not math.isfinite(total) or r_m <= 0.0:  # one check: inf/nan anywhere poisons the sum
            self.non_finite = True
            return 0.0, 0.0
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        c_r, c_theta = sin_t, cos_t / r_m
        self.gravity_down_n = self._g * (sin_t * sin_t + c_theta * (r_m - self._half_length_m)
                                         * cos_t)
        emf_r = self._emf_v(self._r, c_r, r_vel_m_per_s)
        emf_theta = self._emf_v(self._theta, c_theta, theta_vel_rad_per_s)
        voltage_r_v = max(-self._r.supply_v, min(self._r.supply_v, voltage_r_v))
        voltage_theta_v = max(-self._theta.supply_v, min(self._theta.supply_v, voltage_theta_v))
        share_r = self._r.share_n(c_r, voltage_r_v, emf_r)
        share_theta = self._theta.share_n(c_theta, voltage_theta_v, emf_theta)
        self.budget_n = self._budget_n(r_m, sin_t, cos_t, r_vel_m_per_s, theta_vel_rad_per_s)
        target_n = self.budget_n - self.gravity_down_n  # what the motors may add
        if share_r + share_theta <= target_n:
            self.worst_case_n = self.gravity_down_n + share_r + share_theta
            return voltage_r_v, voltage_theta_v
        self.clamped += 1
        want_r, want_theta = self._shares_within(target_n, (share_r, share_theta), (
            self._r.share_n(c_r, -math.copysign(self._r.supply_v, c_r or 1.0), emf_r),
            self._theta.share_n(c_theta, -math.copysign(self._theta.supply_v, c_theta or 1.0),
                                emf_theta)))
        voltage_r_v = self._cut(self._r, c_r, voltage_r_v, want_r, emf_r)
        voltage_theta_v = self._cut(self._theta, c_theta, voltage_theta_v, want_theta,
                                    emf_theta)
        self.worst_case_n = (self.gravity_down_n + self._r.share_n(c_r, voltage_r_v, emf_r)
                             + self._theta.share_n(c_theta, voltage_theta_v, emf_theta))
        if self.worst_case_n > self.budget_n + 1e-9 * self._limit_n:
            self.saturated += 1
            if self._v_measured_m_per_s <= 0.0:  # not braking a descent: at rest, or rising
                self.infeasible = True
        return voltage_r_v, voltage_theta_v

    @staticmethod
    def _shares_within(target_n: float, asked: tuple[float, float],
                       fullest_lift: tuple[float, float]) -> tuple[float, float]:
        """Shares whose sum is ``target_n`` (or as low as the supply allows), each between
        its fullest lift and what was asked: pressing is cut first, in proportion to what
        each joint asked; then the joint with more lift left gives it first."""
        floors = [max(lo, 0.0) for lo in fullest_lift]
        pressing = [max(q - f, 0.0) for q, f in zip(asked, floors, strict=True)]
        over_n = sum(asked) - target_n  # > 0
        if over_n <= sum(pressing):
            scale = over_n / sum(pressing)
            return asked[0] - pressing[0] * scale, asked[1] - pressing[1] * scale
        want = [q - p for q, p in zip(asked, pressing, strict=True)]
        need_n = sum(want) - target_n  # still over
        order = (0, 1) if want[0] - fullest_lift[0] >= want[1] - fullest_lift[1] else (1, 0)
        for j in order:
            cut_n = min(need_n, max(want[j] - fullest_lift[j], 0.0))
            want[j] -= cut_n
            need_n -= cut_n
        return want[0], want[1]

    @staticmethod
    def _cut(joint: _Joint, c: float, voltage_v: float, share_n: float, emf_v: float) -> float:
        bound_v = joint.voltage_for(c, share_n, emf_v)
        s = 1.0 if c >= 0.0 else -1.0
        limited = min(s * voltage_v, s * bound_v)  # only ever toward lifting
        return max(-joint.supply_v, min(joint.supply_v, s * limited))
