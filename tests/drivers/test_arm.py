"""Rigid-body arm with motors: energy, gravity, end stops, contact mapping, sensors."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from drivers.arm import DEFAULT_SUBSTEP_S, ArmPlant, ArmState
from drivers.ground import Ground
from drivers.ground_params import BuriedObjects, GroundParams, StoneParams
from drivers.mechanics import ArmParams, gravity_joint_loads, joint_masses, tip_apparent_masses_kg
from drivers.motor import (
    R_MOTOR_DEFAULT,
    THETA_MOTOR_DEFAULT,
    Bridge,
    MotorParams,
    joint_load_band,
    joint_per_motor_rad,
    no_load_joint_speed,
    stall_joint_load,
)
from drivers.soil_params import SoilLayer, SoilParams
from rakectl.core import kinematics
from rakectl.core.kinematics import Workspace
from rakectl.errors import ConfigError, NonFiniteError
from rakectl.sim.rake_plant import PeakRecorder

WS = Workspace(pivot_height_m=0.6, r_min_m=0.35, r_max_m=1.6, theta_min_rad=-0.2,
               theta_max_rad=1.3)
ARM = ArmParams(counterweight_kg=0.0)  # unbalanced: its gravity is what most tests check
FRICTIONLESS_ARM = dataclasses.replace(
    ARM, stop_stiffness_r_n_per_m=0.0, stop_damping_r_ns_per_m=0.0,
    stop_stiffness_theta_nm_per_rad=0.0, stop_damping_theta_nms_per_rad=0.0,
    damping_r_ns_per_m=0.0, damping_theta_nms_per_rad=0.0,
)
STEP_S = 1e-3

r_inside = st.floats(0.4, 1.55)
theta_inside = st.floats(-0.15, 1.25)


def _ideal(p: MotorParams) -> MotorParams:
    return dataclasses.replace(p, gear_efficiency=1.0, coulomb_friction_nm=0.0,
                               viscous_friction_nms_per_rad=0.0)


def _ideal_plant(arm: ArmParams = ARM, substep_s: float = DEFAULT_SUBSTEP_S) -> ArmPlant:
    return ArmPlant(arm, _ideal(R_MOTOR_DEFAULT), _ideal(THETA_MOTOR_DEFAULT), WS, substep_s)


class NoContact:
    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        return 0.0, 0.0


@dataclasses.dataclass
class ConstantForce:
    force_reach_n: float
    force_height_n: float

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        return self.force_reach_n, self.force_height_n


@dataclasses.dataclass
class TipSpring:
    """A conservative spring from the tip to a fixed anchor; remembers its energy."""

    anchor_m: tuple[float, float]
    stiffness_n_per_m: float
    energy_j: float = 0.0

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        dx, dz = reach_m - self.anchor_m[0], height_m - self.anchor_m[1]
        self.energy_j = 0.5 * self.stiffness_n_per_m * (dx * dx + dz * dz)
        return -self.stiffness_n_per_m * dx, -self.stiffness_n_per_m * dz


def _run(plant: ArmPlant, volts: tuple[float, float], contact: object, seconds: float) -> None:
    for _ in range(round(seconds / STEP_S)):
        plant.step(volts[0], volts[1], contact, STEP_S)  # type: ignore[arg-type]


def _holding_voltages(plant: ArmPlant, loads: tuple[float, float]) -> tuple[float, float]:
    """Set ideal motors' currents to deliver ``loads`` at rest; the voltages that keep them."""
    currents = [
        load * joint_per_motor_rad(p) / p.torque_constant_nm_per_a
        for load, p in zip(loads, (R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT), strict=True)
    ]
    state = plant.state()
    plant.set_state(dataclasses.replace(state, current_r_a=currents[0],
                                        current_theta_a=currents[1]))
    return currents[0] * R_MOTOR_DEFAULT.resistance_ohm, (
        currents[1] * THETA_MOTOR_DEFAULT.resistance_ohm
    )


# --------------------------------------------------------------------------- energy


