"""The bound the voltage clamp checks a request against (pure): per joint, the worst-case
load a motor voltage can put on it; per sampled contact direction, the budget of the push
along it and the worst-case push of a pair of voltages.

Kept apart from :mod:`rakectl.core.clamp`, which decides what to send (the anchor and the
cut), so that the bound and its derivation below read on their own.

Contact directions. The ground pushes the tine along an outward normal n: up
from a top, sideways from a side, between them from a rounded edge, and down
from the bottom of an object the tines are under; the tine pushes it along
u = −n, in any direction. u(φ) = (−sin φ, −cos φ) in (reach, height), φ from
straight down, −90° away from the robot, 90° toward it, ±180° straight up (a
lift into an object's bottom).

What the tip can push with. The joint loads Q = (F_r, τ_θ) of the motors plus
the generalized gravity forces G act on the tip through J (rakectl.core.kinematics).
Each motor's load is bounded through its current: steady state i = (V − k_e ω_m)/R
within the drive's current limit, the measured speed taken with an uncertainty
δω toward the side that makes the load larger (a back-driven motor draws MORE
than V/R); through the transmission a joint pushes at most (k_t i + τ_c)/(η k)
(friction and efficiency both working the worst way: the stick band's far edge)
and pulls back at least (k_t i + τ_c)·η/k, k the joint motion per motor radian.
So for any weights a_j, the worst case of Σ a_j Q_j is a sum of one nondecreasing
function of s_j·V_j per joint (s_j = sign a_j, ``JointModel.load_n``), inverted in
closed form (``JointModel.voltage_for``).

Impact along u. The tines hang on a compliant mount, vertically k_v (and c_v),
in compression and in extension alike, horizontally k_h (and c_h), in series
with whatever they press, so along u no
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
√(k_u m_u)·v_u + τ k_u v_u ≥ F_L: with the defaults at r = 1.2 m, from 0.53 m/s
straight down or up (m_u ≈ 1.9 kg) and 0.22 m/s toward the robot (m_u ≈ 14 kg).

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
judged again each tick, before it can come back). The latency,
``clamp.reaction_latency_s``, is the longest a voltage can act after the
motion it was judged on: the drives hold it until the next command or, when
none comes (a stalled or dead controller, lost commands), until their
watchdog, so the watchdog plus one period (3 + 1 ms on the robot;
``rakectl.config.settings.held_command_gap`` names a configuration short of
it). Left out: a contact met within the latency slows the tip, and a motor
at a held voltage then pushes harder by its electrical damping times that
slowing; through the mount the slowing is at most v·(k t²/2 + c t)/m_u,
≈ 2.3 N of push at 4 ms at the fastest approach straight down, inside the
model margin (docs/safety.md). Since F_u(P̂) = |P| for a push
P, the budget also bounds a press held afterwards: F_L/2 in every direction at rest.

Every direction, sampled. Since F_u = (uᵀ w)/(uᵀ A u), with A = J M⁻¹ Jᵀ and
w = J M⁻¹ (Q + G) the tip's acceleration under the push, the condition F_u ≤ B_u
reads uᵀ w ≤ B_u·uᵀAu: linear in the joint loads, so its worst case over the
loads' uncertainty is at a corner of their box. The clamp checks it at N = 72
directions, 5° apart around the circle. Between two samples the left-hand side
of f_peak ≤ F_L can exceed its larger sampled value by at most 1.33 % over the
workspace and every push and speed (tests/core/test_clamp.py measures it
against 1440 directions);
the budgets are taken at F_L/(1 + ``SAMPLING_MARGIN``), 3 %, so the bound holds
in every direction, not only the sampled ones.
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

DIRECTIONS = 72  # contact directions sampled around the circle (every 5°)
SAMPLING_MARGIN = 0.03  # kept back for directions between the samples (1.33 % measured)


def unbalanced_weight_n(clamp: ClampSettings) -> float:
    """The rake's weight the motors hold: what the counterweight (if any) leaves of it."""
    share = clamp.counterbalance_share if clamp.counterweight_kg > 0.0 else 0.0
    return (1.0 - share) * clamp.rake_mass_kg * clamp.gravity_m_per_s2


