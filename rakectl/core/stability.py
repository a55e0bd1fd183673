"""Stability of the nominal discrete impedance loop (pure).

The loop of the seed paper's eq. (12) as the controller runs it, one state per
tick: the impedance filter discretized by zero-order hold with F̂ held over the
period (:class:`rakectl.core.impedance.ImpedanceFilter`), the position loop's
nominal first-order response P(s) = 1/(τs + 1) under a zero-order hold of
x_ref = x_d + x_c (:class:`rakectl.sim.plants.FirstOrderLoop`), and the
estimator F̂ = K_e (x[k] − x[k − d]) over a line of d = α/dt delayed positions
(:class:`rakectl.core.impedance.DelayForceEstimator`, unfloored: the linear
loop). The state is (x_c, ẋ_c, x[k], x[k−1], …, x[k−d]); x_d and F_d are inputs
and do not change stability. The loop is stable when every eigenvalue of its
transition matrix lies inside the unit circle.
"""

from __future__ import annotations

import numpy as np

from rakectl.core.discretize import Matrix, zoh

# At most this many ticks of delay are checked (0.25 s at 1 kHz): the eigenvalues of the
# (d + 3)-square transition matrix cost O(d³), about 0.3 s at 250 ticks on a 2-core
# machine, and a load checks several position loops.
MAX_DELAY_TICKS = 250


def loop_matrix(mass_kg: float, damping_ns_per_m: float, stiffness_n_per_m: float,
                env_stiffness_n_per_m: float, delay_ticks: int, time_constant_s: float,
                dt_s: float) -> Matrix:
    """The transition matrix of the state (x_c, ẋ_c, x[k], …, x[k − delay_ticks])."""
    if not 0 <= delay_ticks <= MAX_DELAY_TICKS:
        raise ValueError(f"loop_matrix: delay_ticks must be in 0 … {MAX_DELAY_TICKS}, "
                         f"got {delay_ticks}")
    a = np.array([[0.0, 1.0], [-stiffness_n_per_m / mass_kg, -damping_ns_per_m / mass_kg]])
    filter_a, filter_b = zoh(a, np.array([[0.0], [1.0 / mass_kg]]), dt_s)
    loop_a, loop_b = zoh(np.array([[-1.0 / time_constant_s]]),
                         np.array([[1.0 / time_constant_s]]), dt_s)
    d = delay_ticks
    t = np.zeros((3 + d, 3 + d))
    t[0:2, 0:2] = filter_a
    t[0:2, 2] -= filter_b[:, 0] * env_stiffness_n_per_m  # −F̂ = −K_e x[k] …
    t[0:2, 2 + d] += filter_b[:, 0] * env_stiffness_n_per_m  # … + K_e x[k − d]
    t[2, 2] = loop_a[0, 0]
    t[2, 0] = loop_b[0, 0]  # x_ref = x_d + x_c, with x_c before this tick's filter step
    for j in range(d):  # the delay line shifts by one tick
        t[3 + j, 2 + j] = 1.0
    return t


def spectral_radius(mass_kg: float, damping_ns_per_m: float, stiffness_n_per_m: float,
                    env_stiffness_n_per_m: float, delay_ticks: int, time_constant_s: float,
                    dt_s: float) -> float:
    """The largest eigenvalue modulus of :func:`loop_matrix`: < 1 is a stable loop."""
    t = loop_matrix(mass_kg, damping_ns_per_m, stiffness_n_per_m, env_stiffness_n_per_m,
                    delay_ticks, time_constant_s, dt_s)
    return float(np.max(np.abs(np.linalg.eigvals(t))))
