"""Exact discretization against scipy (an independent implementation)."""

from __future__ import annotations

import decimal

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rakectl.core.discretize import expm, zoh

# Entries are 0 or of magnitude >= 1e-6: with an entry of 2e-226 next to ones
# of order 1, hypothesis found scipy returning 0 where the exact exponential
# of the nilpotent block [[0, 0.01], [0, 0]] has 0.01 (ours gives 0.01).
ENTRY = st.one_of(st.just(0.0), st.floats(1e-6, 1e3), st.floats(-1e3, -1e-6))


def _expm_40_digits(m: np.ndarray) -> np.ndarray:
    """e^M in 40-digit decimal arithmetic (scaling and squaring, 60 Taylor terms): a
    reference whose own rounding is far below float64's."""
    with decimal.localcontext() as ctx:
        ctx.prec = 40
        a = [[decimal.Decimal(float(x)) for x in row] for row in m]
        squarings = max(0, int(np.ceil(np.log2(max(np.abs(m).sum(axis=0).max(), 1e-300))))
                        + 4)
        a = [[x / (2 ** squarings) for x in row] for row in a]
        n = len(a)

        def mul(x: list[list[decimal.Decimal]], y: list[list[decimal.Decimal]]
                ) -> list[list[decimal.Decimal]]:
            return [[sum((x[i][k] * y[k][j] for k in range(n)), decimal.Decimal(0))
                     for j in range(n)] for i in range(n)]

        eye = [[decimal.Decimal(int(i == j)) for j in range(n)] for i in range(n)]
        result = [row[:] for row in eye]
        for k in range(60, 0, -1):  # Horner: I + A/1 (I + A/2 (I + …))
            product = mul(a, result)
            result = [[eye[i][j] + product[i][j] / k for j in range(n)] for i in range(n)]
        for _ in range(squarings):
            result = mul(result, result)
        return np.array([[float(x) for x in row] for row in result])


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (3, 3), elements=ENTRY))
def test_expm_matches_scipy_and_a_40_digit_reference(m: np.ndarray) -> None:
    """Against the 40-digit reference, normwise to 1e-13; against scipy's Padé (an
    independent algorithm) to 1e-7 only: on blocks of very different scales hypothesis
    found scipy off by 1.1e-8 relative in an entry where ours was exact (0.01·expm1(1e-8)
    /1e-8 beside −4.26), so scipy cannot be the tight reference."""
    m = m * 1e-2
    ours = expm(m)
    exact = _expm_40_digits(m)
    scale = max(1.0, float(np.linalg.norm(exact, 1)))
    assert float(np.linalg.norm(ours - exact, 1)) <= 1e-13 * scale
    assert float(np.linalg.norm(ours - scipy.linalg.expm(m), 1)) <= 1e-7 * scale


@given(arrays(np.float64, (3, 3), elements=st.floats(-5, 5)))
def test_expm_of_minus_a_is_its_inverse(m: np.ndarray) -> None:
    """e^A e^−A = I, a check that needs no other implementation (to within the
    rounding that the product's conditioning ‖e^A‖·‖e^−A‖ allows)."""
    plus, minus = expm(m), expm(-m)
    conditioning = np.linalg.norm(plus, 1) * np.linalg.norm(minus, 1)
    assert np.abs(plus @ minus - np.eye(3)).max() <= 1e-13 * conditioning


def test_expm_of_a_nilpotent_block_is_exact() -> None:
    m = np.array([[2e-226, 0.01, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 4.26]])
    result = expm(m)
    assert result[0, 1] == pytest.approx(0.01, rel=1e-12)
    assert result[2, 2] == pytest.approx(np.exp(4.26), rel=1e-12)


def test_zoh_matches_scipy_cont2discrete_on_the_paper_filter() -> None:
    a = np.array([[0.0, 1.0], [-1.0e4 / 0.39, -1.33e4 / 0.39]])
    b = np.array([[0.0], [1.0 / 0.39]])
    ad, bd = zoh(a, b, 1e-3)
    ad_ref, bd_ref, *_ = scipy.signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), 1e-3)
    assert np.allclose(ad, ad_ref, rtol=1e-10, atol=1e-14)
    assert np.allclose(bd, bd_ref, rtol=1e-10, atol=1e-14)


def test_expm_rejects_non_finite_input() -> None:
    with pytest.raises(ValueError, match="non-finite"):
        expm(np.array([[np.nan]]))


def test_zoh_rejects_non_positive_period() -> None:
    with pytest.raises(ValueError, match="dt_s"):
        zoh(np.eye(1), np.eye(1), 0.0)
