"""The residual-pattern p-values of `diagnose` (Spearman's rho per pose feature): exact for a few
tests, checked against a closed form and scipy's exact permutation test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import permutation_test, rankdata, spearmanr

from vtestbed.researcher.discrepancy import EXACT_PATTERN_TESTS, residual_patterns, spearman


def test_a_perfect_order_of_three_tests_has_p_one_third():
    """Of the 3! orderings, two (rho = +1 and -1) are as extreme: p = 2/6, where the t
    approximation says 0."""
    rho, p = spearman([10.0, 20.0, 30.0], [3.0, 2.0, 1.0])
    assert rho == pytest.approx(-1.0)
    assert p == pytest.approx(1.0 / 3.0, abs=1e-12)
    assert spearmanr([10.0, 20.0, 30.0], [3.0, 2.0, 1.0]).pvalue < 1e-6  # what it replaces


@pytest.mark.parametrize("n", [5, EXACT_PATTERN_TESTS])
def test_small_samples_match_scipys_exact_permutation_test(n):
    rng = np.random.default_rng(n)
    x = np.round(rng.normal(size=n), 1)  # ties possible: ranks average them
    x[1] = x[0]
    y = x + rng.normal(scale=0.8, size=n)
    rx = rankdata(x) - rankdata(x).mean()

    def rho_of(b, axis=-1):  # scipy orders one sample every way (n! of them); rho of each, vectorised
        rb = rankdata(b, axis=axis)
        rb = rb - rb.mean(axis=axis, keepdims=True)
        return (rb @ rx) / np.sqrt((rx @ rx) * np.sum(rb**2, axis=axis))

    exact = permutation_test(
        (y,), rho_of, permutation_type="pairings", n_resamples=np.inf, vectorized=True
    ).pvalue
    rho, p = spearman(x, y)
    assert rho == pytest.approx(spearmanr(x, y).statistic, abs=1e-12)
    assert p == pytest.approx(exact, abs=1e-9)


def test_larger_samples_use_scipys_p_value_and_constant_features_are_noted():
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=20), rng.normal(size=20)
    out = residual_patterns(list(y), {"q2_deg": list(x), "q1_deg": [0.0] * 20})
    assert out["q2_deg"]["p_value"] == pytest.approx(spearmanr(x, y).pvalue, rel=1e-12)
    assert out["q1_deg"] == {"rho": None, "p_value": None, "note": "constant over the tests"}
