"""The voltage clamp: no voltage reaches the bus without passing here (pure).

It bounds each motor's voltage so that the worst-case STATIC vertical force
of the rake tip on the ground cannot exceed F_limit (90 N at most), whatever
the controller asked for and whatever the force estimator believes. It uses
only the measured joint positions and velocities and the configured models
(motors, transmissions, arm mass); nothing estimated.

Derivation. At rest the joint loads Q = (F_r, τ_θ) of the motors plus the
generalized gravity forces G balance the ground's force on the tip through
Jᵀ (rakectl.kinematics), so the tip presses on the ground with F = J⁻ᵀ(Q + G).
With θ below the horizontal, its downward component is

    F_down = sin θ · (F_r + G_r) + (cos θ / r) · (τ_θ + G_θ),
    G_r = m g sin θ,   G_θ = m g (r − L/2) cos θ.

Each motor's joint load is bounded through its current. Steady state
(L di/dt → 0): i = (V − k_e ω_m)/R, within the drive's current limit; a motor
back-driven against its voltage (ω_m opposite to V) draws MORE than V/R, so
the measured speed enters with an uncertainty δω toward the dangerous side.
Through the transmission, a joint can hold statically up to
(k_t i + τ_c)/(η k) in the direction it pushes (friction and efficiency both
working against the ground: the stick band's far edge), k the joint motion
per motor radian. With s_j = sign(c_j) the direction in which joint j presses
down (c_r = sin θ, c_θ = cos θ / r):

    F_j(V_j) = |c_j| · max(0, k_t · clip((s_j V_j − k_e s_j ω_m + k_e δω)/R, ±I_lim) + τ_c) / (η k)

is a worst-case bound of joint j's share, nondecreasing in s_j V_j, so the
constraint G_down + F_r(V_r) + F_θ(V_θ) ≤ (1 − margin) F_limit is met by a
bound on s_j V_j found in closed form. Requests within it pass unchanged;
otherwise the remaining budget is shared between the joints in proportion to
their requested shares, and each joint's voltage toward the ground is cut to
its share. Lifting voltages are never restricted (beyond the supply).

What it does not cover: dynamic forces (an arm moving into a rigid object at
speed: impact), which the force supervision and speed limits address, and
the current's electrical transient (L/R ≈ 0.3 ms) after a command drops,
which the margin absorbs. A non-finite input gives 0 V and sets
``non_finite`` (the caller must fault): it is never silently replaced. When
even the fullest lifting voltage cannot meet the bound (the rake's own weight
over budget, or a motor back-driven so fast that its braking current presses
down harder than the budget at the supply limit), the clamp returns that
best effort and sets ``infeasible``: the caller must treat it as a fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rakectl.motor_model import MotorParams, joint_per_motor_rad, joint_resolution
from rakectl.settings import ClampSettings


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
        """Worst-case downward force of this joint at ``voltage_v`` (``emf_v`` = k_e·(s·ω + δω))."""
        s = 1.0 if c >= 0.0 else -1.0
        limit_a = self.current_limit_a  # the drive limits both directions
        current_a = max(-limit_a, min(limit_a, (s * voltage_v - emf_v) / self.resistance_ohm))
        torque_nm = self.kt_nm_per_a * current_a + self.coulomb_nm
        if torque_nm <= 0.0:
            return 0.0
        return abs(c) * torque_nm / (self.efficiency * self.joint_per_motor_rad)

    def voltage_for(self, c: float, share_n: float, emf_v: float) -> float:
        """Largest s·V whose share is ≤ ``share_n`` (may be negative: lifting), as a signed V."""
        s = 1.0 if c >= 0.0 else -1.0
        if abs(c) < 1e-12:
            return s * self.supply_v
        torque_nm = share_n * self.efficiency * self.joint_per_motor_rad / abs(c)
        current_a = (torque_nm - self.coulomb_nm) / self.kt_nm_per_a
        if current_a >= self.current_limit_a:
            return s * self.supply_v
        return s * (self.resistance_ohm * current_a + emf_v)


class VoltageClamp:
    """Bounds the two motor voltages each tick; see the module docstring."""

    __slots__ = ("_g", "_half_length_m", "_limit_n", "_r", "_theta", "_velocity_share",
                 "clamped", "gravity_down_n", "infeasible", "limit_n", "non_finite",
                 "worst_case_n")

    def __init__(self, clamp: ClampSettings, motor_r: MotorParams, motor_theta: MotorParams,
                 dt_s: float) -> None:
        if clamp.force_limit_n > 90.0:
            raise ValueError("clamp.force_limit_n may not exceed 90 N")
        self._limit_n = clamp.force_limit_n * (1.0 - clamp.model_margin)
        self.limit_n = self._limit_n  # the bound on the worst case (limit less the margin)
        self._r = _Joint.of(motor_r, clamp, dt_s)
        self._theta = _Joint.of(motor_theta, clamp, dt_s)
        self._g = clamp.rake_mass_kg * clamp.gravity_m_per_s2
        self._half_length_m = 0.5 * clamp.rake_length_m
        self._velocity_share = clamp.velocity_margin_share
        self.clamped = 0  # ticks on which a request was cut
        self.non_finite = False
        self.infeasible = False  # latched: the bound could not be met at least once
        self.gravity_down_n = 0.0
        self.worst_case_n = 0.0  # worst-case static downward force of the voltages returned

    def _emf_v(self, joint: _Joint, c: float, velocity: float) -> float:
        """k_e·(s·ω_m + δω): back-EMF seen toward the ground side, with the uncertainty."""
        s = 1.0 if c >= 0.0 else -1.0
        margin = joint.velocity_margin + self._velocity_share * abs(velocity)
        return joint.kt_nm_per_a * (s * velocity - margin) / joint.joint_per_motor_rad

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
        budget_n = self._limit_n - self.gravity_down_n
        if budget_n < 0.0:
            self.infeasible = True
        if share_r + share_theta <= max(budget_n, 0.0):
            self.worst_case_n = self.gravity_down_n + share_r + share_theta
            return voltage_r_v, voltage_theta_v
        self.clamped += 1
        budget_n = max(budget_n, 0.0)
        total = share_r + share_theta  # > budget ≥ 0, so > 0
        voltage_r_v = self._cut(self._r, c_r, voltage_r_v, budget_n * share_r / total, emf_r)
        voltage_theta_v = self._cut(self._theta, c_theta, voltage_theta_v,
                                    budget_n * share_theta / total, emf_theta)
        self.worst_case_n = (self.gravity_down_n + self._r.share_n(c_r, voltage_r_v, emf_r)
                             + self._theta.share_n(c_theta, voltage_theta_v, emf_theta))
        if self.worst_case_n > self._limit_n * (1.0 + 1e-9):
            self.infeasible = True
        return voltage_r_v, voltage_theta_v

    @staticmethod
    def _cut(joint: _Joint, c: float, voltage_v: float, share_n: float, emf_v: float) -> float:
        bound_v = joint.voltage_for(c, share_n, emf_v)
        s = 1.0 if c >= 0.0 else -1.0
        limited = min(s * voltage_v, s * bound_v)  # only the pressing side is restricted
        return max(-joint.supply_v, min(joint.supply_v, s * limited))