def _energy_drift(substep_s: float, start: ArmState, seconds: float) -> tuple[float, float]:
    """(largest |E − E0|, largest |dT/dt|) of a free, frictionless, unpowered arm."""
    plant = _ideal_plant(FRICTIONLESS_ARM, substep_s)
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)  # motor leads open: i = 0, no EMF braking
    plant.set_state(start)
    energy_0 = plant.mechanical_energy_j()
    drift, power, kinetic = 0.0, 0.0, _kinetic_j(plant)
    for _ in range(round(seconds / STEP_S)):
        plant.step(0.0, 0.0, NoContact(), STEP_S)
        drift = max(drift, abs(plant.mechanical_energy_j() - energy_0))
        power = max(power, abs(_kinetic_j(plant) - kinetic) / STEP_S)
        kinetic = _kinetic_j(plant)
    return drift, power


def _kinetic_j(plant: ArmPlant) -> float:
    masses = joint_masses(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, plant.r_m)
    speeds = (plant.r_vel_m_per_s, plant.theta_vel_rad_per_s)
    return 0.5 * sum(m * v * v for m, v in zip(masses, speeds, strict=True))


@settings(max_examples=8, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside, r_vel=st.floats(-0.5, 0.5),
       theta_vel=st.floats(-1.5, 1.5))
def test_energy_is_conserved_without_dissipation(
    r_m: float, theta_rad: float, r_vel: float, theta_vel: float
) -> None:
    """Swinging and sliding for 2 s with motor leads open, no friction, damping or stops.

    Symplectic Euler conserves a modified energy H − (h/2)·q̇·∂V/∂q + O(h²): E stays within
    h × the largest power exchanged between kinetic and potential energy.
    """
    drift, power = _energy_drift(1e-4, ArmState(r_m, theta_rad, r_vel, theta_vel), 2.0)
    assert drift <= 1e-4 * power + 1e-6


# --------------------------------------------------------------------------- counterweight

BALANCED = dataclasses.replace(FRICTIONLESS_ARM, counterweight_kg=8.0, counterbalance_share=1.0)


def test_the_counterweight_adds_its_mass_as_seen_through_the_linkage() -> None:
    """By hand: it moves β·m/m_c as fast as the carriage, so it adds m_c·(β m/m_c)² =
    β² m²/m_c to the mass along r and that times (r − L/2)² to θ's inertia."""
    arm = dataclasses.replace(ARM, counterweight_kg=8.0, counterbalance_share=0.75)
    added_kg = (0.75 * 4.0) ** 2 / 8.0
    mass_r, inertia = joint_masses(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1.3)
    bare_r, bare_inertia = joint_masses(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1.3)
    assert mass_r - bare_r == pytest.approx(added_kg, rel=1e-12)
    assert inertia - bare_inertia == pytest.approx(added_kg * 0.5 ** 2, rel=1e-12)
    assert gravity_joint_loads(arm, 1.3, 0.4) == pytest.approx(
        tuple(0.25 * load for load in gravity_joint_loads(ARM, 1.3, 0.4)), rel=1e-12)


@pytest.mark.parametrize(("r_m", "theta_rad"), [(0.5, 0.1), (1.2, 0.6), (1.55, -0.15)])
def test_a_balanced_arm_stays_where_it_is_left(r_m: float, theta_rad: float) -> None:
    """β = 1: the arm's centre of mass does not move with the joints, so an unpowered,
    frictionless arm left at rest anywhere stays there."""
    plant = _ideal_plant(BALANCED)
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    plant.set_pose_at_rest(r_m, theta_rad)
    _run(plant, (0.0, 0.0), NoContact(), 0.5)
    assert plant.r_m == pytest.approx(r_m, abs=1e-12)
    assert plant.theta_rad == pytest.approx(theta_rad, abs=1e-12)


