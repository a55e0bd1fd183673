"""The load-time stability check's loop against independent computations of the same loop."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from rakectl.config.settings import EstimatorSettings, ImpedanceSettings
from rakectl.core.stability import MAX_DELAY_TICKS, loop_matrix, spectral_radius
from rakectl.sim.plants import FirstOrderLoop
from rakectl.sim.scenario import PlantSettings, Scenario

# (M_d, B_d, K_d, K_e, α ticks, τ, dt)
Case = tuple[float, float, float, float, int, float, float]
PAPER: Case = (0.39, 1.33e4, 1.0e4, 2.0e5, 10, 0.2, 1e-3)
SLIP: Case = (0.39, 13.3, 1.0e4, 2.0e5, 10, 0.2, 1e-3)  # B_d 13.3 N·s/mm entered as N·s/m
CASES: list[Case] = [
    PAPER, SLIP,
    (0.39, 133.0, 1.0e4, 2.0e5, 10, 0.2, 1e-3),
    (0.39, 1.0e3, 1.0e4, 2.0e5, 50, 0.2, 1e-3),
    (2.0, 2.0e3, 5.0e3, 5.0e4, 20, 0.1, 1e-3),
    (1.0, 300.0, 1.0e4, 1.0e5, 5, 0.05, 1e-3),
    (0.39, 1.33e4, 1.0e4, 2.0e5, 1, 0.2, 0.02),  # config/rakectl-vcan.yaml: 50 Hz
    (0.39, 1.33e4, 1.0e4, 2.0e5, 0, 0.2, 1e-3),  # free space: F̂ ≡ 0
]


def _scipy_matrix(m: float, b: float, k: float, ke: float, d: int, tau: float,
                  dt: float) -> np.ndarray:
    """The same loop built with scipy's zero-order hold (as the review built it)."""
    a = np.array([[0.0, 1.0], [-k / m, -b / m]])
    ad, bd, *_ = scipy.signal.cont2discrete((a, np.array([[0.0], [1.0 / m]]), np.eye(2),
                                             np.zeros((2, 1))), dt, "zoh")
    decay = math.exp(-dt / tau)
    t = np.zeros((3 + d, 3 + d))
    t[0:2, 0:2] = ad
    t[0:2, 2] += -bd[:, 0] * ke
    t[0:2, 2 + d] += bd[:, 0] * ke
    t[2, 2], t[2, 0] = decay, 1.0 - decay
    for j in range(d):
        t[3 + j, 2 + j] = 1.0
    return t


def _simulated_growth(m: float, b: float, k: float, ke: float, d: int, tau: float,
                      dt: float, ticks: int) -> float:
    """Per-tick growth of the difference equations run directly from a displaced start:
    the ratio of the state's largest size over the last ``ticks`` to that over the
    ``ticks`` before, to the power 1/ticks, after ``ticks`` for the faster modes to fade
    (→ the spectral radius)."""
    a = np.array([[0.0, 1.0, 0.0], [-k / m, -b / m, 1.0 / m], [0.0, 0.0, 0.0]])
    phi = scipy.linalg.expm(a * dt)
    ad, bd = phi[:2, :2], phi[:2, 2]
    decay = math.exp(-dt / tau)
    x_c, x = np.array([1e-3, 0.0]), [0.0] * (d + 1)  # x[k], x[k−1], …, x[k−d]
    sizes = []
    for _ in range(3 * ticks):
        f_hat = ke * (x[0] - x[d])
        x_new = decay * x[0] + (1.0 - decay) * x_c[0]
        x_c = ad @ x_c - bd * f_hat
        x = [x_new, *x[:d]]
        sizes.append(math.hypot(x_c[0], x[0]))
    return float((max(sizes[2 * ticks:]) / max(sizes[ticks:2 * ticks])) ** (1.0 / ticks))


def test_the_papers_values_are_stable_and_the_unit_slip_is_not() -> None:
    assert spectral_radius(*PAPER) == pytest.approx(0.999359, abs=1e-6)
    assert spectral_radius(*SLIP) == pytest.approx(1.0265, abs=1e-4)


@pytest.mark.parametrize("case", CASES)
def test_eigenvalues_match_the_loop_built_with_scipy(case: Case) -> None:
    ours = np.sort_complex(np.linalg.eigvals(loop_matrix(*case)))
    theirs = np.sort_complex(np.linalg.eigvals(_scipy_matrix(*case)))
    assert np.allclose(ours, theirs, atol=1e-9)


@pytest.mark.parametrize("case", CASES[:6])
def test_the_radius_is_the_growth_of_a_direct_simulation(case: Case) -> None:
    radius = spectral_radius(*case)
    growth = _simulated_growth(*case, ticks=4000)
    assert (growth > 1.0) == (radius > 1.0)
    assert growth == pytest.approx(radius, abs=1e-4)


def _code_loop(damping_ns_per_m: float) -> list[float]:
    """F̂ over 20 s of the paper's ramp, run by the simulation's own FirstOrderLoop and
    controller (bypassing the load-time check)."""
    settings = dataclasses.replace(
        Scenario(), impedance=ImpedanceSettings(0.39, damping_ns_per_m, 1.0e4),
        estimator=EstimatorSettings(2.0e5, 0.01), plant=PlantSettings(time_constant_s=0.2))
    loop = FirstOrderLoop(settings, 0.0)
    loop.reset()
    forces = []
    for tick in range(20_000):
        loop.step(math.nan, 0.007 * tick * 1e-3, True)
        forces.append(loop.row()[4])
    return forces


def test_the_controllers_own_loop_diverges_where_the_radius_exceeds_one() -> None:
    """The model is the code's: the paper's B_d settles at 14 N, 13.3 N·s/m blows up."""
    assert _code_loop(1.33e4)[-1] == pytest.approx(14.0, abs=0.05)
    assert not max(_code_loop(13.3)) < 1e6  # inf and NaN too


def test_a_delay_beyond_the_checked_range_is_refused() -> None:
    with pytest.raises(ValueError, match="delay_ticks"):
        loop_matrix(*PAPER[:4], MAX_DELAY_TICKS + 1, 0.2, 1e-3)
