"""The discrete impedance controller against an independent continuous-time solution."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given
from hypothesis import strategies as st

from rakectl.config.loader import load_settings
from rakectl.core.impedance import DelayForceEstimator, ImpedanceFilter
from rakectl.errors import ConfigError
from rakectl.sim.scenario import PlantKind, Scenario, TrajectoryKind
from rakectl.sim.simulate import run
from tests.reference import LoopParams, solve

PAPER = LoopParams(0.39, 1.33e4, 1.0e4, 2.0e5, 0.01, 0.2, 0.007, 0.0, 20.0)
SOFT = LoopParams(2.0, 2.0e3, 5.0e3, 5.0e4, 0.02, 0.1, 0.01, 0.0, 10.0)
# non-zero desired force and a lightly damped filter (the force overshoots)
PRESSING = LoopParams(1.0, 300.0, 1.0e4, 1.0e5, 0.005, 0.05, 0.005, 20.0, 5.0)


@functools.cache
def _reference(p: LoopParams) -> dict[str, np.ndarray]:
    """The continuous loop sampled every 1 ms (fine step 10 µs, 20 µs past 10 s)."""
    return solve(p, fine_step_s=1e-5 if p.duration_s <= 10 else 2e-5, sample_every_s=1e-3)


def _overrides(p: LoopParams) -> list[str]:
    return [
        f"impedance.mass_kg={p.mass_kg}", f"impedance.damping_ns_per_m={p.damping_ns_per_m}",
        f"impedance.stiffness_n_per_m={p.stiffness_n_per_m}",
        f"estimator.environment_stiffness_n_per_m={p.env_stiffness_n_per_m}",
        f"estimator.delay_s={p.delay_s}", f"plant.time_constant_s={p.time_constant_s}",
        f"trajectory.speed_m_per_s={p.speed_m_per_s}", f"desired_force_n={p.desired_force_n}",
        f"duration_s={p.duration_s}", "plant.kind=first_order", "trajectory.kind=ramp",
    ]


@pytest.mark.parametrize("params", [PAPER, SOFT, PRESSING], ids=["paper", "soft", "pressing"])
def test_discrete_loop_matches_continuous_solution(params: LoopParams) -> None:
    """At 1 kHz the exact-ZOH controller stays within 20 µm and 5 % of the force
    range of the continuous loop (fine-step exponential integrator at 10-20 µs).
    Measured: ≤ 5.4 µm and ≤ 3.1 %; the rest is the 1 ms sample-and-hold."""
    reference = _reference(params)
    result = run(load_settings(None, _overrides(params), root=Scenario))
    n = min(len(reference["t_s"]), len(result.data))
    x_error = np.abs(result.column("x_m")[:n] - reference["x_m"][:n])
    f_error = np.abs(result.column("f_hat_n")[:n] - reference["f_hat_n"][:n])
    f_range = np.ptp(reference["f_hat_n"])
    assert f_range > 5.0  # the scenario really loads the estimator
    assert x_error.max() <= 20e-6
    assert f_error.max() <= 0.05 * f_range
    # steady state of the ramp: F̂ → K_e v α, x_c → (F_d − F̂)/K_d
    f_ss = params.env_stiffness_n_per_m * params.speed_m_per_s * params.delay_s
    assert result.column("f_hat_n")[-1] == pytest.approx(f_ss, rel=1e-3)
    x_c_ss = (params.desired_force_n - f_ss) / params.stiffness_n_per_m
    assert result.column("x_c_m")[-1] == pytest.approx(x_c_ss, rel=1e-3)


def _settling_time_s(t_s: np.ndarray, y: np.ndarray, final: float) -> float:
    """When ``y`` last enters the band of ±1 % around ``final``, to stay."""
    outside = np.nonzero(np.abs(y - final) > 0.01 * abs(final))[0]
    return float(t_s[outside[-1] + 1]) if len(outside) else float(t_s[0])


def test_paper_figures() -> None:
    """The scenario file is the paper's Section X, and its run follows the continuous loop
    over the whole 20 s: the end values alone (K_e v α, F̂/K_d + τ v) do not depend on M_d
    or B_d. M_d barely shows in the run (39 kg instead of 0.39 moves x by under 1 µm: the
    mass pole −B_d/M_d is fast either way), so the parameters are compared too."""
    settings = load_settings("config/scenarios/paper-fig5.yaml", root=Scenario)
    imp, est = settings.impedance, settings.estimator
    assert LoopParams(imp.mass_kg, imp.damping_ns_per_m, imp.stiffness_n_per_m,
                      est.environment_stiffness_n_per_m, est.delay_s,
                      settings.plant.time_constant_s, settings.trajectory.speed_m_per_s,
                      settings.desired_force_n, settings.duration_s) == PAPER
    assert (settings.plant.kind, settings.trajectory.kind, settings.rate_hz) == (
        PlantKind.FIRST_ORDER, TrajectoryKind.RAMP, 1000.0)
    result = run(settings)
    summary = result.summary()
    assert summary["f_hat_final_n"] == pytest.approx(14.00, abs=0.05)
    assert summary["tracking_error_final_m"] == pytest.approx(2.80e-3, abs=0.02e-3)
    assert summary["ticks"] == 20_000
    reference = _reference(PAPER)  # measured: 2.3 µm and 0.24 % (B_d 1.2e4: 46 µm)
    n = min(len(reference["t_s"]), len(result.data))
    assert np.abs(result.column("x_m")[:n] - reference["x_m"][:n]).max() <= 5e-6
    f_error = np.abs(result.column("f_hat_n")[:n] - reference["f_hat_n"][:n]).max()
    assert f_error <= 0.01 * np.ptp(reference["f_hat_n"])
    t_s, error_m = result.column("t_s"), result.column("x_d_m") - result.column("x_m")
    # docs/control.md: F̂ within 1 % of 14 N after 4.4 s, x_d − x within 1 % after 6.5 s
    assert _settling_time_s(t_s, result.column("f_hat_n"), 14.0) == pytest.approx(4.39,
                                                                                   abs=0.02)
    assert _settling_time_s(t_s, error_m, error_m[-1]) == pytest.approx(6.50, abs=0.02)


def test_forward_euler_would_diverge_but_exact_filter_does_not() -> None:
    """Why the filter is discretized exactly: the paper's fast pole −B/M ≈ −3.4e4 rad/s."""
    m, b, k, dt = 0.39, 1.33e4, 1.0e4, 1e-3
    x, v = 0.0, 0.0
    for _ in range(15):  # forward Euler on the same filter, unit force
        x, v = x + dt * v, v + dt * (1.0 - b * v - k * x) / m
    assert abs(x) > 1e6
    f = ImpedanceFilter(m, b, k, dt)
    for _ in range(20_000):
        f.step(1.0)
    assert f.x_c_m == pytest.approx(1.0 / k, rel=1e-5)  # 15 time constants B/K


