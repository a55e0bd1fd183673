"""The full rake in simulated time: the daemon's controller against drivers/ physics.

The chain of the real robot: the reference goes through the same
:class:`rakectl.core.control.TipController` as in the daemon (impedance filter on
the depth axis, inverse kinematics, joint loops, voltage clamp); the voltages
reach the motors one tick later, as over the CAN bus (a drive applies the
RPDO of SYNC k at SYNC k+1); the motors, the arm and the ground (drivers/)
respond; the encoders' quantized positions are what the controller measures.
The ground truth (true tip forces, mine activation) is what the safety
claims are checked against.
"""

from __future__ import annotations

from drivers.arm import ArmPlant
from drivers.ground import Ground, GroundTruth
from drivers.objects import Contact
from drivers.soil import VerticalLaw
from rakectl.core import kinematics
from rakectl.core.clamp import VoltageClamp
from rakectl.core.control import TipController
from rakectl.core.descent import drag_limit_n
from rakectl.core.supervision import ForceLevel, ForceSupervisor
from rakectl.sim.plants import BASE_COLUMNS
from rakectl.sim.scenario import Scenario

# The telemetry's `contact` column: 0 none, 1 soil, 2 stone, 3 root, 4 mine.
CONTACT_CODE = {kind: float(code) for code, kind in enumerate(Contact)}
# Before t = 0 the controller holds the start pose this long, as an armed robot would.
SETTLE_S = 1.0

__all__ = ["BASE_COLUMNS", "CONTACT_CODE", "RakeLoop"]


class PeakRecorder:
    """Passes the ground through to the arm and keeps each tick's largest vertical force."""

    __slots__ = ("ground", "peak_down_n", "truth")

    def __init__(self, ground: Ground) -> None:
        self.ground = ground
        self.truth: GroundTruth = ground.truth
        self.peak_down_n = 0.0

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        force = self.ground.step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, dt_s)
        if self.truth.force_down_n > self.peak_down_n:
            self.peak_down_n = self.truth.force_down_n
        return force

    def vertical_laws(self, reach_m: float, height_m: float, face_height_m: float,
                      step_s: float, reach_vel_m_per_s: float = 0.0) -> list[VerticalLaw]:
        return self.ground.vertical_laws(reach_m, height_m, face_height_m, step_s,
                                         reach_vel_m_per_s)

    def transmitted(self, force_down_n: float) -> None:
        self.ground.transmitted(force_down_n)
        if force_down_n > self.peak_down_n:
            self.peak_down_n = force_down_n