def test_a_partly_balanced_arm_starts_to_fall_as_its_unbalanced_share() -> None:
    """β = 0.6: from rest the joints accelerate as gravity's unbalanced 40 % over each
    joint's mass with the counterweight (hand-computed), for the first milliseconds."""
    arm = dataclasses.replace(FRICTIONLESS_ARM, counterweight_kg=8.0, counterbalance_share=0.6)
    plant = _ideal_plant(arm)
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    r_m, theta_rad, t_s = 1.2, 0.3, 0.002
    plant.set_pose_at_rest(r_m, theta_rad)
    _run(plant, (0.0, 0.0), NoContact(), t_s)
    mass_r, inertia = joint_masses(arm, _ideal(R_MOTOR_DEFAULT), _ideal(THETA_MOTOR_DEFAULT), r_m)
    weight_n = 0.4 * 4.0 * 9.81
    assert plant.r_vel_m_per_s == pytest.approx(weight_n * math.sin(theta_rad) / mass_r * t_s,
                                                rel=1e-2)
    assert plant.theta_vel_rad_per_s == pytest.approx(
        weight_n * (r_m - 0.8) * math.cos(theta_rad) / inertia * t_s, rel=1e-2)


@settings(max_examples=4, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside, r_vel=st.floats(-0.5, 0.5),
       theta_vel=st.floats(-1.5, 1.5))
@example(r_m=1.53125, theta_rad=0.875, r_vel=0.0, theta_vel=-1.1875)  # 6.8e-4 J at 0.1 ms
def test_energy_is_conserved_with_a_counterweight(r_m: float, theta_rad: float, r_vel: float,
                                                  theta_vel: float) -> None:
    """The same as without it, a third of the weight left unbalanced: the energy error is
    the integrator's first-order one (it halves with the substep), not a drift of the
    counterweight's terms."""
    arm = dataclasses.replace(FRICTIONLESS_ARM, counterweight_kg=6.0, counterbalance_share=0.7)

    def error_j(substep_s: float) -> float:
        plant = _ideal_plant(arm, substep_s)
        plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
        plant.set_state(ArmState(r_m, theta_rad, r_vel, theta_vel))
        energy_0, drift = plant.mechanical_energy_j(), 0.0
        for _ in range(round(1.0 / STEP_S)):
            plant.step(0.0, 0.0, NoContact(), STEP_S)
            drift = max(drift, abs(plant.mechanical_energy_j() - energy_0))
        return drift

    coarse, fine = error_j(1e-4), error_j(5e-5)
    assert fine <= 0.6 * coarse + 1e-7
    assert coarse <= 2e-3


def test_energy_error_is_the_integrators_first_order_error() -> None:
    """The bounded energy error halves with the substep, no drift."""
    start = ArmState(1.0, 0.0, 0.5, 1.0)
    coarse, _ = _energy_drift(2e-4, start, 2.0)
    fine, _ = _energy_drift(1e-4, start, 2.0)
    assert 1.8 < coarse / fine < 2.2


def test_energy_is_conserved_with_a_conservative_tip_spring() -> None:
    """Contact work is consistent with Jᵀ F: arm + spring energy is conserved.

    A 2 kN/m spring makes the arm oscillate at ω ≈ 26 rad/s; symplectic Euler keeps the
    energy within ≈ ½hω of the kinetic energy, asserted as |ΔE| ≤ 3e-3 × max kinetic.
    """
    plant = _ideal_plant(FRICTIONLESS_ARM)
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    plant.set_state(ArmState(1.0, 0.4, 0.3, -0.5))
    reach_m, height_m = plant.tip_m()
    spring = TipSpring((reach_m + 0.05, height_m + 0.1), 2.0e3)
    spring.step(reach_m, height_m, 0.0, 0.0, 0.0)
    energy_0 = plant.mechanical_energy_j() + spring.energy_j
    drift, kinetic = 0.0, 0.0
    for _ in range(3000):
        plant.step(0.0, 0.0, spring, STEP_S)
        spring.step(*plant.tip_m(), 0.0, 0.0, 0.0)
        drift = max(drift, abs(plant.mechanical_energy_j() + spring.energy_j - energy_0))
        kinetic = max(kinetic, _kinetic_j(plant))
    assert kinetic > 1.0  # it did swing
    assert drift <= 3e-3 * kinetic


# --------------------------------------------------------------------------- gravity


