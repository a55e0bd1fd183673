"""Exact discretization against scipy (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rakectl.discretize import expm, zoh

# Entries are 0 or of magnitude >= 1e-6: with an entry of 2e-226 next to ones
# of order 1, hypothesis found scipy returning 0 where the exact exponential
# of the nilpotent block [[0, 0.01], [0, 0]] has 0.01 (ours gives 0.01).
ENTRY = st.one_of(st.just(0.0), st.floats(1e-6, 1e3), st.floats(-1e3, -1e-6))


@given(arrays(np.float64, (3, 3), elements=ENTRY))
def test_expm_matches_scipy(m: np.ndarray) -> None:
    m = m * 1e-2
    # Normwise, the accuracy both algorithms promise: hypothesis found scipy's Padé off by
    # 1.1e-8 relative in the entry 0.01·expm1(1e-8)/1e-8 of diag(-4.26, [[1e-8, 0.01], [0, 0]])
    # (ours exact to 3e-16), 1.1e-10 against a norm of 1.
    expected = scipy.linalg.expm(m)
    scale = max(1.0, float(np.linalg.norm(expected, 1)))
    assert float(np.linalg.norm(expm(m) - expected, 1)) <= 1e-9 * scale


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