class RakeLoop:
    """TipController + one-tick bus delay + motors, arm and ground."""

    columns: tuple[str, ...] = (
        "reach_ref_m", "r_ref_m", "theta_ref_rad", "r_m", "theta_rad", "voltage_r_req_v",
        "voltage_theta_req_v", "voltage_r_v", "voltage_theta_v", "current_r_a",
        "current_theta_a", "tip_reach_m", "tip_depth_m", "interface_depth_m", "f_true_z_n",
        "f_true_x_n", "contact", "mine_activated", "f_current_n", "f_reach_current_n",
        "force_level",
    )

    def __init__(self, settings: Scenario, start_reach_m: float, start_depth_m: float,
                 clamp: VoltageClamp | None = None) -> None:
        """``clamp`` replaces the configured clamp (tests only; see TipController)."""
        emu = settings.emulator
        self.dt_s = 1.0 / settings.rate_hz
        self.controller = TipController(settings, clamp)
        bound = settings.clamp
        self.supervisor = ForceSupervisor(
            settings.supervision, bound, settings.motors.r, settings.motors.theta, self.dt_s,
            drag_limit_n(settings.descent, bound.force_limit_n, bound.model_margin))
        self.workspace = self.controller.servo.workspace
        self.arm = ArmPlant(emu.arm, emu.motor_r, emu.motor_theta, self.workspace,
                            emu.substep_s, emu.seed)
        self.ground = Ground(emu.ground, emu.seed)
        self.contact = PeakRecorder(self.ground)
        self.start = (start_reach_m, start_depth_m)
        self._pending_v = (0.0, 0.0)  # sent this tick, applied from the next
        self._reach_ref_m = start_reach_m
        self._row: tuple[float, ...] = ()
        self.f_true_z_max_n = 0.0
        self.fault = ""

    def reset(self) -> None:
        """Put the arm at rest at the start pose and let the loops take its weight."""
        q = kinematics.inverse(self.workspace, self.start[0], -self.start[1])
        self.arm.set_pose_at_rest(*q)
        self.controller.reset(*q)
        self._pending_v = (0.0, 0.0)
        for _ in range(round(SETTLE_S / self.dt_s)):
            self._tick(self.start[0], self.start[1])
        m = self.arm.measure()  # the run starts from a clean estimator and filter
        self.controller.reset(m.r_m, m.theta_rad, keep_servo=True)
        self.f_true_z_max_n = 0.0

    def _tick(self, reach_ref_m: float, depth_ref_m: float) -> None:
        m = self.arm.measure()
        voltages = self.controller.step(reach_ref_m, depth_ref_m, m.r_m, m.theta_rad,
                                        m.r_vel_m_per_s, m.theta_vel_rad_per_s,
                                        mount_force_n=self.supervisor.f_current_n)
        self.contact.peak_down_n = 0.0
        self.arm.step(self._pending_v[0], self._pending_v[1], self.contact, self.dt_s)
        self._pending_v = voltages

    def step(self, reach_ref_m: float, depth_ref_m: float, contact: bool) -> None:
        c = self.controller
        c.set_contact(contact)
        x_c_m = c.impedance.filter.x_c_m
        self._reach_ref_m = reach_ref_m
        self._tick(reach_ref_m, depth_ref_m)
        if c.fault and not self.fault:
            self.fault = c.fault
        m = self.arm.measure()
        self.supervisor.step(c.f_hat_n, m.r_m, m.theta_rad, m.current_r_a, m.current_theta_a)
        self.f_true_z_max_n = max(self.f_true_z_max_n, self.contact.peak_down_n)
        self._row = (c.x_ref_m, c.depth_m, c.impedance.estimator.x_e_m, x_c_m, c.f_hat_n)

    def measured_tip(self) -> tuple[float, float]:
        return self.controller.reach_m, self.controller.depth_m

    @property
    def force_level(self) -> ForceLevel:
        return self.supervisor.level

    @property
    def force_estimate_n(self) -> float:
        """The conservative estimate the daemon gives an adaptive lane: max(F̂, current-based)."""
        return max(self.controller.f_hat_n, self.supervisor.f_current_n)

    @property
    def caution_n(self) -> float:
        return self.supervisor.caution_n

    def row(self) -> tuple[float, ...]:
        arm, truth, c = self.arm, self.ground.truth, self.controller
        reach_m, height_m = arm.tip_m()
        return (
            *self._row, self._reach_ref_m, c.servo.q_ref[0], c.servo.q_ref[1], arm.r_m,
            arm.theta_rad,
            c.requested_v[0], c.requested_v[1], self._pending_v[0], self._pending_v[1],
            arm.current_r_a, arm.current_theta_a, reach_m, -height_m,
            -truth.interface_height_m, self.contact.peak_down_n, truth.force_drag_n,
            CONTACT_CODE[truth.contact], float(truth.mine_activated),
            self.supervisor.f_current_n, self.supervisor.f_reach_current_n,
            float(self.supervisor.level),
        )

    def summary(self) -> dict[str, float | int | bool]:
        mines = [body for body in self.ground.bodies if body.kind is Contact.MINE]
        return {
            "f_true_z_max_n": self.f_true_z_max_n,
            "mine_activated": self.ground.truth.mine_activated,
            "mine_plate_force_max_n": max((m.peak_down_n for m in mines), default=0.0),
            "mine_side_force_max_n": max((m.peak_side_n for m in mines), default=0.0),
            "clamped_ticks": self.controller.clamp.clamped,
            "f_supervised_max_n": self.supervisor.f_max_n,
            "unreachable_ticks": self.controller.servo.unreachable,
        }