def test_default_motors_can_hold_the_rake() -> None:
    worst_torque_nm = max(abs(gravity_joint_loads(ARM, WS.r_max_m, t)[1]) for t in (0.0, 0.3))
    worst_force_n = abs(gravity_joint_loads(ARM, WS.r_max_m, WS.theta_max_rad)[0])
    assert stall_joint_load(THETA_MOTOR_DEFAULT, 24.0) > 1.4 * worst_torque_nm
    assert stall_joint_load(R_MOTOR_DEFAULT, 24.0) > 2.0 * worst_force_n


@settings(max_examples=25, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside)
def test_gravity_loads_applied_by_the_motors_hold_the_arm(r_m: float, theta_rad: float) -> None:
    plant = _ideal_plant()
    plant.set_pose_at_rest(r_m, theta_rad)
    volts = _holding_voltages(plant, gravity_joint_loads(ARM, r_m, theta_rad))
    _run(plant, volts, NoContact(), 0.3)
    assert plant.r_m == pytest.approx(r_m, abs=1e-9)
    assert plant.theta_rad == pytest.approx(theta_rad, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside)
def test_unpowered_arm_falls_the_way_gravity_pulls(r_m: float, theta_rad: float) -> None:
    """Default motors shorted (0 V): each joint whose weight exceeds its friction band moves
    the way gravity pulls; an arm whose weight is inside both bands does not move at all."""
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_pose_at_rest(r_m, theta_rad)
    pulls = [-load for load in gravity_joint_loads(ARM, r_m, theta_rad)]
    bands = [joint_load_band(p, 0.0)[1] for p in (R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT)]
    assume(all(abs(abs(f) - b) > 0.5 * b for f, b in zip(pulls, bands, strict=True)))
    _run(plant, (0.0, 0.0), NoContact(), 0.02)
    moved = (plant.r_m - r_m, plant.theta_rad - theta_rad)
    if all(abs(f) < b for f, b in zip(pulls, bands, strict=True)):
        assert moved == (0.0, 0.0)
    for pull, band, delta in zip(pulls, bands, moved, strict=True):
        if abs(pull) > band:
            assert delta * pull > 0.0


# --------------------------------------------------------------------------- end stops


def _overshoot(plant: ArmPlant, volts: tuple[float, float], seconds: float) -> tuple[float, float]:
    """Largest excursion beyond the joint limits (m, rad), checked every substep."""
    worst_r, worst_theta = 0.0, 0.0
    for _ in range(round(seconds / plant.substep_s)):
        plant.step(volts[0], volts[1], NoContact(), plant.substep_s)
        worst_r = max(worst_r, plant.r_m - WS.r_max_m, WS.r_min_m - plant.r_m)
        worst_theta = max(worst_theta, plant.theta_rad - WS.theta_max_rad,
                          WS.theta_min_rad - plant.theta_rad)
    return worst_r, worst_theta


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_end_stops_hold_the_joints_at_full_voltage(sign: float) -> None:
    """Full supply into the stops: overshoot ≤ 3 mm on r, ≤ 5 mrad on θ (measured 2.3, 2.9)."""
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_pose_at_rest(1.0, 0.5)
    worst_r, worst_theta = _overshoot(plant, (24.0 * sign, 24.0 * sign), 1.5)
    assert worst_r <= 3e-3
    assert worst_theta <= 5e-3
    assert plant.r_vel_m_per_s == pytest.approx(0.0, abs=1e-6)  # at rest on the stops
    assert plant.theta_vel_rad_per_s == pytest.approx(0.0, abs=1e-6)


