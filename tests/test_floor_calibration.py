"""The discrepancy tests' p-values against a floor estimated from few samples
(vtestbed/researcher/floor_calibration.py), checked against brute force.

Reference: a Monte Carlo of the whole procedure under the null on a random design (8 tests, 6
compliance-like columns, a 1- and a 3-column candidate): Wishart floors with ``nu`` samples,
Gaussian noise, the researcher's :class:`Whitener` and least squares, then the fraction of
statistics beyond a threshold. The calibrated survival function (with the true floor as its
plug-in, so that it is one function of the threshold) must match those fractions within their
binomial scatter and the draws' own (10 % at the 0.9 quantile, 20 % at the 0.99 one), where the
plain chi^2 reference is off by a factor 1.8-3.4 at the 0.99 quantile with ``nu = 40``.
"""

import numpy as np
import pytest
from scipy.special import chdtrc
from scipy.stats import chi2 as chi2_dist
from scipy.stats import ncx2

from vtestbed.researcher.floor_calibration import (
    fit_p_value,
    floor_whiteners,
    inflation,
    lr_critical_value,
    lr_p_value,
    lr_power,
)
from vtestbed.researcher.model_fit import Whitener
from vtestbed.researcher.noise_floor import NoiseFloor

NU, TESTS, REPS = 40, 8, 40_000
THETA = 0.55  # the alternative's size: noncentrality about 15 with the floor known (power 0.9 at 1 %)
SIGMA = np.array([5e-6, 6e-6, 4e-6, 9e-6, 8e-6, 1e-5])  # a floor with unequal components


@pytest.fixture(scope="module")
def null_run():
    """The statistics of REPS null datasets (vectorised over the datasets: each whitened by its
    own floor estimate as :class:`Whitener` does, then least squares by QR), and the design."""
    rng = np.random.default_rng(5)
    n = 6 * TESTS
    scale = np.tile(SIGMA, TESTS)
    a = rng.standard_normal((n, 6)) * scale[:, None]
    b = rng.standard_normal((n, 3)) * scale[:, None]
    designs = {1: np.hstack([a, b[:, :1]]), 3: np.hstack([a, b])}
    z = rng.standard_normal((REPS, NU, 6)) * SIGMA
    floors = np.einsum("rni,rnj->rij", z, z) / NU
    g = np.stack([Whitener(NoiseFloor(f, NU, TESTS)).inv_chol for f in floors[:50]])  # the class's own
    g_all = np.linalg.inv(np.linalg.cholesky(floors)) / np.sqrt(inflation(NU))
    np.testing.assert_allclose(g_all[:50], g, rtol=1e-10)  # the vectorised whitening is the class's
    noise = rng.standard_normal((REPS, n)) * scale

    def whitened(data):  # (REPS, n): each dataset whitened by its own floor estimate
        return np.einsum("rij,rtj->rti", g_all, data.reshape(REPS, TESTS, 6)).reshape(REPS, n)

    def chi2(d, x):
        q = np.linalg.qr(np.einsum("rij,tjk->rtik", g_all, x.reshape(TESTS, 6, -1)).reshape(REPS, n, -1))[0]
        return np.sum((d - np.einsum("rnk,rk->rn", q, np.einsum("rnk,rn->rk", q, d))) ** 2, axis=1)

    d = whitened(noise)  # the baseline is true: A c = 0
    base = chi2(d, a)
    stats = {"detect": base, 1: base - chi2(d, designs[1]), 3: base - chi2(d, designs[3])}
    # the alternative: the 1-column candidate's effect, THETA times its column, hidden in the data
    d_alt = whitened(noise + THETA * b[:, 0])
    stats["alt"] = chi2(d_alt, a) - chi2(d_alt, designs[1])
    true_white = Whitener(NoiseFloor(np.diag(SIGMA**2), NU, TESTS))
    return stats, true_white, a, designs


@pytest.mark.parametrize("df", [1, 3])
def test_the_likelihood_ratio_tail_matches_brute_force(null_run, df):
    stats, white, _, designs = null_run
    tested = np.r_[np.zeros(6, bool), np.ones(df, bool)]
    for q, rel in ((0.9, 0.1), (0.99, 0.2)):
        t = float(np.quantile(stats[df], q))
        assert lr_p_value(t, white(designs[df]), tested, df, NU) == pytest.approx(1 - q, rel=rel)
    # the plain chi^2 tail, which the calibration corrects, is outside that tolerance
    assert chdtrc(df, float(np.quantile(stats[df], 0.99))) < 0.75 * 0.01


def test_power_against_a_hidden_effect_matches_brute_force(null_run):
    """The fraction of the brute force's alternative datasets beyond the calibrated critical value
    is what :func:`lr_power` predicts (binomial scatter 0.002, the draws' 0.01); the power computed
    as if the floor were known is off by more than that tolerance."""
    stats, white, a, designs = null_run
    tested, level = np.r_[np.zeros(6, bool), True], 0.01
    x = white(designs[1])
    crit = lr_critical_value(x, tested, 1, NU, level)
    assert lr_p_value(crit, x, tested, 1, NU) == pytest.approx(level, rel=1e-6)
    brute = float(np.mean(stats["alt"] > crit))
    signal = x[:, 6] * THETA * np.sqrt(inflation(NU))  # whitened by the true floor, no inflation
    predicted = lr_power(signal, x, tested, 1, NU, level)
    assert predicted == pytest.approx(brute, abs=0.03)
    lam = signal @ signal - signal @ x[:, :6] @ np.linalg.lstsq(x[:, :6], signal, rcond=None)[0]
    known = ncx2.sf(chi2_dist.isf(level, 1), 1, lam)
    assert abs(known - brute) > 0.04


def test_the_detection_tail_matches_brute_force(null_run):
    stats, white, a, _ = null_run
    for q, rel in ((0.9, 0.1), (0.99, 0.2)):
        t = float(np.quantile(stats["detect"], q))
        assert fit_p_value(t, white(a), NU) == pytest.approx(1 - q, rel=rel)
    assert chdtrc(6 * TESTS - 6, float(np.quantile(stats["detect"], 0.99))) < 0.5 * 0.01


def test_a_floor_known_exactly_gives_the_chi2_reference():
    """With 10^6 samples the floor's uncertainty vanishes: the calibrated p-values are chi^2's."""
    rng = np.random.default_rng(3)
    x = rng.standard_normal((48, 9))
    tested = np.r_[np.zeros(6, bool), np.ones(3, bool)]
    assert lr_p_value(9.0, x, tested, 3, 10**6) == pytest.approx(chdtrc(3, 9.0), rel=2e-3)
    assert fit_p_value(50.0, x[:, :6], 10**6) == pytest.approx(chdtrc(42, 50.0), rel=2e-3)


def test_draws_are_seeded_and_read_only():
    g = floor_whiteners(NU)
    assert g is floor_whiteners(NU) and not g.flags.writeable
    # each draw whitens its own floor estimate: g S g^T = I / f, and S averages to the identity
    s = np.linalg.inv(np.einsum("dji,djk->dik", g, g)) / inflation(NU)
    assert np.mean(s, axis=0) == pytest.approx(np.eye(6), abs=0.05)  # 4.5 standard errors at nu = 40


def test_nothing_to_test_gives_one():
    x = np.eye(12)[:, :7]
    assert lr_p_value(0.0, x, np.r_[np.zeros(6, bool), True], 1, NU) == 1.0
    assert lr_p_value(5.0, x, np.r_[np.zeros(6, bool), True], 0, NU) == 1.0
