"""The tines' mount sideways, against hand-computed and independent references.

A stone's side met by the arm coasting along the reach (a mass meeting a
spring-damper, integrated here with RK4, not the emulator's code), a steady
drag through soil (the earthmoving equation by hand), a static press with a
known motor current, the mount's reading against the ground's own on a
rounded edge, and a rounded edge forcing descending tines sideways through
soil, which loads the object with the soil's cutting resistance.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from drivers.arm import ArmPlant, ArmState
from drivers.ground import Ground
from drivers.ground_params import BuriedObjects, GroundParams, MineParams, StoneParams
from drivers.mechanics import ArmParams, joint_masses, unbalanced_weight_n
from drivers.motor import R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, Bridge, joint_load_band
from drivers.mount import TineMount
from drivers.soil import VerticalLaw, cutting_force_n
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.core import kinematics
from rakectl.core.kinematics import Workspace
from rakectl.sim.rake_plant import PeakRecorder

WS = Workspace(pivot_height_m=0.6, r_min_m=0.35, r_max_m=1.6, theta_min_rad=-0.2,
               theta_max_rad=1.3)
ARM = ArmParams()
STEP_S = 1e-3
AIR = SoilParams(layers=(SoilLayer(stiffness_n_per_m=1.0, collapse_force_n=1e-3,
                                   cohesion_pa=0.0, unit_weight_n_per_m3=1.0),),
                 surface_slope=0.0, stiffness_rel_std=0.0, strength_rel_std=0.0,
                 lane_reach_max_m=2.0)


class _Sides(PeakRecorder):
    """The ground as the rake loop passes it; per substep the ground's own reading along
    the reach next to what the mount carried sideways."""

    def __init__(self, ground: Ground) -> None:
        super().__init__(ground)
        self.readings: list[float] = []

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        force = super().step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, dt_s)
        self.readings.append(force[0])
        return force


def _coast_into_a_side(arm: ArmParams, speed_m_per_s: float) -> tuple[float, float, float]:
    """θ = 0, r retracting at ``speed_m_per_s`` with its motor open, the tines 1 mm from a
    stone's far side at mid-height: (peak side force on the stone, the largest mount
    offset, the r joint's mass)."""
    r_m, theta_rad = 1.2, 0.0
    reach_m, height_m = kinematics.forward(WS, r_m, theta_rad)
    stone = StoneParams(reach_m - 0.001 - 0.05, -(height_m + 0.02), 0.1, 0.06, edge_radius_m=0.0)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,))), seed=0)
    ideal = dataclasses.replace(R_MOTOR_DEFAULT, gear_efficiency=1.0, coulomb_friction_nm=0.0,
                                viscous_friction_nms_per_rad=0.0)  # no friction to brake it
    arm = dataclasses.replace(arm, damping_r_ns_per_m=0.0)
    plant = ArmPlant(arm, ideal, THETA_MOTOR_DEFAULT, WS)
    plant.set_state(ArmState(r_m, theta_rad, -speed_m_per_s, 0.0))
    plant.set_bridges(Bridge.OPEN, Bridge.DRIVEN)  # r coasts; θ is held level
    recorder = PeakRecorder(ground)
    offset_m = 0.0
    for _ in range(300):
        plant.step(0.0, _servo(plant, r_m, theta_rad, 0.0, 0.0)[1], recorder, STEP_S)
        offset_m = max(offset_m, plant.mount_offset_m)
    mass_r = joint_masses(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, r_m)[0]
    return ground.bodies[0].peak_side_n, offset_m, mass_r


def _mass_meets_spring_damper(mass_kg: float, stiffness: float, damping: float,
                              speed_m_per_s: float, push_n: float = 0.0) -> float:
    """Peak force of a mass arriving on a spring-damper (RK4, 1 µs), pushed on by a
    constant ``push_n`` (< 0: held back, as gravity holds back a rise)."""
    h, x, v, peak = 1e-6, 0.0, speed_m_per_s, 0.0

    def accel(x: float, v: float) -> float:
        return (push_n - max(stiffness * x + damping * v, 0.0)) / mass_kg

    while True:
        k1x, k1v = v, accel(x, v)
        k2x, k2v = v + 0.5 * h * k1v, accel(x + 0.5 * h * k1x, v + 0.5 * h * k1v)
        k3x, k3v = v + 0.5 * h * k2v, accel(x + 0.5 * h * k2x, v + 0.5 * h * k2v)
        k4x, k4v = v + h * k3v, accel(x + h * k3x, v + h * k3v)
        x += h * (k1x + 2 * k2x + 2 * k3x + k4x) / 6
        v += h * (k1v + 2 * k2v + 2 * k3v + k4v) / 6
        peak = max(peak, stiffness * x + damping * v)
        if v < 0.0:
            return peak