@settings(max_examples=20, deadline=None)
@given(speed=st.floats(0.05, 1.5), theta_rad=theta_inside, upper=st.booleans())
def test_r_stop_overshoot_is_bounded_by_the_spring(speed: float, theta_rad: float,
                                                    upper: bool) -> None:
    """Unpowered impact at speed v: overshoot ≤ v·√(M/k) + (weight along r)/k."""
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_bridges(Bridge.OPEN, Bridge.DRIVEN)
    limit = WS.r_max_m if upper else WS.r_min_m
    direction = 1.0 if upper else -1.0
    plant.set_state(ArmState(limit - direction * 1e-3, theta_rad, direction * speed))
    volts = _holding_voltages(plant, (0.0, gravity_joint_loads(ARM, limit, theta_rad)[1]))
    worst_r, _ = _overshoot(plant, volts, 0.05)
    mass_kg, _ = joint_masses(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, limit)
    stiffness = ARM.stop_stiffness_r_n_per_m
    weight_n = ARM.rake_mass_kg * ARM.gravity_m_per_s2
    assert worst_r <= speed * math.sqrt(mass_kg / stiffness) + weight_n / stiffness


# --------------------------------------------------------------------------- contact


@settings(max_examples=25, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside, force_n=st.floats(-90.0, 90.0))
def test_vertical_tip_force_maps_through_the_jacobian(
    r_m: float, theta_rad: float, force_n: float
) -> None:
    """Motors supplying gravity − Jᵀ F hold the arm; the plant's contact loads are Jᵀ F."""
    plant = _ideal_plant()
    plant.set_pose_at_rest(r_m, theta_rad)
    expected = kinematics.joint_loads(r_m, theta_rad, 0.0, force_n)
    hold = gravity_joint_loads(ARM, r_m, theta_rad)
    volts = _holding_voltages(plant, (hold[0] - expected[0], hold[1] - expected[1]))
    assume(abs(plant.current_r_a) < 0.99 * R_MOTOR_DEFAULT.current_limit_a)
    assume(abs(plant.current_theta_a) < 0.99 * THETA_MOTOR_DEFAULT.current_limit_a)
    _run(plant, volts, ConstantForce(0.0, force_n), 0.2)
    assert plant.last_contact_joint_loads == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert plant.last_tip_force_n == (0.0, force_n)
    assert plant.r_m == pytest.approx(r_m, abs=1e-9)
    assert plant.theta_rad == pytest.approx(theta_rad, abs=1e-9)


@settings(max_examples=10, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside, force_n=st.floats(5.0, 90.0))
def test_upward_tip_force_lifts_the_tip(r_m: float, theta_rad: float, force_n: float) -> None:
    plant = _ideal_plant()
    plant.set_pose_at_rest(r_m, theta_rad)
    volts = _holding_voltages(plant, gravity_joint_loads(ARM, r_m, theta_rad))
    height_0 = plant.tip_m()[1]
    _run(plant, volts, ConstantForce(0.0, force_n), 0.005)
    assert plant.tip_m()[1] > height_0


@settings(max_examples=20, deadline=None)
@given(r_m=r_inside, theta_rad=theta_inside, force_n=st.floats(-100.0, 100.0).filter(bool))
def test_tip_apparent_mass_is_what_a_tip_force_accelerates(
    r_m: float, theta_rad: float, force_n: float
) -> None:
    weightless = dataclasses.replace(ARM, gravity_m_per_s2=0.0)
    plant = _ideal_plant(weightless)
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    masses = tip_apparent_masses_kg(weightless, _ideal(R_MOTOR_DEFAULT),
                                    _ideal(THETA_MOTOR_DEFAULT), r_m, theta_rad)
    for axis, force in enumerate(((force_n, 0.0), (0.0, force_n))):
        plant.set_pose_at_rest(r_m, theta_rad)
        plant.step(0.0, 0.0, ConstantForce(*force), plant.substep_s)
        tip_vel = plant.tip_vel_m_per_s()[axis]
        assert tip_vel == pytest.approx(force_n * plant.substep_s / masses[axis], rel=1e-3)


# --------------------------------------------------------------------------- sensors


def _record(seed: int, steps: int = 200) -> list[object]:
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS, seed=seed)
    plant.set_pose_at_rest(1.0, 0.4)
    measurements: list[object] = []
    for _ in range(steps):
        plant.step(3.0, -2.0, NoContact(), STEP_S)
        measurements.append(plant.measure())
    return measurements


