"""Independent continuous-time solution of the impedance loop, for tests only.

The loop of the seed paper's eq. (12) as a delay differential equation in the
state y = (x_c, ẋ_c, x):

    ẋ_c = v_c
    v̇_c = (F_d − K_e (x(t) − x(t − α)) − B_d v_c − K_d x_c) / M_d
    ẋ  = (x_d(t) + x_c − x) / τ

solved by an exponential integrator at a fine step h (≪ the controller's
1 ms period and ≪ α) with scipy's matrix exponential: the fast impedance
pole is integrated exactly, and the delayed x(t − α) and x_d(t) are held
over each fine step. It shares no code with rakectl.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg


@dataclass(frozen=True)
class LoopParams:
    mass_kg: float
    damping_ns_per_m: float
    stiffness_n_per_m: float
    env_stiffness_n_per_m: float
    delay_s: float
    time_constant_s: float
    speed_m_per_s: float
    desired_force_n: float
    duration_s: float


def solve(p: LoopParams, fine_step_s: float, sample_every_s: float) -> dict[str, np.ndarray]:
    """x(t), x_c(t), F̂(t) sampled every ``sample_every_s`` (a multiple of the fine step)."""
    m, b, k, ke, tau = (p.mass_kg, p.damping_ns_per_m, p.stiffness_n_per_m,
                        p.env_stiffness_n_per_m, p.time_constant_s)
    # inputs u = (x_d, x_delayed, 1)
    a = np.array([[0, 1, 0], [-k / m, -b / m, -ke / m], [1 / tau, 0, -1 / tau]])
    bu = np.array([[0, 0, 0], [0, ke / m, p.desired_force_n / m], [1 / tau, 0, 0]])
    aug = np.zeros((6, 6))
    aug[:3, :3], aug[:3, 3:] = a, bu
    phi = scipy.linalg.expm(aug * fine_step_s)
    ad, bd = phi[:3, :3], phi[:3, 3:]
    steps = round(p.duration_s / fine_step_s)
    delay_steps = round(p.delay_s / fine_step_s)
    every = round(sample_every_s / fine_step_s)
    history = np.zeros(steps + 1)  # x at each fine step; x(t<0) = x(0) = 0
    y = np.zeros(3)
    samples = []
    for n in range(steps):
        x_delayed = history[n - delay_steps] if n >= delay_steps else 0.0
        if n % every == 0:
            samples.append((n * fine_step_s, y[2], y[0], ke * (y[2] - x_delayed)))
        t_mid = (n + 0.5) * fine_step_s  # ramp held at its mid-step value
        y = ad @ y + bd @ np.array([p.speed_m_per_s * t_mid, x_delayed, 1.0])
        history[n + 1] = y[2]
    t, x, x_c, f_hat = (np.array(col) for col in zip(*samples, strict=True))
    return {"t_s": t, "x_m": x, "x_c_m": x_c, "f_hat_n": f_hat}