@pytest.mark.parametrize("speed_m_per_s", [0.05, 0.2, 0.4])
def test_a_side_met_coasting_peaks_as_a_mass_on_the_mount(speed_m_per_s: float) -> None:
    """The arm coasting along the reach meets a stone's side (10⁷ N/m): the side force
    peaks as the r joint's mass meeting the mount's spring-damper, the stone's own
    stiffness in series (within 3 %); a rigid tine peaks far higher."""
    peak_n, offset_m, mass_kg = _coast_into_a_side(ARM, speed_m_per_s)
    k = 1.0 / (1.0 / ARM.tine_mount_side_stiffness_n_per_m + 1.0 / 1e7)
    expected = _mass_meets_spring_damper(mass_kg, k, ARM.tine_mount_side_damping_ns_per_m,
                                         speed_m_per_s)
    assert peak_n == pytest.approx(expected, rel=0.03)
    assert offset_m == pytest.approx(expected / ARM.tine_mount_side_stiffness_n_per_m, rel=0.05)
    rigid_n, _, _ = _coast_into_a_side(
        dataclasses.replace(ARM, tine_mount_side_stiffness_n_per_m=0.0), speed_m_per_s)
    assert rigid_n > 5.0 * peak_n


def _servo(plant: ArmPlant, r_ref: float, theta_ref: float, r_dot: float,
           theta_dot: float) -> tuple[float, float]:
    """Joint PD with velocity feed-forward on the true state: stiff enough to hold a path."""
    return (3e3 * (r_ref - plant.r_m) + 60.0 * (r_dot - plant.r_vel_m_per_s) + 16.0 * r_dot,
            3e3 * (theta_ref - plant.theta_rad) + 60.0 * (theta_dot - plant.theta_vel_rad_per_s)
            + 7.0 * theta_dot)


def test_a_steady_drag_deflects_the_mount_by_drag_over_stiffness() -> None:
    """Dragged at a steady 0.05 m/s through homogeneous soil at a 10 mm cut, the tines trail
    the arm by H/k_h, H from the earthmoving equation by hand, and the arm feels H."""
    layer = SoilLayer(stiffness_n_per_m=2e5, collapse_force_n=1e4, cohesion_pa=5e3,
                      damping_time_s=0.0)
    soil = SoilParams(layers=(layer,), surface_slope=0.0, stiffness_rel_std=0.0,
                      strength_rel_std=0.0, lane_reach_max_m=2.0)
    ground = Ground(GroundParams(soil=soil), seed=0)
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    reach_m, depth_m, speed = 1.3, 0.010, 0.05
    plant.set_state(ArmState(*kinematics.inverse(WS, reach_m, -depth_m)))
    recorder = _Sides(ground)
    for k in range(1500):
        reach = reach_m - speed * min(k, 1400) * STEP_S
        r, th = kinematics.inverse(WS, reach, -depth_m)
        moving = -speed if k < 1400 else 0.0
        plant.step(*_servo(plant, r, th, *_joint_rates(r, th, moving, 0.0)), recorder, STEP_S)
        if k == 1300:
            offset_m, side_n, reading_n = (plant.mount_offset_m, plant.last_tip_force_n[0],
                                           recorder.readings[-1])
    drag_n = cutting_force_n(layer, soil, depth_m)
    assert offset_m == pytest.approx(drag_n / ARM.tine_mount_side_stiffness_n_per_m, rel=0.03)
    assert side_n == pytest.approx(drag_n, rel=0.03)
    assert reading_n == pytest.approx(drag_n, rel=0.03)


def _joint_rates(r_m: float, theta_rad: float, reach_vel: float, height_vel: float
                 ) -> tuple[float, float]:
    j11, j12, j21, j22 = kinematics.jacobian(r_m, theta_rad)
    det = j11 * j22 - j12 * j21
    return ((j22 * reach_vel - j12 * height_vel) / det,
            (-j21 * reach_vel + j11 * height_vel) / det)