@given(
    mass=st.floats(0.01, 100), damping=st.floats(1.0, 1e5), stiffness=st.floats(1.0, 1e6),
    # 0 or at least 1 µN: forces like 1e-300 give subnormal positions, where
    # floating point has no relative precision left to compare
    force=st.one_of(st.just(0.0), st.floats(1e-6, 100), st.floats(-100, -1e-6)),
    ticks=st.integers(1, 3000),
)
def test_filter_samples_the_continuous_step_response_exactly(
    mass: float, damping: float, stiffness: float, force: float, ticks: int
) -> None:
    """Under a held force the discrete filter equals the continuous solution at every
    sample instant, for any admissible impedance (scipy's expm at t = k·dt as truth)."""
    f = ImpedanceFilter(mass, damping, stiffness, 1e-3)
    for _ in range(ticks):
        f.step(force)
    a = np.array([[0.0, 1.0, 0.0], [-stiffness / mass, -damping / mass, force / mass],
                  [0.0, 0.0, 0.0]])
    x_c_true = scipy.linalg.expm(a * ticks * 1e-3)[0, 2]
    assert f.x_c_m == pytest.approx(x_c_true, rel=1e-6, abs=1e-12 * abs(force) / stiffness)


def test_estimator_uses_the_delayed_position() -> None:
    est = DelayForceEstimator(2.0e5, 0.01, 0.05, 1e-3)
    est.reset(0.0)
    forces = [est.step(1e-3 * k) for k in range(1, 40)]  # 1 mm per tick
    assert forces[-1] == pytest.approx(2.0e5 * 10 * 1e-3)
    assert forces[3] == pytest.approx(2.0e5 * 4 * 1e-3)  # history not yet full: x_e = start


