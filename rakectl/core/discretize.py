"""Exact zero-order-hold discretization of linear time-invariant systems.

ẋ = A x + B u with u held over each period dt becomes x[k+1] = A_d x[k] + B_d u[k]
with A_d = e^{A dt} and B_d = ∫₀^dt e^{A s} ds B, both read off one matrix
exponential of the augmented matrix [[A, B], [0, 0]]·dt (Van Loan, 1978).
Exact for any pole, however fast: forward Euler at 1 kHz diverges on the
paper's impedance filter, whose fast pole is at −B_d/M_d ≈ −3.4·10⁴ rad/s.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Matrix = NDArray[np.float64]

_TAYLOR_TERMS = 18  # at ‖M‖₁ ≤ 0.25 the truncation error is below 1e-25
_SCALED_NORM = 0.25


def expm(m: Matrix) -> Matrix:
    """Matrix exponential by scaling and squaring with a truncated Taylor series."""
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError("expm: matrix has non-finite entries")
    norm = float(np.linalg.norm(m, 1))
    squarings = max(0, math.ceil(math.log2(norm / _SCALED_NORM))) if norm > 0 else 0
    scaled = m / 2.0**squarings
    eye = np.eye(m.shape[0])
    result = eye.copy()
    for k in range(_TAYLOR_TERMS, 0, -1):  # Horner: I + M/1 (I + M/2 (I + …))
        result = eye + scaled @ result / k
    for _ in range(squarings):
        result = result @ result
    return result


def zoh(a: Matrix, b: Matrix, dt_s: float) -> tuple[Matrix, Matrix]:
    """(A_d, B_d) of ẋ = A x + B u under a zero-order hold of period dt_s."""
    if not dt_s > 0:
        raise ValueError(f"zoh: dt_s must be > 0, got {dt_s}")
    a = np.atleast_2d(np.asarray(a, dtype=np.float64))
    b = np.asarray(b, dtype=np.float64).reshape(a.shape[0], -1)
    n, m = b.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n] = a
    augmented[:n, n:] = b
    phi = expm(augmented * dt_s)
    return phi[:n, :n], phi[:n, n:]
