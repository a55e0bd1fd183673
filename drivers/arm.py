"""Rigid-body dynamics of the r-θ rake arm in its vertical plane (pure model):
:class:`ArmPlant`; the contact it is handed, the state it is put in and the drives'
report it gives are the types of :mod:`drivers.arm_types`.

With the arm's mass matrix, gravity and notation from :mod:`drivers.mechanics`
(q = (r, θ), momenta p_r = M_r ṙ and p_θ = M_θ θ̇), the equations of motion are::

    ṗ_θ = (1 − β) m g s cos θ + Q_θ
    ṗ_r = (1 − β) m g sin θ + m' s θ̇² + Q_r

Q holds the motor loads (drivers.motor), joint damping, hard stops at the
Workspace limits and the tip contact force mapped through Jᵀ by
``rakectl.core.kinematics.joint_loads``.

Integration: symplectic Euler, p first from q_n, then q from p_{n+1}. Because
∂H/∂r depends on p_θ only and ∂H/∂θ on neither momentum, this is explicit and
exactly symplectic: the energy error is bounded (≈ h/2 × the power exchanged
between kinetic and potential energy) and does not drift. Friction (motor
Coulomb plus gear efficiency) is resolved implicitly as stick-slip, and the
hard stops as a linearly implicit spring-damper that only pushes back into the
workspace, so both are unconditionally stable. The currents are integrated
exactly per substep (drivers.motor), so L/R does not limit the substep either.

What stays explicit is the dissipation of the drives and joints (checked at
construction: h·c/M < 0.1) and the contact, which the ground computes from
the tip's state at the start of each substep. With M_tip the tip's apparent
mass along the contact direction (:func:`drivers.mechanics.tip_apparent_masses_kg`,
down to ≈1.7 kg with the defaults), a contact of stiffness K and damping slope
c is stable while h·√(K/M_tip) < 2 and h·c/M_tip < 2. The soil bounds its drag's
damping slope at c_max = 2·10⁴ N·s/m (drivers.soil), so at the default substep
of 50 µs h·c/M_tip ≤ 0.6, and a stone's 10⁷ N/m penalty spring is resolved with
h·ω ≈ 0.12. (Without that bound the drag −H·tanh(v/v_s) of a deep cut has a
slope H/v_s up to ≈1.3·10⁵ N·s/m and makes the tip chatter at 0.1 ms.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.arm_types import ArmState, ContactModel, Measurement
from drivers.mechanics import ArmParams, counterweight_mass_kg, joint_masses, unbalanced_weight_n
from drivers.motor import Bridge, MotorDrive, MotorParams, stick_slip_velocity, substeps_in
from drivers.mount import MAX_PARTS, MAX_SLIDE_M, TineMount
from rakectl.core import kinematics
from rakectl.core.kinematics import Workspace
from rakectl.errors import ConfigError, NonFiniteError

__all__ = ["ArmState", "ContactModel", "Measurement"]  # re-exported from drivers.arm_types

DEFAULT_SUBSTEP_S = 5e-5  # set by the contact; see the module docstring
MAX_EXPLICIT_DAMPING = 0.1  # largest allowed h·c/M of an explicitly integrated damper


@dataclass(frozen=True, slots=True)
class _HardStop:
    lower: float
    upper: float
    stiffness: float
    damping: float


def _joint_velocity(
    momentum: float, force: float, mass: float, position: float, stop: _HardStop,
    band: tuple[float, float], h: float,
) -> float:
    """Velocity at the end of a substep: stick-slip drive band, implicit one-sided stop."""
    upper_depth, lower_depth = position - stop.upper, position - stop.lower
    depth = upper_depth if upper_depth > 0.0 else min(lower_depth, 0.0)
    plus, minus = band
    if depth != 0.0:
        stiff, damp = stop.stiffness, stop.damping
        denom = mass + h * (damp + h * stiff)
        vel = stick_slip_velocity(momentum + h * (force - stiff * depth), h * plus, h * minus,
                                  denom)
        if (stiff * (depth + h * vel) + damp * vel) * depth >= 0.0:  # pushes back: accept
            return vel
    return stick_slip_velocity(momentum + h * force, h * plus, h * minus, mass)


class ArmPlant:
    """The arm, its two motors and drives, advanced in fixed substeps."""

    def __init__(
        self,
        arm: ArmParams,
        motor_r: MotorParams,
        motor_theta: MotorParams,
        workspace: Workspace,
        substep_s: float = DEFAULT_SUBSTEP_S,
        seed: int = 0,
    ) -> None:
        if not 0.0 < substep_s <= 1e-3:
            raise ConfigError(f"substep_s must be in (0, 1 ms], got {substep_s:g}")
        self.arm, self.workspace, self.substep_s = arm, workspace, substep_s
        self._drive_r = MotorDrive(motor_r, substep_s)
        self._drive_theta = MotorDrive(motor_theta, substep_s)
        self._mass_r, _ = joint_masses(arm, motor_r, motor_theta, 0.0)
        self._moving_kg = arm.rake_mass_kg + counterweight_mass_kg(arm)
        self._weight_n = unbalanced_weight_n(arm)
        self._inertia_theta_0 = joint_masses(arm, motor_r, motor_theta, arm.rake_length_m / 2)[1]
        self._stop_r = _HardStop(workspace.r_min_m, workspace.r_max_m,
                                 arm.stop_stiffness_r_n_per_m, arm.stop_damping_r_ns_per_m)
        self._stop_theta = _HardStop(workspace.theta_min_rad, workspace.theta_max_rad,
                                     arm.stop_stiffness_theta_nm_per_rad,
                                     arm.stop_damping_theta_nms_per_rad)
        self._check_explicit_damping()
        self._rng = np.random.default_rng(seed)
        self._bridge_r, self._bridge_theta = Bridge.DRIVEN, Bridge.DRIVEN
        self._time_s, self._last_tip_force_n, self._last_contact_loads = 0.0, (0.0, 0.0), (0.0, 0.0)
        self._tines = TineMount(arm.tine_mount_stiffness_n_per_m,
                                arm.tine_mount_damping_ns_per_m,
                                arm.tine_mount_side_stiffness_n_per_m,
                                arm.tine_mount_side_damping_ns_per_m, substep_s)
        self.set_state(ArmState(workspace.r_min_m, 0.0))

    def _check_explicit_damping(self) -> None:
        for name, damping, mass in (
            ("r", self._drive_r.emf_damping + self.arm.damping_r_ns_per_m, self._mass_r),
            ("theta", self._drive_theta.emf_damping + self.arm.damping_theta_nms_per_rad,
             self._inertia_theta_0),
        ):
            if self.substep_s * damping / mass > MAX_EXPLICIT_DAMPING:
                raise ConfigError(f"substep_s={self.substep_s:g} s is too long for the {name} "
                                  f"joint's damping ({damping:g}) on its mass ({mass:g})")

    # ------------------------------------------------------------------- state

    def set_state(self, state: ArmState) -> None:
        """Put the arm in a state; the drives' velocity estimates restart at zero."""
        self._r_m, self._theta_rad = state.r_m, state.theta_rad
        self._p_r = self._mass_r * state.r_vel_m_per_s
        self._p_theta = self._inertia_theta(state.r_m) * state.theta_vel_rad_per_s
        self._current_r_a, self._current_theta_a = state.current_r_a, state.current_theta_a
        self._counts_r = self._drive_r.counts(state.r_m)
        self._tines.reset()
        self._counts_theta = self._drive_theta.counts(state.theta_rad)
        self._measured = Measurement(
            self._counts_r * self._drive_r.resolution,
            self._counts_theta * self._drive_theta.resolution,
            0.0, 0.0, state.current_r_a, state.current_theta_a,
        )

    def set_pose_at_rest(self, r_m: float, theta_rad: float) -> None:
        self.set_state(ArmState(r_m, theta_rad))

    def set_bridges(self, r: Bridge, theta: Bridge) -> None:
        """Drive (DRIVEN) or disconnect (OPEN) each motor."""
        self._bridge_r, self._bridge_theta = r, theta

    def state(self) -> ArmState:
        return ArmState(self._r_m, self._theta_rad, self.r_vel_m_per_s,
                        self.theta_vel_rad_per_s, self._current_r_a, self._current_theta_a)

    @property
    def time_s(self) -> float:
        return self._time_s

    @property
    def r_m(self) -> float:
        return self._r_m

    @property
    def theta_rad(self) -> float:
        return self._theta_rad

    @property
    def r_vel_m_per_s(self) -> float:
        return self._p_r / self._mass_r

    @property
    def theta_vel_rad_per_s(self) -> float:
        return self._p_theta / self._inertia_theta(self._r_m)

    @property
    def current_r_a(self) -> float:
        return self._current_r_a

    @property
    def current_theta_a(self) -> float:
        return self._current_theta_a

    @property
    def last_tip_force_n(self) -> tuple[float, float]:
        """Force on the tip by the ground in the last substep: (reach, height) in N."""
        return self._last_tip_force_n

    @property
    def last_contact_joint_loads(self) -> tuple[float, float]:
        """That force as joint loads Jᵀ F: (F_r in N, τ_θ in N·m)."""
        return self._last_contact_loads

    def tip_m(self) -> tuple[float, float]:
        """True tip (reach_m, height_m) of the arm, before the tine mount's compression."""
        return kinematics.forward(self.workspace, self._r_m, self._theta_rad)

    @property
    def mount_m(self) -> float:
        """Compression of the tine mount (> 0: tines pushed up)."""
        return self._tines.compression_m

    @property
    def mount_offset_m(self) -> float:
        """Sideways offset of the tines on their mount (> 0: away from the robot)."""
        return self._tines.offset_m

    def tine_m(self) -> tuple[float, float]:
        """Where the tines are: the tip moved by the mount's offset and compression."""
        reach_m, height_m = self.tip_m()
        return reach_m + self._tines.offset_m, height_m + self._tines.compression_m

    def tip_vel_m_per_s(self) -> tuple[float, float]:
        return kinematics.tip_velocity(self._r_m, self._theta_rad, self.r_vel_m_per_s,
                                       self.theta_vel_rad_per_s)

    def mechanical_energy_j(self) -> float:
        """Kinetic (rake, platform, reflected rotors) plus gravitational energy."""
        kinetic_j = 0.5 * (self._p_r**2 / self._mass_r
                           + self._p_theta**2 / self._inertia_theta(self._r_m))
        com_m = self._r_m - 0.5 * self.arm.rake_length_m
        height_m = self.workspace.pivot_height_m - com_m * math.sin(self._theta_rad)
        return kinetic_j + unbalanced_weight_n(self.arm) * height_m

    def measure(self) -> Measurement:
        """The drives' report, sampled at the end of the last step."""
        return self._measured

    # ------------------------------------------------------------------- dynamics

    def _inertia_theta(self, r_m: float) -> float:
        com_m = r_m - 0.5 * self.arm.rake_length_m
        return self._inertia_theta_0 + self._moving_kg * com_m * com_m

    def step(
        self, voltage_r_v: float, voltage_theta_v: float, contact: ContactModel, dt_s: float
    ) -> None:
        """Advance dt_s (a whole number of substeps) at constant voltage commands."""
        if not (math.isfinite(voltage_r_v) and math.isfinite(voltage_theta_v)):
            raise NonFiniteError(f"voltages must be finite, got {voltage_r_v}, {voltage_theta_v}")
        for _ in range(substeps_in(dt_s, self.substep_s)):
            self._substep(voltage_r_v, voltage_theta_v, contact)
        self._time_s += dt_s
        self._sample(dt_s)

    def _contact_loads(self, contact: ContactModel, vel_r: float, vel_theta: float) -> tuple[
        float, float
    ]:
        r_m, theta_rad = self._r_m, self._theta_rad
        reach_m, height_m = kinematics.forward(self.workspace, r_m, theta_rad)
        reach_vel, height_vel = kinematics.tip_velocity(r_m, theta_rad, vel_r, vel_theta)
        laws = getattr(contact, "vertical_laws", None)
        transmitted = getattr(contact, "transmitted", None)
        ground = getattr(contact, "ground", contact)
        lifted = getattr(ground, "lifted", None)
        tines = self._tines
        if tines.sideways and transmitted is not None and hasattr(ground, "normal_laws"):
            return self._mounted_loads(contact, transmitted, ground, reach_m, height_m,
                                       reach_vel, height_vel)
        mount_n = -1.0  # < 0: rigid tines
        if tines.vertical and laws is not None and transmitted is not None:
            # every law the tines could meet down to the mount fully extended (the lowest
            # they can reach), so a relaxing mount never carries them unseen into the ground
            compression_m = tines._vertical(
                laws(reach_m, height_m, height_m + tines.compression_m, self.substep_s,
                     reach_vel), height_m,
                height_vel)
            tines.hooked_on = -1
            if hasattr(ground, "bottom_laws"):  # under an object: its bottom extends it
                compression_m = tines.hooked(ground, reach_m, height_m, height_vel,
                                             compression_m)
            rate_m_per_s = (compression_m - tines.compression_m) / self.substep_s
            mount_n = tines.vertical_n(tines.k_v * compression_m + tines.c_v * rate_m_per_s)
            height_vel += rate_m_per_s
            height_m += compression_m
            tines.compression_m = compression_m
        force = contact.step(reach_m, height_m, reach_vel, height_vel, self.substep_s)
        if not math.isfinite(force[0] + force[1]):
            raise NonFiniteError(f"contact force must be finite, got {force}")
        if transmitted is not None and tines.vertical and laws is not None:
            # massless tines: the arm feels what the mount carries, and the ground gets it
            # too (where the tines rest on a surface the soil's own law reads 0 there); an
            # object's bottom they are at holds what pushes them up: the ground below and
            # the mount's pull (TineMount.under)
            under = tines.under
            if under >= 0 and lifted is not None:  # at a bottom: bottom_laws, so a Ground
                lifted(under, mount_n)
            if tines.hooked_on < 0:
                transmitted(mount_n)
            force = (force[0], mount_n)
        self._last_tip_force_n = force
        self._last_contact_loads = kinematics.joint_loads(r_m, theta_rad, force[0], force[1])
        return self._last_contact_loads

    def _mounted_loads(self, contact: ContactModel, transmitted: Any, ground: Any,
                       reach_m: float, height_m: float, reach_vel: float, height_vel: float
                       ) -> tuple[float, float]:
        """The mount that gives sideways too (drivers.mount): the ground is met where the
        tines are, and the arm feels what the mount carries both ways."""
        tines, h = self._tines, self.substep_s
        tines.step_s = h
        e, d = tines.solve(ground, reach_m, height_m, reach_vel, height_vel)
        slide_m = max(abs(e - tines.offset_m), abs(d - tines.compression_m))
        parts = min(MAX_PARTS, math.ceil(slide_m / MAX_SLIDE_M)) if slide_m > MAX_SLIDE_M else 1
        tines.step_s = h / parts
        side_sum = down_sum = 0.0
        for k in range(parts):
            at_reach, at_height = reach_m + k * tines.step_s * reach_vel, \
                height_m + k * tines.step_s * height_vel
            if parts > 1:
                e, d = tines.solve(ground, at_reach, at_height, reach_vel, height_vel)
            solved_d = d
            d = tines.hooked(ground, at_reach + e, at_height, height_vel, d)
            if tines.under >= 0 and d != solved_d:  # a bottom holds them: balance e there
                e = tines.rebalanced(ground, at_reach, at_height, reach_vel, height_vel, e, d)
            tine_vel = (reach_vel + (e - tines.offset_m) / tines.step_s,
                        height_vel + (d - tines.compression_m) / tines.step_s)
            side_n, down_n = tines.commit(e, d, reach_vel)
            force = contact.step(at_reach + e, at_height + d, tine_vel[0], tine_vel[1],
                                 tines.step_s)
            if not math.isfinite(force[0] + force[1] + side_n + down_n):
                raise NonFiniteError(f"contact force must be finite, got {force}")
            under = tines.under
            if under >= 0:  # at an object's bottom: it holds what pushes the tines up
                ground.lifted(under, down_n)
            if tines.hooked_on < 0 and tines.vertical:
                transmitted(down_n)
            side_sum += side_n
            down_sum += down_n if tines.vertical else force[1]
        tines.step_s = h
        force = (side_sum / parts, down_sum / parts)  # the arm feels the substep's mean
        r_m, theta_rad = self._r_m, self._theta_rad
        self._last_tip_force_n = force
        self._last_contact_loads = kinematics.joint_loads(r_m, theta_rad, force[0], force[1])
        return self._last_contact_loads

    def _substep(self, voltage_r_v: float, voltage_theta_v: float, contact: ContactModel) -> None:
        h, arm, r_m, theta_rad = self.substep_s, self.arm, self._r_m, self._theta_rad
        inertia_theta = self._inertia_theta(r_m)
        vel_r, vel_theta = self._p_r / self._mass_r, self._p_theta / inertia_theta
        load_r, load_theta = self._contact_loads(contact, vel_r, vel_theta)
        self._current_r_a, mean_r_a = self._drive_r.currents(
            self._current_r_a, voltage_r_v, vel_r, self._bridge_r)
        self._current_theta_a, mean_theta_a = self._drive_theta.currents(
            self._current_theta_a, voltage_theta_v, vel_theta, self._bridge_theta)
        com_m, weight_n = r_m - 0.5 * arm.rake_length_m, self._weight_n
        force_theta = (weight_n * com_m * math.cos(theta_rad) + load_theta
                       - arm.damping_theta_nms_per_rad * vel_theta)
        band = self._drive_theta.load_band(mean_theta_a, vel_theta)
        vel_theta = _joint_velocity(self._p_theta, force_theta, inertia_theta, theta_rad,
                                    self._stop_theta, band, h)
        force_r = (weight_n * math.sin(theta_rad) + load_r - arm.damping_r_ns_per_m * vel_r
                   + self._moving_kg * com_m * vel_theta * vel_theta)  # centrifugal: p_θ new
        band = self._drive_r.load_band(mean_r_a, vel_r)
        vel_r = _joint_velocity(self._p_r, force_r, self._mass_r, r_m, self._stop_r, band, h)
        self._p_theta, self._p_r = inertia_theta * vel_theta, self._mass_r * vel_r
        self._r_m, self._theta_rad = r_m + h * vel_r, theta_rad + h * vel_theta

    def _sample(self, dt_s: float) -> None:
        counts_r = self._drive_r.counts(self._r_m)
        counts_theta = self._drive_theta.counts(self._theta_rad)
        res_r, res_theta = self._drive_r.resolution, self._drive_theta.resolution
        noise = self._rng.standard_normal(2)
        self._measured = Measurement(
            counts_r * res_r,
            counts_theta * res_theta,
            (counts_r - self._counts_r) * res_r / dt_s,
            (counts_theta - self._counts_theta) * res_theta / dt_s,
            self._current_r_a + self._drive_r.params.current_noise_a * float(noise[0]),
            self._current_theta_a + self._drive_theta.params.current_noise_a * float(noise[1]),
        )
        self._counts_r, self._counts_theta = counts_r, counts_theta
