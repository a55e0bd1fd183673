"""The full rake as a plant for offline simulation.

The chain of the real robot, in simulated time: the vertical reference x_ref
from the impedance controller and the trajectory's reach go through inverse
kinematics to joint references; the joint position loops (rakectl) turn them
into motor voltages; the motors, the arm and the ground (drivers/) respond;
the encoders' positions, through forward kinematics, give the measured depth
the estimator sees. The ground truth (true tip forces, mine activation) is
what the safety claims are checked against.
"""

from __future__ import annotations

from drivers.arm import ArmPlant
from drivers.objects import Contact, Ground, GroundTruth
from rakectl import kinematics
from rakectl.joint_control import JointPositionLoop, PidGains
from rakectl.scenario import Scenario
from rakectl.settings import JointLoopSettings

# The telemetry's `contact` column: 0 none, 1 soil, 2 stone, 3 root, 4 mine.
CONTACT_CODE = {kind: float(code) for code, kind in enumerate(Contact)}
# Before t = 0 the loops hold the start pose this long, as an armed robot would.
SETTLE_S = 1.0


def workspace_of(settings: Scenario) -> kinematics.Workspace:
    g = settings.geometry
    return kinematics.Workspace(g.pivot_height_m, g.r_min_m, g.r_max_m, g.theta_min_rad,
                                g.theta_max_rad)


def _gains(loop: JointLoopSettings, voltage_limit_v: float) -> PidGains:
    return PidGains(loop.kp_v_per_unit, loop.ki_v_per_unit_s, loop.kd_v_s_per_unit,
                    loop.kff_v_s_per_unit, voltage_limit_v)


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


class RakePlant:
    """Joint loops + motors + arm + ground, stepped once per control tick."""

    columns: tuple[str, ...] = (
        "reach_ref_m", "r_ref_m", "theta_ref_rad", "r_m", "theta_rad", "voltage_r_v",
        "voltage_theta_v", "current_r_a", "current_theta_a", "tip_reach_m", "tip_depth_m",
        "interface_depth_m", "f_true_z_n", "f_true_x_n", "contact", "mine_activated",
    )

    def __init__(self, settings: Scenario, start_reach_m: float, start_depth_m: float) -> None:
        emu, dt_s = settings.emulator, 1.0 / settings.rate_hz
        self.dt_s = dt_s
        self.workspace = workspace_of(settings)
        self.arm = ArmPlant(emu.arm, emu.motor_r, emu.motor_theta, self.workspace,
                            emu.substep_s, emu.seed)
        self.ground = Ground(emu.ground, emu.seed)
        self.contact = PeakRecorder(self.ground)
        jc = settings.joint_control
        self.loop_r = JointPositionLoop(_gains(jc.r, jc.voltage_limit_v), dt_s)
        self.loop_theta = JointPositionLoop(_gains(jc.theta, jc.voltage_limit_v), dt_s)
        self.start = (start_reach_m, start_depth_m)
        self._q_ref = (0.0, 0.0)
        self._reach_ref_m = start_reach_m
        self.f_true_z_max_n = 0.0

    def _depth_m(self) -> float:
        m = self.arm.measure()
        return -kinematics.forward(self.workspace, m.r_m, m.theta_rad)[1]

    def reset(self) -> float:
        """Put the arm at rest at the start pose and let the loops take its weight."""
        self._q_ref = kinematics.inverse(self.workspace, self.start[0], -self.start[1])
        self.arm.set_pose_at_rest(*self._q_ref)
        self.loop_r.reset()
        self.loop_theta.reset()
        for _ in range(round(SETTLE_S / self.dt_s)):
            self._drive(self._q_ref, 0.0, 0.0)
        self.f_true_z_max_n = 0.0
        self.contact.peak_down_n = 0.0
        return self._depth_m()

    def _drive(self, q_ref: tuple[float, float], r_vel_ref: float, theta_vel_ref: float) -> None:
        m = self.arm.measure()
        voltage_r = self.loop_r.step(q_ref[0], r_vel_ref, m.r_m, m.r_vel_m_per_s)
        voltage_theta = self.loop_theta.step(q_ref[1], theta_vel_ref, m.theta_rad,
                                             m.theta_vel_rad_per_s)
        self.arm.step(voltage_r, voltage_theta, self.contact, self.dt_s)

    def step(self, reach_ref_m: float, x_ref_m: float) -> float:
        """Hold the tip reference (reach, depth x_ref) for one tick; return the measured depth."""
        q_ref = kinematics.inverse(self.workspace, reach_ref_m, -x_ref_m)
        r_vel = (q_ref[0] - self._q_ref[0]) / self.dt_s
        theta_vel = (q_ref[1] - self._q_ref[1]) / self.dt_s
        self._q_ref, self._reach_ref_m = q_ref, reach_ref_m
        self.contact.peak_down_n = 0.0
        self._drive(q_ref, r_vel, theta_vel)
        self.f_true_z_max_n = max(self.f_true_z_max_n, self.contact.peak_down_n)
        return self._depth_m()

    def truth(self) -> tuple[float, ...]:
        arm, truth = self.arm, self.ground.truth
        reach_m, height_m = arm.tip_m()
        return (
            self._reach_ref_m, self._q_ref[0], self._q_ref[1], arm.r_m, arm.theta_rad,
            self.loop_r.voltage_v, self.loop_theta.voltage_v, arm.current_r_a,
            arm.current_theta_a, reach_m, -height_m, -truth.interface_height_m,
            self.contact.peak_down_n, truth.force_drag_n, CONTACT_CODE[truth.contact],
            float(truth.mine_activated),
        )

    def summary(self) -> dict[str, float | int | bool]:
        mines = [body for body in self.ground.bodies if body.kind is Contact.MINE]
        return {
            "f_true_z_max_n": self.f_true_z_max_n,
            "mine_activated": self.ground.truth.mine_activated,
            "mine_plate_force_max_n": max((m.peak_down_n for m in mines), default=0.0),
            "mine_side_force_max_n": max((m.peak_side_n for m in mines), default=0.0),
        }