def test_a_static_side_press_is_the_motors_force_through_the_mount() -> None:
    """θ = 0, the r motor at a known stalled current presses the tines on a stone's side:
    the stone holds the motor's force (within its friction band) and the mount is
    offset by that force over its stiffness."""
    r_m, theta_rad = 1.2, 0.0
    reach_m, height_m = kinematics.forward(WS, r_m, theta_rad)
    stone = StoneParams(reach_m - 0.0005 - 0.05, -(height_m + 0.02), 0.1, 0.06,
                        edge_radius_m=0.0)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,))), seed=0)
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_state(ArmState(r_m, theta_rad))
    voltage_v = -0.6  # retract: push toward the robot, into the stone's far side
    recorder = PeakRecorder(ground)
    for _ in range(600):
        plant.step(voltage_v, _servo(plant, r_m, theta_rad, 0.0, 0.0)[1], recorder, STEP_S)
    current_a = voltage_v / R_MOTOR_DEFAULT.resistance_ohm
    band = sorted(joint_load_band(R_MOTOR_DEFAULT, current_a))
    side_n = ground.bodies[0].force_reach_n
    assert -band[1] - 1.0 <= side_n <= -band[0] + 1.0  # it holds what the motor pushes
    assert plant.mount_offset_m == pytest.approx(side_n / ARM.tine_mount_side_stiffness_n_per_m,
                                                 rel=0.02)


def test_on_a_rounded_edge_the_mount_carries_what_the_mine_reads() -> None:
    """Dragged at 0.1 m/s into a mine's rim 1.5 mm under its plate, motors open: on every
    substep the mine's own reading along its normal and what the mount carries agree."""
    r_m, theta_rad = 1.2, 0.2
    reach_m, height_m = kinematics.forward(WS, r_m, theta_rad)
    mine = MineParams(reach_m - 0.0005 - 0.04, -(height_m + 0.0015), 0.08, 0.05,
                      activation_force_n=1e4)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(mines=(mine,))), seed=0)
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    speed = 0.1
    plant.set_state(ArmState(r_m, theta_rad, *_joint_rates(r_m, theta_rad, -speed, 0.0)))
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    recorder = _Sides(ground)
    body = ground.bodies[0]
    pairs = []
    for _ in range(60):
        plant.step(0.0, 0.0, recorder, STEP_S)
        pairs.append((body.force_reach_n, body.force_up_n, *plant.last_tip_force_n))
    touching = [p for p in pairs if p[0] != 0.0 or p[1] != 0.0]
    assert touching, "the tines met the rim"
    for own_x, own_up, mount_x, mount_up in touching:
        assert mount_x == pytest.approx(own_x, rel=0.05, abs=0.5)
        assert mount_up == pytest.approx(own_up, rel=0.05, abs=0.5)
    assert max(math.hypot(p[0], p[1]) for p in touching) == pytest.approx(
        max(body.peak_side_n, body.peak_down_n), rel=0.5)


def test_tines_held_at_a_cells_edge_meet_a_rounded_edge_in_balance() -> None:
    """Held at a soil cell's edge (where the drag jumps and the solve cannot settle), tines
    2 µm inside a stone's rounded edge, the mount compressed 5 mm (25 N), the arm
    descending at 20 mm/s, take the
    compression of the backward-Euler balance along the vertical, computed by hand on
    the edge's normal, and the stone then reads (Body.touch) what the mount carries: not
    a penetration the mount never carried (20261125/2781: 141 N against 13 N), nor a
    speed nothing pushed the tines to (20261128 edge 7070: raised 0.5 mm in 50 µs, the
    mount's damping read 90.4 N)."""
    stone = StoneParams(reach_m=1.0, depth_m=0.01, width_m=0.05, thickness_m=0.07,
                        edge_radius_m=0.005)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,))), seed=0)
    rho, angle = 0.005, math.radians(40.0)  # a point on the far edge, 40° from the top
    centre_x, centre_z = 1.025 - rho, -0.01 - rho
    p0_m, d0_m, h_s, v_m_per_s = 2e-6, 5e-3, 50e-6, -0.02
    tine_x = centre_x + (rho - p0_m) * math.sin(angle)
    tine_z = centre_z + (rho - p0_m) * math.cos(angle)
    arm_x, arm_z = 1.02, tine_z - d0_m
    mount = TineMount(5000.0, 7.5, 5000.0, 7.5, h_s)
    mount.offset_m, mount.compression_m = tine_x - arm_x, d0_m
    ground.bodies[0].touching = True  # in it at the last reading
    [(index, law)] = ground.normal_laws(tine_x, tine_z, h_s)
    assert law.depth_m == pytest.approx(p0_m, abs=1e-12)
    assert law.n_up == pytest.approx(math.cos(angle))
    # by hand: k·d + c·(d − d0)/h = n_z·(K·p + B·ṗ), p = p0 − n_z·x, ṗ = −n_z·(v + x/h),
    # x = d − d0, the offset held (no motion along the reach)
    n_z, k_s, b_s = math.cos(angle), law.stiffness_n_per_m, law.damping_ns_per_m
    x_m = ((n_z * k_s * p0_m - n_z * n_z * b_s * v_m_per_s - 5000.0 * d0_m)
           / (5000.0 + 7.5 / h_s + n_z * n_z * (k_s + b_s / h_s)))
    d_m = mount._held(ground, arm_x, arm_z, 0.0, v_m_per_s, mount.offset_m)
    assert 0.0 < n_z * x_m < p0_m  # still in the edge: the law is linear there
    assert d_m == pytest.approx(d0_m + x_m, abs=1e-10)  # the edge's curvature over x: < 0.1 nm
    mount_n = 5000.0 * d_m + 7.5 * (d_m - d0_m) / h_s
    body = ground.bodies[index]
    assert body.touch(tine_x, arm_z + d_m, 0.0, v_m_per_s + (d_m - d0_m) / h_s, h_s)
    assert body.force_up_n == pytest.approx(mount_n, rel=1e-3)
    assert 10.0 < mount_n < 90.0  # a contact worth checking, met at a speed the mount allows