@dataclass(frozen=True)
class JointModel:
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
    def of(cls, p: MotorParams, clamp: ClampSettings, dt_s: float) -> JointModel:
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


class ContactEnvelope:
    """This tick's budget in every sampled direction, and the worst case of a voltage pair
    against it; see the module docstring.

    :meth:`prepare` sets the tick's terms (``r_m``, ``emf``, ``weights``, ``bound``,
    ``budget``, ``budget_n``) from the measured motion; :meth:`excess` and
    :meth:`worst_push` judge voltages against them.
    """

    def __init__(self, clamp: ClampSettings, motor_r: MotorParams, motor_theta: MotorParams,
                 dt_s: float, directions: int) -> None:
        """``directions`` is 1 (straight down only) or a multiple of 4, checked by the
        clamp (straight down and up and both sideways among the samples)."""
        self.limit_n = clamp.force_limit_n * (1.0 - clamp.model_margin)
        self._sampled_limit_n = self.limit_n / (1.0 + SAMPLING_MARGIN) if directions > 1 \
            else self.limit_n
        self.r = JointModel.of(motor_r, clamp, dt_s)
        self.theta = JointModel.of(motor_theta, clamp, dt_s)
        share = clamp.counterbalance_share if clamp.counterweight_kg > 0.0 else 0.0
        self.weight_n = unbalanced_weight_n(clamp)
        balancing_kg = ((share * clamp.rake_mass_kg) ** 2 / clamp.counterweight_kg
                        if clamp.counterweight_kg > 0.0 else 0.0)
        self.half_length_m = 0.5 * clamp.rake_length_m
        self._velocity_share = clamp.velocity_margin_share
        self._latency_s = clamp.reaction_latency_s
        self._rake_mass_kg = clamp.rake_mass_kg + balancing_kg  # what moves along r
        self._mass_r = self._rake_mass_kg + reflected_inertia(motor_r)
        self._inertia_0 = (clamp.rake_mass_kg * clamp.rake_length_m ** 2 / 12.0
                           + clamp.platform_inertia_kgm2 + reflected_inertia(motor_theta))
        k_v, k_h = clamp.contact_stiffness_n_per_m, clamp.side_contact_stiffness_n_per_m
        tau_v_s, tau_h_s = clamp.contact_damping_ns_per_m / k_v, \
            clamp.side_contact_damping_ns_per_m / k_h
        angles = np.linspace(-math.pi, math.pi, directions, endpoint=False) \
            if directions > 1 else np.zeros(1)
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
        self.weights = np.zeros((directions, 4))
        self._pair = np.zeros(2)  # scratch: two numbers to multiply a (directions × 2) by
        self._ones = np.ones(2)
        self.bound = np.zeros(directions)
        self.budget = np.zeros(directions)
        self._gravity = np.zeros(directions)
        self._mass = np.zeros(directions)
        self.r_m = 1.0  # this tick's r
        self.emf = (0.0, 0.0, 0.0, 0.0)  # r for s = +1, s = −1; θ for s = +1, s = −1
        self._judged: dict[tuple[float, float], np.ndarray] = {}  # this tick's pairs
        self.budget_n = 0.0  # this tick's smallest budget over the directions

    def prepare(self, r_m: float, theta_rad: float, r_vel: float, theta_vel: float) -> bool:
        """This tick's weights and bounds in every direction; whether the tip moves toward
        any of them faster than its measurement's uncertainty."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        self.r_m = r_m
        self._judged.clear()
        com_m = r_m - self.half_length_m
        mass_r = self._mass_r
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        share = self._velocity_share
        margin_r = self.r.velocity_margin + share * abs(r_vel)
        margin_theta = self.theta.velocity_margin + share * abs(theta_vel)
        self.emf = (self.r.emf_v(1.0, r_vel, margin_r), self.r.emf_v(-1.0, r_vel, margin_r),
                    self.theta.emf_v(1.0, theta_vel, margin_theta),
                    self.theta.emf_v(-1.0, theta_vel, margin_theta))
        # g = Jᵀu = (sin(θ − φ), r cos(θ − φ)), one row per direction
        pair = self._pair
        pair[0], pair[1] = sin_t, cos_t
        g = self._rotations @ pair
        g[:, 1] *= r_m
        pair[0], pair[1] = 1.0 / mass_r, 1.0 / inertia
        c = g * pair  # uᵀw = uᵀ J M⁻¹ (Q + G) = c · (Q + G)
        weights = self.weights
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
        braking = d_n <= 0.0
        ratio = self._stiffness * mass * speed * speed
        np.divide(ratio, d_n, out=ratio, where=~braking)  # no division where it must brake
        budget = (d_n - ratio) * 0.5
        budget[braking] = -np.inf
        self.budget = budget
        self.budget_n = float(budget.min())
        # gravity's part of uᵀw is fixed this tick: it is folded into the bound
        pair[0], pair[1] = self.weight_n * sin_t, self.weight_n * com_m * cos_t
        self._gravity = c @ pair
        self.bound = budget * q - self._gravity
        return bool((measured > uncertain).any())

    def loads(self, voltage_r_v: float, voltage_theta_v: float) -> list[float]:
        """Worst-case joint loads (Q_r highest, lowest, Q_θ highest, lowest)."""
        emf = self.emf
        return [self.r.load_n(1.0, voltage_r_v, emf[0]),
                -self.r.load_n(-1.0, voltage_r_v, emf[1]),
                self.theta.load_n(1.0, voltage_theta_v, emf[2]),
                -self.theta.load_n(-1.0, voltage_theta_v, emf[3])]

    def _worst(self, voltage_r_v: float, voltage_theta_v: float) -> np.ndarray:
        """Worst case over the loads' box of uᵀ J M⁻¹ Q, in every direction; a pair judged
        again this tick (the cut's, then :meth:`worst_push`'s) is looked up."""
        key = (voltage_r_v, voltage_theta_v)
        worst = self._judged.get(key)
        if worst is None:
            worst = self._judged[key] = self.weights @ self.loads(voltage_r_v, voltage_theta_v)
        return worst

    def excess(self, voltage_r_v: float, voltage_theta_v: float) -> float:
        """How far the worst direction is over its bound, in m/s² (≤ 0: within all)."""
        return float((self._worst(voltage_r_v, voltage_theta_v) - self.bound).max())

    def worst_push(self, voltage_r_v: float, voltage_theta_v: float) -> tuple[float, float]:
        """The largest worst-case push F_u of these voltages (N) and the direction φ it is
        along (rad)."""
        push = self._mass * (self._worst(voltage_r_v, voltage_theta_v) + self._gravity)
        i = int(np.argmax(push))
        return float(push[i]), float(self.angles_rad[i])

    def tip_mass_kg(self, r_m: float, theta_rad: float, angle_rad: float = 0.0) -> float:
        """Apparent mass of the tip along u(φ), 1/(g_uᵀ M⁻¹ g_u); φ = 0 is straight down."""
        sin_t, cos_t = math.sin(theta_rad), math.cos(theta_rad)
        ux, uz = -math.sin(angle_rad), -math.cos(angle_rad)
        com_m = r_m - self.half_length_m
        inertia = self._inertia_0 + self._rake_mass_kg * com_m * com_m
        g_r, g_theta = cos_t * ux - sin_t * uz, -r_m * (sin_t * ux + cos_t * uz)
        return 1.0 / (g_r * g_r / self._mass_r + g_theta * g_theta / inertia)