def test_measurements_are_reproducible_with_the_same_seed() -> None:
    assert _record(7) == _record(7)
    other = _record(8)
    assert other != _record(7)
    positions = [(m.r_m, m.theta_rad) for m in _record(7)]  # type: ignore[attr-defined]
    assert positions == [(m.r_m, m.theta_rad) for m in other]  # type: ignore[attr-defined]


def test_measurements_are_quantized_differenced_and_noisy() -> None:
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS, seed=3)
    plant.set_pose_at_rest(1.0, 0.4)
    res_r = 2 * math.pi * joint_per_motor_rad(R_MOTOR_DEFAULT) / 2000
    res_theta = 2 * math.pi * joint_per_motor_rad(THETA_MOTOR_DEFAULT) / 2000
    previous = plant.measure()
    noise: list[float] = []
    for _ in range(3000):
        plant.step(4.0, -3.0, NoContact(), STEP_S)
        m = plant.measure()
        assert plant.r_m - res_r < m.r_m <= plant.r_m + 1e-12
        assert plant.theta_rad - res_theta < m.theta_rad <= plant.theta_rad + 1e-12
        assert m.r_vel_m_per_s == pytest.approx((m.r_m - previous.r_m) / STEP_S, rel=1e-9)
        assert m.theta_vel_rad_per_s == pytest.approx(
            (m.theta_rad - previous.theta_rad) / STEP_S, rel=1e-9, abs=1e-12)
        noise.append(m.current_theta_a - plant.current_theta_a)
        previous = m
    rms = math.sqrt(sum(n * n for n in noise) / len(noise))
    assert rms == pytest.approx(THETA_MOTOR_DEFAULT.current_noise_a, rel=0.1)


def test_speed_is_bounded_by_the_no_load_speed() -> None:
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_pose_at_rest(0.5, 0.0)
    _run(plant, (5.0, 0.0), NoContact(), 0.3)
    assert 0.0 < plant.r_vel_m_per_s <= no_load_joint_speed(R_MOTOR_DEFAULT, 5.0)


# --------------------------------------------------------------------------- errors


def test_bad_inputs_are_rejected() -> None:
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    with pytest.raises(NonFiniteError):
        plant.step(math.nan, 0.0, NoContact(), STEP_S)
    with pytest.raises(NonFiniteError):
        plant.step(0.0, 0.0, ConstantForce(math.inf, 0.0), STEP_S)
    with pytest.raises(ConfigError):
        plant.step(0.0, 0.0, NoContact(), 1.01e-3)
    with pytest.raises(ConfigError, match="rake_mass_kg"):
        ArmParams(rake_mass_kg=-1.0)
    with pytest.raises(ConfigError, match="too long"):
        ArmPlant(dataclasses.replace(ARM, damping_theta_nms_per_rad=1e4), R_MOTOR_DEFAULT,
                 THETA_MOTOR_DEFAULT, WS)