def _rise_into_a_bottom(speed_m_per_s: float) -> tuple[Ground, float, float]:
    """θ = 0, the arm rising at ``speed_m_per_s`` with its θ motor open and r held, the
    tines 2 µm under a stone's bottom: (the ground, the θ joint's mass at the tip, the
    weight's pull at the tip, < 0)."""
    r_m, theta_rad = 1.2, 0.0
    reach_m, height_m = kinematics.forward(WS, r_m, theta_rad)
    stone = StoneParams(reach_m, -(height_m + 2e-6) - 0.06, 0.1, 0.06)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,))), seed=0)
    ideal = dataclasses.replace(THETA_MOTOR_DEFAULT, gear_efficiency=1.0,
                                coulomb_friction_nm=0.0, viscous_friction_nms_per_rad=0.0)
    arm = dataclasses.replace(ARM, damping_theta_nms_per_rad=0.0)
    plant = ArmPlant(arm, R_MOTOR_DEFAULT, ideal, WS)
    plant.set_state(ArmState(r_m, theta_rad, 0.0, -speed_m_per_s / r_m))  # θ falls: tip up
    plant.set_bridges(Bridge.DRIVEN, Bridge.OPEN)
    recorder = PeakRecorder(ground)
    for _ in range(60):
        plant.step(_servo(plant, r_m, theta_rad, 0.0, 0.0)[0], 0.0, recorder, STEP_S)
    inertia = joint_masses(arm, R_MOTOR_DEFAULT, ideal, r_m)[1]
    pull_n = -unbalanced_weight_n(arm) * (r_m - 0.5 * arm.rake_length_m) / r_m
    return ground, inertia / (r_m * r_m), pull_n


@pytest.mark.parametrize("speed_m_per_s", [0.05, 0.2, 0.4])
def test_tines_rising_under_a_stone_meet_its_bottom_through_the_mount(
        speed_m_per_s: float) -> None:
    """A tine under an object that rises into it meets its bottom (it was read through the
    nearest side: 20261125/2993, 180 N on a mine's side at once). The mount extends as it
    compresses, so the bottom peaks as the arm's mass meeting the mount's spring-damper,
    the stone's stiffness in series, the weight the open motor leaves unheld holding it
    back (RK4 by hand, within 5 %); recorded on the stone's body, none on the ground. A
    mount rigid when extended would meet the stone itself: ten times more and over."""
    ground, mass_kg, pull_n = _rise_into_a_bottom(speed_m_per_s)
    stone = ground.bodies[0]
    k = 1.0 / (1.0 / ARM.tine_mount_stiffness_n_per_m + 1.0 / 1e7)
    expected = _mass_meets_spring_damper(mass_kg, k, ARM.tine_mount_damping_ns_per_m,
                                         speed_m_per_s, pull_n)
    assert stone.peak_side_n == pytest.approx(expected, rel=0.05)
    assert stone.peak_down_n == 0.0
    assert ground.truth.max_force_down_n < 1e-9  # the mount relaxing after: rounding only
    rigid = _mass_meets_spring_damper(mass_kg, 1e7, 1e7 * 2e-4, speed_m_per_s, pull_n)
    assert rigid > 10.0 * stone.peak_side_n


