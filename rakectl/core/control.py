"""The per-tick control law shared by the daemon and the offline simulation (pure).

    reference (reach, depth, contact) ──▶ impedance filter on the depth axis
        ──▶ inverse kinematics ──▶ joint position loops ──▶ voltages ──▶ clamp

``TipController.step`` takes the measured joints and the reference and returns
the clamped voltages; the requested (pre-clamp) ones stay readable for the
flight recorder. With ``descent.enforce`` the impedance's output passes the
descent limiter (:mod:`rakectl.core.ground_map`) before the joint loops: every
reference, whatever made it, is held at the ground map's floor. Nothing here
raises in normal operation: an unreachable reference holds the last reachable
one (counted); a non-finite number sets ``fault`` and gives 0 V, which the
caller must turn into a fault state.
"""

from __future__ import annotations

import math

from rakectl.config.settings import JointLoopSettings, Settings
from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.descent import SoilBound
from rakectl.core.ground_map import DescentLimiter, GroundMap
from rakectl.core.impedance import DelayForceEstimator, ImpedanceController, ImpedanceFilter
from rakectl.core.joint_control import JointPositionLoop, PidGains
from rakectl.errors import KinematicsError


def workspace_of(settings: Settings) -> kinematics.Workspace:
    g = settings.geometry
    return kinematics.Workspace(g.pivot_height_m, g.r_min_m, g.r_max_m, g.theta_min_rad,
                                g.theta_max_rad)


def build_impedance(settings: Settings) -> ImpedanceController:
    dt_s = 1.0 / settings.rate_hz
    imp, est = settings.impedance, settings.estimator
    return ImpedanceController(
        ImpedanceFilter(imp.mass_kg, imp.damping_ns_per_m, imp.stiffness_n_per_m, dt_s),
        DelayForceEstimator(est.environment_stiffness_n_per_m, est.delay_s, est.max_delay_s, dt_s),
        desired_force_n=settings.desired_force_n,
    )


def _gains(loop: JointLoopSettings, voltage_limit_v: float) -> PidGains:
    return PidGains(loop.kp_v_per_unit, loop.ki_v_per_unit_s, loop.kd_v_s_per_unit,
                    loop.kff_v_s_per_unit, voltage_limit_v)


def _unwind(loop: JointPositionLoop, integral_before_v: float, requested_v: float,
            applied_v: float) -> None:
    """Undo this tick's integration if it grew toward a voltage the clamp cut."""
    if (loop.integral_v - integral_before_v) * (requested_v - applied_v) > 0.0:
        loop.integral_v = integral_before_v


class JointServo:
    """Tip reference (reach, depth) → joint references → PID voltages (before the clamp)."""

    __slots__ = ("dt_s", "loop_r", "loop_theta", "q_ref", "unreachable", "workspace")

    def __init__(self, settings: Settings) -> None:
        self.dt_s = 1.0 / settings.rate_hz
        self.workspace = workspace_of(settings)
        jc = settings.joint_control
        self.loop_r = JointPositionLoop(_gains(jc.r, jc.voltage_limit_v), self.dt_s)
        self.loop_theta = JointPositionLoop(_gains(jc.theta, jc.voltage_limit_v), self.dt_s)
        self.q_ref = (0.0, 0.0)
        self.unreachable = 0  # ticks whose reference was outside the workspace

    def reset(self, r_m: float, theta_rad: float) -> None:
        self.q_ref = (r_m, theta_rad)
        self.loop_r.reset()
        self.loop_theta.reset()

    def step(self, reach_ref_m: float, depth_ref_m: float, r_m: float, theta_rad: float,
             r_vel_m_per_s: float, theta_vel_rad_per_s: float) -> tuple[float, float]:
        try:
            q_ref = kinematics.inverse(self.workspace, reach_ref_m, -depth_ref_m)
        except KinematicsError:  # hold the last reachable reference
            self.unreachable += 1
            q_ref = self.q_ref
        r_vel_ref = (q_ref[0] - self.q_ref[0]) / self.dt_s
        theta_vel_ref = (q_ref[1] - self.q_ref[1]) / self.dt_s
        self.q_ref = q_ref
        return (self.loop_r.step(q_ref[0], r_vel_ref, r_m, r_vel_m_per_s),
                self.loop_theta.step(q_ref[1], theta_vel_ref, theta_rad, theta_vel_rad_per_s))


def build_descent(settings: Settings) -> DescentLimiter | None:
    """The descent limiter over a ground map of the whole reach, or None when
    ``descent.enforce`` is off."""
    d = settings.descent
    if not d.enforce:
        return None
    bound = SoilBound.from_settings(d, settings.clamp.force_limit_n, settings.clamp.model_margin)
    survey = [(p.reach_m, p.height_m) for p in d.survey]
    return DescentLimiter(GroundMap(0.0, settings.geometry.r_max_m, d.ceiling_m,
                                    bound.first_step_m, d.side_reach_m, survey),
                          1.0 / settings.rate_hz)