def test_free_space_estimator_reads_zero_and_switches_to_contact_at_once() -> None:
    est = DelayForceEstimator(2.0e5, 0.0, 0.05, 1e-3)
    est.reset(0.0)
    assert all(est.step(1e-3 * k) == 0.0 for k in range(1, 60))
    est.set_delay(0.02)
    assert est.step(60e-3) == pytest.approx(2.0e5 * 20e-3)


def test_estimator_never_reads_tension() -> None:
    """A rising tip is not pulled by the soil: F̂ stays at 0, never negative."""
    est = DelayForceEstimator(2.0e5, 0.01, 0.05, 1e-3)
    est.reset(0.05)
    assert all(est.step(0.05 - 1e-3 * k) == 0.0 for k in range(1, 40))


def test_entering_contact_anchors_the_soil_at_the_tip() -> None:
    """Free-space motion before contact is not soil deformation."""
    est = DelayForceEstimator(2.0e5, 0.0, 0.05, 1e-3)
    est.reset(-0.03)
    for k in range(1, 30):  # fast free-space descent, 0.15 m/s
        est.step(-0.03 + 1.5e-4 * k)
    est.enter_contact(0.01, -0.03 + 1.5e-4 * 29)
    assert est.step(-0.03 + 1.5e-4 * 29) == 0.0
    assert est.step(-0.03 + 1.5e-4 * 29 + 7e-6) == pytest.approx(2.0e5 * 7e-6)


def test_late_and_bunched_samples_give_the_force_of_the_sampling_instants() -> None:
    """Feedback read late (the same sample twice), then two samples in one tick (only the
    newest kept): F̂ is held while late, and after the burst equals what on-time delivery
    gives at that instant: x(t) − x(t − α) spans α of sampling time, not of reading."""
    def x_at(k: int) -> float:  # a descent at 20 mm/s, sampled every 1 ms
        return 2e-5 * k

    on_time = DelayForceEstimator(2.0e5, 0.01, 0.05, 1e-3)
    late = DelayForceEstimator(2.0e5, 0.01, 0.05, 1e-3)
    ticks = DelayForceEstimator(2.0e5, 0.01, 0.05, 1e-3)  # counts ticks, as before
    for est in (on_time, late, ticks):
        est.reset(0.0)
    expected, got, by_ticks, held = [], [], [], []
    newest = 0  # the newest sample the late reader has
    for k in range(1, 80):
        expected.append(on_time.step(x_at(k)))
        if k % 7 == 0:  # every seventh answer comes a tick late, together with the next
            samples = 0
        elif k % 7 == 1 and k > 1:
            samples = 2
        else:
            samples = 1
        newest += samples
        held.append(samples == 0)
        got.append(late.step(x_at(newest), samples))
        by_ticks.append(ticks.step(x_at(newest)))
    for i in range(30, len(got)):
        if held[i]:
            assert got[i] == got[i - 1]
        else:
            assert got[i] == pytest.approx(expected[i], rel=1e-9)
    assert expected[-1] == pytest.approx(2.0e5 * 10 * 2e-5)  # 40 N: K_e v α
    assert max(by_ticks[30:]) == pytest.approx(2.0e5 * 11 * 2e-5)  # +10 %: one tick more


def test_a_burst_longer_than_the_history_is_recorded_as_a_straight_line() -> None:
    est = DelayForceEstimator(2.0e5, 0.01, 0.02, 1e-3)
    est.reset(0.0)
    assert est.step(1e-3, samples=100) == pytest.approx(2.0e5 * 1e-3 * 10 / 21)
    assert est.step(1e-3, samples=0) == est.f_hat_n


def test_estimator_rejects_delay_beyond_its_history() -> None:
    est = DelayForceEstimator(2.0e5, 0.0, 0.05, 1e-3)
    with pytest.raises(ConfigError, match="delay"):
        est.set_delay(0.2)
    with pytest.raises(ConfigError):
        est.set_delay(math.nan)