def test_a_bottom_the_relaxing_mount_leaves_does_not_pull() -> None:
    """Tines 20 µm into a mine's bottom while a mount compressed by 15 mm relaxes downward
    faster than they rise: the bottom's damping would pull, so it carries nothing and the
    mount relaxes as in free air (it was solved as pulling the arm up by 58.8 N)."""
    ground = Ground(GroundParams(objects=BuriedObjects(mines=(MineParams(),))), seed=0)
    bottom_m, step_s = ground.bodies[0].bottom_m, 5e-5
    ground.bodies[0].touching = True  # in it at the last reading
    mount = TineMount(5e3, 7.5, 5e3, 7.5, step_s)
    mount.compression_m = 0.015
    relaxed = 7.5 * 0.015 / (7.5 + step_s * 5e3)
    height_m = bottom_m + 2e-5 - relaxed
    assert mount.hooked(ground, 1.0, height_m, 0.03, relaxed) == relaxed
    assert mount.hooked_on == -1
    assert mount.commit(0.0, relaxed, 0.0)[1] == 0.0


def test_a_plate_let_go_as_pulling_holds_the_tines_when_the_soil_gives_way() -> None:
    """Tines resting 2.5 µm into a mine's plate under a collapsing soil (20261127/8181's
    substep at 0.671 s): with both laws pressing, the stiffer soil lifts the tines off the
    plate faster than it pushes, so the plate is let go; the soil then gives way by one
    step and the mount relaxes back down. The plate must hold them again: the solution is
    the hand-solved balance of the mount, the plate and the collapsed soil, where the
    mine's own law reads what the solve put on it (the plate left out read 302 N at
    233 mm/s with the mount carrying 22 N)."""
    k, c, h = 5e3, 7.5, 5e-5
    d0, arm_m, arm_vel = 4.7175e-3, 0.24758e-3, -7.6e-3
    mine = MineParams(reach_m=1.1, depth_m=-4.9676e-3, width_m=0.08, thickness_m=0.036,
                      activation_force_n=94.0)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(mines=(mine,))), seed=0)
    plate = ground.bodies[0]
    plate.touching = True  # in it at the last reading
    [plate_law] = [law for law in ground.vertical_laws(1.1, arm_m, arm_m + d0, h)
                   if not law.collapses]
    assert plate_law.ref_m == plate.top_m
    soil = VerticalLaw(5.3917e-3, 61532.9, 61.5329, 19.45, True)
    mount = TineMount(k, c, 0.0, 0.0, h)
    mount.compression_m = d0
    d = mount._vertical([plate_law, soil], arm_m, arm_vel)

    # by hand: the plate pressing, the soil's interface one step of cap/K lower
    soil_ref = soil.ref_m - soil.cap_n / soil.stiffness_n_per_m
    k_p, b_p, k_s, b_s = 5e6, 5e6 * 2e-4, soil.stiffness_n_per_m, soil.damping_ns_per_m
    expected = ((k_p * (plate.top_m - arm_m) + k_s * (soil_ref - arm_m)
                 + (c + b_p + b_s) * d0 / h - (b_p + b_s) * arm_vel)
                / (k + c / h + k_p + b_p / h + k_s + b_s / h))
    assert d == pytest.approx(expected, abs=1e-12)
    rate = arm_vel + (d - d0) / h
    assert plate.touch(1.1, arm_m + d, 0.0, rate, h)
    soil_n = k_s * (soil_ref - arm_m - d) - b_s * rate
    assert 0.0 < soil_n < soil.cap_n
    mount_n = k * d + c * (d - d0) / h
    assert plate.force_up_n + soil_n == pytest.approx(mount_n, rel=1e-9)
    assert 10.0 < plate.force_up_n < mount_n < 30.0