def _drop_onto_a_stone(arm: ArmParams, speed_m_per_s: float) -> tuple[float, float]:
    """The tip 2 mm above a stone's top, moving down at ``speed_m_per_s``, motors open:
    the largest vertical force on the stone and the mount's largest compression."""
    r_m, theta_rad = 1.2, 0.6
    reach_m, height_m = kinematics.forward(WS, r_m, theta_rad)
    stone = StoneParams(reach_m, -(height_m - 0.002), 0.1, 0.05)  # top 2 mm below the tip
    air = SoilParams(layers=(SoilLayer(stiffness_n_per_m=1.0, collapse_force_n=1e-3),),
                     surface_slope=0.0)
    ground = Ground(GroundParams(soil=dataclasses.replace(air, lane_reach_max_m=2.0),
                                 objects=BuriedObjects(stones=(stone,))), seed=0)
    plant = ArmPlant(arm, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_state(ArmState(r_m, theta_rad, 0.0, speed_m_per_s / (r_m * math.cos(theta_rad))))
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    peak_n = compression_m = 0.0
    for _ in range(100):
        plant.step(0.0, 0.0, ground, STEP_S)
        peak_n = max(peak_n, ground.truth.max_force_down_n)
        compression_m = max(compression_m, plant.mount_m)
    return peak_n, compression_m


def test_the_compliant_tine_mount_takes_the_impact() -> None:
    """At 0.1 m/s onto a stone (10⁷ N/m), a rigid tine peaks at several hundred N; on the
    3·10⁴ N/m mount the peak is about v·√(k·m) plus the weight, and the mount compresses."""
    rigid_n, _ = _drop_onto_a_stone(dataclasses.replace(ARM, tine_mount_stiffness_n_per_m=0.0),
                                    0.1)
    mounted_n, compression_m = _drop_onto_a_stone(ARM, 0.1)
    mass_kg = tip_apparent_masses_kg(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, 1.2, 0.6)[1]
    impact_n = 0.1 * math.sqrt(ARM.tine_mount_stiffness_n_per_m * mass_kg)
    assert rigid_n > 300.0
    assert mounted_n < 2.0 * impact_n + 60.0  # the arm's weight at the tip is < 40 N
    assert compression_m == pytest.approx(mounted_n / ARM.tine_mount_stiffness_n_per_m,
                                          rel=0.3)


class _Reading(PeakRecorder):
    """The ground as the rake loop passes it, keeping per substep the ground's own vertical
    reading and what the tine mount said it carried."""

    def __init__(self, ground: Ground) -> None:
        super().__init__(ground)
        self.pairs: list[tuple[float, float]] = []
        self._own_n = 0.0

    def step(self, reach_m: float, height_m: float, reach_vel_m_per_s: float,
             height_vel_m_per_s: float, dt_s: float) -> tuple[float, float]:
        force = super().step(reach_m, height_m, reach_vel_m_per_s, height_vel_m_per_s, dt_s)
        self._own_n = self.truth.force_down_n
        return force

    def transmitted(self, force_down_n: float) -> None:
        super().transmitted(force_down_n)
        self.pairs.append((self._own_n, force_down_n))


@pytest.mark.parametrize("speed_m_per_s", [0.02, 0.1, 0.2])
def test_the_mount_carries_what_the_ground_reads(speed_m_per_s: float) -> None:
    """Falling through a weak layer onto a strong one (which collapses in a saw-tooth)
    and onto a stone: on every substep the ground's own law never reads more than the
    mount carries (the arm feels all of it), and where it reads anything the two agree.
    The mount's solve once used the wrong layer and a stale yield state: it carried
    97 N while the soil read 15 N, and 27 N while the soil read 54 N."""
    reach_m = 1.2
    r_m, theta_rad = kinematics.inverse(WS, reach_m, 0.002)  # 2 mm above the surface
    soil = SoilParams(layers=(SoilLayer(stiffness_n_per_m=2.4e5, collapse_force_n=3.4),
                              SoilLayer(from_depth_m=0.003, stiffness_n_per_m=1.4e6,
                                        collapse_force_n=38.0)),
                      surface_slope=0.0, surface_waves=(), lane_reach_max_m=2.0)
    stone = StoneParams(reach_m, 0.010, 0.1, 0.05)
    ground = Ground(GroundParams(soil=soil, objects=BuriedObjects(stones=(stone,))), seed=0)
    reading = _Reading(ground)
    plant = ArmPlant(ARM, R_MOTOR_DEFAULT, THETA_MOTOR_DEFAULT, WS)
    plant.set_state(ArmState(r_m, theta_rad, 0.0, speed_m_per_s / (r_m * math.cos(theta_rad))))
    plant.set_bridges(Bridge.OPEN, Bridge.OPEN)
    for _ in range(300):
        plant.step(0.0, 0.0, reading, STEP_S)
    touching = [(own, mount) for own, mount in reading.pairs if own > 0.0]
    assert len(touching) > 1000  # it did press on the ground
    assert max(mount for _, mount in touching) > 20.0
    for own_n, mount_n in reading.pairs:
        assert own_n <= mount_n + 1e-6
    for own_n, mount_n in touching:
        assert mount_n == pytest.approx(own_n, rel=0.01, abs=0.5)