class TipController:
    """Impedance control on the depth axis, joint loops and the clamp, one tick at a time."""

    __slots__ = ("_contact", "_contact_delay_s", "_lift_m_per_n", "_lift_margin_n", "clamp",
                 "depth_m", "descent", "fault", "impedance", "reach_m", "requested_v", "servo",
                 "x_ref_m")

    def __init__(self, settings: Settings, clamp: VoltageClamp | None = None) -> None:
        """``clamp`` replaces the configured clamp: for tests only (no setting reaches it)."""
        self.impedance = build_impedance(settings)
        self.servo = JointServo(settings)
        dt_s = 1.0 / settings.rate_hz
        self.clamp = clamp if clamp is not None else VoltageClamp(
            settings.clamp, settings.motors.r, settings.motors.theta, dt_s)
        self._contact_delay_s = settings.estimator.delay_s
        self._contact = False
        self.descent = build_descent(settings)
        self._lift_m_per_n = 1.0 / settings.clamp.contact_stiffness_n_per_m
        self._lift_margin_n = settings.descent.mount_force_margin_n
        self.impedance.estimator.set_delay(0.0)
        self.reach_m = self.depth_m = self.x_ref_m = 0.0
        self.requested_v = (0.0, 0.0)
        self.fault = ""

    @property
    def f_hat_n(self) -> float:
        return self.impedance.f_hat_n

    def tines_lift_m(self, mount_force_n: float) -> float:
        """The most the tines may stand above the tip: the mount compressed by the vertical
        force read from the currents, plus ``descent.mount_force_margin_n`` for that
        reading's lag (what the ground map and a survey mark take); a non-finite reading
        gives a non-finite lift (``max(0.0, nan)`` would read it as no force)."""
        force_n = 0.0 if mount_force_n < 0.0 else mount_force_n
        return (force_n + self._lift_margin_n) * self._lift_m_per_n

    def reset(self, r_m: float, theta_rad: float, keep_servo: bool = False) -> None:
        """Start from rest at the measured pose (on arming); ``keep_servo`` keeps the joint
        loops' integrators (which carry the arm's weight) and only restarts the impedance."""
        self.reach_m, height_m = kinematics.forward(self.servo.workspace, r_m, theta_rad)
        self.depth_m = -height_m
        self.impedance.reset(self.depth_m)
        if not keep_servo:
            self.servo.reset(r_m, theta_rad)
            if self.descent is not None:  # arming: the platform may have moved
                self.descent.map.reset()
        if self.descent is not None:
            self.descent.reset()
        self.fault = ""

    def set_contact(self, contact: bool) -> None:
        """α > 0 while the tip is meant to touch the soil, α = 0 in free space."""
        if contact is self._contact:
            return
        self._contact = contact
        if contact:
            self.impedance.estimator.enter_contact(self._contact_delay_s, self.depth_m)
        else:
            self.impedance.estimator.set_delay(0.0)

    def step(self, reach_ref_m: float, depth_ref_m: float, r_m: float, theta_rad: float,
             r_vel_m_per_s: float, theta_vel_rad_per_s: float, samples: int = 1, *,
             mount_force_n: float) -> tuple[float, float]:
        """Clamped voltages (r, θ) for this tick from the measured joints and the reference;
        ``samples``: the sampling instants (SYNCs) the joints advanced since the last tick
        (:attr:`rakectl.drive.health.Feedback.samples`), for the force estimate;
        ``mount_force_n``: the vertical force the tine mount carries, as last read from the
        currents (:attr:`rakectl.core.supervision.ForceSupervisor.f_current_n`), which
        holds the tines above the tip for the ground map."""
        if not (math.isfinite(r_m) and math.isfinite(theta_rad) and r_m > 0.0):
            self.fault = "non-finite or impossible joint feedback"
            return 0.0, 0.0
        self.reach_m = r_m * math.cos(theta_rad)
        self.depth_m = r_m * math.sin(theta_rad) - self.servo.workspace.pivot_height_m
        self.x_ref_m = self.impedance.step(depth_ref_m, self.depth_m, samples)
        if not (math.isfinite(reach_ref_m) and math.isfinite(self.x_ref_m)):  # else the
            self.fault = "non-finite tip reference"  # servo holds it as unreachable
            return 0.0, 0.0
        descent = self.descent
        if descent is not None:
            if not math.isfinite(mount_force_n):
                self.fault = "non-finite mount force for the ground map"
                return 0.0, 0.0
            descent.map.track(self.reach_m, self.tines_lift_m(mount_force_n) - self.depth_m)
            depth_rate = (r_vel_m_per_s * math.sin(theta_rad)
                          + r_m * math.cos(theta_rad) * theta_vel_rad_per_s)
            self.x_ref_m = descent.clip(self.x_ref_m, reach_ref_m, self.reach_m, self.depth_m,
                                        depth_rate)
        servo = self.servo
        integrals = (servo.loop_r.integral_v, servo.loop_theta.integral_v)
        requested = servo.step(reach_ref_m, self.x_ref_m, r_m, theta_rad, r_vel_m_per_s,
                               theta_vel_rad_per_s)
        self.requested_v = requested
        voltages = self.clamp.apply(r_m, theta_rad, r_vel_m_per_s, theta_vel_rad_per_s,
                                    requested[0], requested[1])
        # anti-windup through the clamp: an integrator does not grow toward a cut voltage
        _unwind(servo.loop_r, integrals[0], requested[0], voltages[0])
        _unwind(servo.loop_theta, integrals[1], requested[1], voltages[1])
        if self.clamp.non_finite:
            self.fault = "non-finite value reached the voltage clamp"
        return voltages