def test_tines_the_soil_pushes_into_a_bottom_rest_under_it() -> None:
    """Tines 1 µm under a mine's bottom, the mount compressed by 1 mm, the soil below
    pressing them up (its interface 40 µm above them: 14 N). Solved against the soil alone
    they end inside the bottom, where the mine's own law reads what nothing pushes (the
    soil gives at most 14 N: 20261128/2199 read 172 N so). Held by the bottom, they rest
    just under it, the mount's force passes either way, and by hand the mine carries the
    soil's push less the mount's force at that rest."""
    k, c, h = 5e3, 7.5, 5e-5
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(mines=(MineParams(),))),
                    seed=0)
    body = ground.bodies[0]
    bottom_m, reach_m = body.bottom_m, MineParams().reach_m
    arm_m, d0 = bottom_m - 1e-3, 1e-3 - 1e-6
    k_s, b_s = 3.5e5, 0.0  # its damping would only slow them: 0.25 µm a substep
    soil = VerticalLaw(bottom_m + 4e-5, k_s, b_s, 1e3, True)
    mount = TineMount(k, c, 0.0, 0.0, h)
    mount.compression_m = d0
    free = mount._vertical([soil], arm_m, 0.0)
    # by hand: K_s (ref − z) − B_s ż = k d + c ḋ, z = arm + d, ż = ḋ = (d − d0)/h
    assert free == pytest.approx((k_s * (soil.ref_m - arm_m) + (b_s + c) * d0 / h)
                                 / (k + c / h + k_s + b_s / h), abs=1e-12)
    assert arm_m + free > bottom_m + 1e-5  # inside it
    assert body.touch(reach_m, arm_m + free, 0.0, (free - d0) / h, h)
    assert -body.force_up_n > 50.0  # what the mine's law reads there

    rest = mount.hooked(ground, reach_m, arm_m, 0.0, free)
    assert (mount.resting_under, mount.hooked_on, mount.under) == (0, -1, 0)
    assert 0.0 <= bottom_m - (arm_m + rest) < 1e-15  # just under it
    assert not body.touch(reach_m, arm_m + rest, 0.0, 0.0, h)  # on its face, not in it
    rate = (rest - d0) / h
    mount_n = k * rest + c * rate
    soil_n = k_s * (soil.ref_m - arm_m - rest) - b_s * rate
    assert mount.commit(0.0, rest, 0.0)[1] == pytest.approx(mount_n, rel=1e-9)
    assert 4.0 < mount_n < soil_n < 15.0  # the mine carries soil_n − mount_n
    mount.resting_under = -1
    mount.hooked_on = 0
    assert mount.vertical_n(-1.0) == -1.0 and mount.vertical_n(1.0) == 0.0  # hooked: pulls
    mount.hooked_on = -1
    assert mount.vertical_n(-1.0) == 0.0 and mount.vertical_n(1.0) == 1.0  # free: pushes
    mount.resting_under = 0
    assert mount.vertical_n(-1.0) == -1.0 and mount.vertical_n(1.0) == 1.0  # resting: both


def test_tines_the_soil_does_not_push_keep_the_hooked_balance() -> None:
    """The same tines with the soil pushing nothing (the mount relaxed, pulling them up
    into the bottom alone): the mount-and-bottom balance of :meth:`TineMount.hooked`."""
    k, c, h = 5e3, 7.5, 5e-5
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(mines=(MineParams(),))),
                    seed=0)
    bottom_m, reach_m = ground.bodies[0].bottom_m, MineParams().reach_m
    ground.bodies[0].touching = True  # in it at the last reading
    mount = TineMount(k, c, 0.0, 0.0, h)
    mount.compression_m = d0 = -2e-4  # extended: pulling the tines up
    arm_m = bottom_m + 2e-4 + 1e-7  # the tines 0.1 µm into the bottom, pulled up
    free = mount._vertical([], arm_m, 0.0)
    assert arm_m + free > bottom_m
    hooked = mount.hooked(ground, reach_m, arm_m, 0.0, free)
    k_b, b_b = 5e6, 5e6 * MineParams().damping_time_s
    # by hand: −(k d + c ḋ) = K_b (z − z_b) + B_b ż
    assert hooked == pytest.approx((c * d0 / h + b_b * d0 / h - k_b * (arm_m - bottom_m))
                                   / (k + c / h + k_b + b_b / h), abs=1e-12)
    assert arm_m + hooked > bottom_m  # in it by what the mount pulls, over its K_b
    assert (mount.hooked_on, mount.resting_under, mount.under) == (0, -1, 0)


def test_tines_descending_into_a_bottom_corner_are_not_rested_under_it() -> None:
    """Tines descending along a stone's side into the corner by its bottom, where the
    bottom is the nearest face, are not under it: the soil pushing them (the mount
    compressed) must not rest them on the bottom, 60 µm lower in one substep, where the
    soil read its damping at 1.2 m/s: 114.8 N (20261127/1561). They stay as solved."""
    k, c, h = 5e3, 7.5, 5e-5
    stone = StoneParams(reach_m=1.0, depth_m=0.02, width_m=0.1, thickness_m=0.03,
                        edge_radius_m=0.0)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(stones=(stone,))), seed=0)
    body = ground.bodies[0]
    reach_m = body.left_m + 1e-5  # 10 µm inside its side
    arm_m, d0, arm_vel = body.bottom_m + 9e-6 - 2e-3, 2e-3, -0.05  # 9 µm above it
    soil = VerticalLaw(body.bottom_m + 3e-5, 3.5e5, 0.0, 1e3, True)
    mount = TineMount(k, c, 0.0, 0.0, h)
    mount.compression_m = d0
    d = mount._vertical([soil], arm_m, arm_vel)
    assert arm_vel + (d - d0) / h < 0.0  # descending
    assert k * d + c * (d - d0) / h > 1.0  # the soil pushes them
    assert body._contact(reach_m, arm_m + d)[2] == -1.0  # the bottom the nearest face
    assert mount.hooked(ground, reach_m, arm_m, arm_vel, d) == d
    assert (mount.resting_under, mount.hooked_on) == (-1, -1)


def test_an_edge_forcing_descending_tines_sideways_loads_it_with_the_soils_resistance() -> None:
    """The gap the clamp leaves (docs/safety.md, "Not covered"): the arm servoed straight
    down at 0.2 m/s, the tines' path 0.3 mm inside a mine's 3 mm rim, in a soil soft to
    the tips and strong to the rake's face (12 kPa). The rim forces the tines toward the
    robot through a 33 mm cut; at the mine's peak the soil's drag is the earthmoving
    equation's H at that cut in closed form (``cutting_force_n``: fully mobilized), and
    the mine carries it and what the mount carries, which is a few newtons: the arm, and
    so the clamp, feels only those."""
    layer = SoilLayer(stiffness_n_per_m=3.5e3, collapse_force_n=9.0, cohesion_pa=12e3,
                      damping_time_s=1e-3)
    soil = SoilParams(layers=(layer,), surface_slope=0.0, stiffness_rel_std=0.0,
                      strength_rel_std=0.0, lane_reach_max_m=2.0)
    reach_m, speed = 1.1, 0.2
    mine = MineParams(reach_m - 0.0003 + 0.04, 0.03, 0.08, 0.06, activation_force_n=1e4)
    ground = Ground(GroundParams(soil=soil, objects=BuriedObjects(mines=(mine,))), seed=0)
    body = ground.bodies[0]
    rows: list[tuple[float, float, float, float]] = []

    class _Record(PeakRecorder):
        def step(self, reach: float, height: float, reach_vel: float, height_vel: float,
                 dt_s: float) -> tuple[float, float]:
            total = super().step(reach, height, reach_vel, height_vel, dt_s)
            rows.append((body.force_reach_n, ground.soil.force_reach_n, total[0],
                         ground.soil.cut_depth_m))
            return total

    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_state(ArmState(*kinematics.inverse(WS, reach_m, -0.005)))
    recorder = _Record(ground)
    for k in range(300):
        r, th = kinematics.inverse(WS, reach_m, -0.005 - speed * k * STEP_S)
        plant.step(*_servo(plant, r, th, *_joint_rates(r, th, 0.0, -speed)), recorder, STEP_S)
    mine_n, drag_n, mount_n, cut_m = min(rows)
    assert cut_m == pytest.approx(0.033, abs=1e-3)
    assert drag_n == pytest.approx(cutting_force_n(layer, soil, cut_m), rel=0.01)
    assert abs(mount_n) < 10.0
    assert -mine_n == pytest.approx(drag_n - mount_n, rel=1e-9)
    assert -mine_n > 150.0 > 90.0  # over the limit, with the mount carrying a few newtons


def test_tines_meeting_a_rim_within_a_substep_meet_it_as_the_mount_pushes() -> None:
    """Massless tines cannot carry the Kelvin–Voigt jump B·v at first touch: met within a
    substep, a face's damping acts on the penetration gained since the touch (K + B/h,
    elastic), so the rim carries what the mount pushes with. Tines on a relaxed mount,
    descending with the arm at 0.09 m/s, 1.35 µm above a mine's rounded rim (15° from its
    top) at a substep's start. By hand, the backward-Euler balance on the rim's normal n:
    (k + c/h)·e = n_x·K'·P, (k + c/h)·d = n_z·K'·P, P = 3 µm − n_x·e − n_z·d,
    K' = K + B/h; the mine then reads (Body.touch) what the mount carries, that substep
    and the next (in it then: K, and B on the speed). With B on the speed from the first
    touch, a rim met so read the damping of the fall: 84.6 N on a mine's plate with the
    mount carrying 12.3 N (20261129 edge 345; it reads 26.3 N now)."""
    mine = MineParams(reach_m=1.0, depth_m=0.01, width_m=0.08, edge_radius_m=0.003)
    ground = Ground(GroundParams(soil=AIR, objects=BuriedObjects(mines=(mine,))), seed=0)
    rho, angle, h_s, v_m_per_s = 0.003, math.radians(15.0), 50e-6, -0.09
    centre_x, centre_z = 1.04 - rho, -0.01 - rho
    # the arm's end with the mount as it was: 3 µm inside the rim (it fell 4.5 µm)
    arm_x = centre_x + (rho - 3e-6) * math.sin(angle)
    arm_z = centre_z + (rho - 3e-6) * math.cos(angle)
    assert ground.bodies[0]._contact(arm_x, arm_z - v_m_per_s * h_s) is None  # above it
    mount = TineMount(5000.0, 7.5, 5000.0, 7.5, h_s)
    e, d = mount.solve(ground, arm_x, arm_z, 0.0, v_m_per_s)
    n_x, n_z = math.sin(angle), math.cos(angle)
    k_fresh = 5e6 + 5e6 * 2e-4 / h_s
    a = 5000.0 + 7.5 / h_s
    p_m = 3e-6 / (1.0 + k_fresh * (n_x * n_x + n_z * n_z) / a)
    assert e == pytest.approx(n_x * k_fresh * p_m / a, rel=1e-3)
    assert d == pytest.approx(n_z * k_fresh * p_m / a, rel=1e-3)
    side_n, down_n = mount.commit(e, d, 0.0)
    ground.step(arm_x + e, arm_z + d, e / h_s, v_m_per_s + d / h_s, h_s)
    body = ground.bodies[0]
    assert body.force_up_n == pytest.approx(down_n, rel=1e-3)
    assert body.force_reach_n == pytest.approx(side_n, rel=1e-3)
    assert 0.1 < down_n < 1.0

    # a substep on, in it: K and B on the speed again, still what the mount carries
    e1, d1 = mount.solve(ground, arm_x, arm_z + v_m_per_s * h_s, 0.0, v_m_per_s)
    rates = ((e1 - e) / h_s, v_m_per_s + (d1 - d) / h_s)
    side_n, down_n = mount.commit(e1, d1, 0.0)
    ground.step(arm_x + e1, arm_z + v_m_per_s * h_s + d1, *rates, h_s)
    assert body.force_up_n == pytest.approx(down_n, rel=1e-3)
    assert 0.5 < down_n < 1.0  # about c·v: the mount taking up the arm's fall



def test_the_soil_gives_way_only_under_a_solution_where_no_law_pulls() -> None:
    """Tines held at a soil cell's edge beside a mine's rim (20261128 edge 7013's substep at
    0.480 s): the soil's law in contact and a rim's law, met anew, whose face lies 3.4 µm
    below where the solution puts the tines. Solved with both, the rim's law pulls them
    0.36 µm past the soil's collapse point; were the collapse taken on that round, the
    tines rested on the collapsed interface at 0.08 m/s, where the soil reads its damping:
    62.6 N, with the mount carrying 12.7 N. The rim is let go first; then, by hand, the
    backward-Euler balance with the soil alone, k·d + c·ḋ = K_s·(ref − z) − B_s·ż, which
    stops the tines 3.2 µm short of the collapse, the soil carrying what the mount does."""
    k, c, h = 5e3, 7.5, 5e-5
    d0, arm_m, arm_vel = 2.2507418367370136e-3, -20.319393416377673e-3, -0.26389146729357643
    soil = VerticalLaw(-18.055456944180426e-3, 778964.35, 778.96435, 3.1286328, True)
    rim = VerticalLaw(-18.063221122641453e-3, 17362107.7, 0.0, math.inf, False)
    mount = TineMount(k, c, 0.0, 0.0, h)
    mount.compression_m = d0
    d = mount._vertical([soil, rim], arm_m, arm_vel)
    k_s, b_s = soil.stiffness_n_per_m, soil.damping_ns_per_m
    expected = ((k_s * (soil.ref_m - arm_m) + (b_s + c) * d0 / h - b_s * arm_vel)
                / (k + c / h + k_s + b_s / h))
    assert d == pytest.approx(expected, abs=1e-12)
    rate = arm_vel + (d - d0) / h
    elastic_n = k_s * (soil.ref_m - arm_m - d)
    assert 0.0 < elastic_n < soil.cap_n  # no collapse
    assert arm_m + d > rim.ref_m  # above the rim: it carries nothing
    mount_n = k * d + c * (d - d0) / h
    assert elastic_n - b_s * rate == pytest.approx(mount_n, rel=1e-9)
    assert 10.0 < mount_n < 15.0
