"""The shared 6 x 6 noise estimators (fgls_pooled, fgls6) on synthetic linear data with a known
correlated displacement noise: against the sample covariance of many draws and the GLS bound."""

import warnings

import numpy as np
import pytest

from vtestbed.researcher.fgls import fgls
from vtestbed.researcher.gls_full import fgls_batch, shared_covariance
from vtestbed.researcher.identify import identify, stack

K = np.array([2.2e6, 9.0e5, 1.1e6, 6.4e4, 2.5e4, 2.0e4])  # N*m/rad, the KR60's order of magnitude
C = 1.0 / K


def drift_noise() -> np.ndarray:
    """(6, 6) displacement covariance of a scanner 0.6 m away whose rigid drift couples
    translation and rotation (docs/poses.md): 2 (P_drift + point noise) [m^2 | rad^2]."""
    r = np.full(3, 0.6 / np.sqrt(3.0))
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    lin = np.eye(6)
    lin[:3, 3:] = -skew
    drift = lin @ np.diag([3e-6**2] * 3 + [5e-6**2] * 3) @ lin.T
    return 2.0 * (drift + np.diag([0.22e-6**2] * 3 + [3.5e-6**2] * 3))


def problem(n_tests: int, seed: int):
    """Random Jacobians (m and 1 scaled as an arm's) and wrenches of T tests; their A (T, 6, n)."""
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(n_tests, 6, 6))
    jac[:, :3] *= 1.5  # [m]
    wrench = np.concatenate(
        [rng.normal(size=(n_tests, 3)) * 150.0, rng.normal(size=(n_tests, 3)) * 20.0], axis=1
    )
    a3 = stack(jac, wrench).reshape(n_tests, 6, 6)
    return jac, wrench, a3


def draws(a3, sigma, n_draws, seed):
    rng = np.random.default_rng(seed)
    return (a3 @ C)[None] + rng.standard_normal((n_draws, a3.shape[0], 6)) @ np.linalg.cholesky(sigma).T


def test_shared_covariance_is_unbiased_at_fixed_weights():
    sigma = drift_noise()
    _, _, a3 = problem(12, 1)
    weight = np.diag(1.0 / np.diag(sigma))
    normal = np.einsum("tki,kl,tlj->ij", a3, weight, a3)
    bread = np.linalg.inv(normal)
    est, naive = [], []
    for d in draws(a3, sigma, 2000, 2):
        c = bread @ np.einsum("tki,kl,tl->i", a3, weight, d)
        res = d - a3 @ c
        est.append(shared_covariance(a3, res, weight, bread))
        naive.append(res.T @ res / 12)
    mean = np.mean(est, axis=0)
    d = np.sqrt(np.diag(sigma))
    # every entry within 0.06 of the diagonal scale (2000 draws of 11 dof: about 0.01 statistical)
    assert np.max(np.abs(mean - sigma) / np.outer(d, d)) < 0.06
    # the residuals alone are visibly smaller: 6 of 72 degrees of freedom went into the fit
    assert np.mean(np.diag(np.mean(naive, axis=0)) / np.diag(sigma)) < 0.95


def test_fgls_batch_repeats_identify_fgls():
    _, _, a3 = problem(9, 3)
    d = draws(a3, drift_noise(), 5, 4) - a3 @ C  # noise only, as the bootstrap passes it
    batch = fgls_batch(a3, d, 5)
    for b in range(5):
        c, _, _ = fgls(a3.reshape(-1, 6), d[b].reshape(-1), 9, 6, 5)
        np.testing.assert_allclose(batch[b], c, rtol=1e-9)


def test_fgls_pooled_keeps_fgls_compliances_and_its_std_matches_the_spread():
    sigma = drift_noise()
    jac, wrench, a3 = problem(12, 5)
    data = draws(a3, sigma, 2000, 6)
    est, jack = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for d in data:
            res = identify(jac, wrench, d, method="fgls")
            est.append(res.compliance)
            jack.append(np.diag(res.compliance_cov))
        pooled = [identify(jac, wrench, d, method="fgls_pooled") for d in data[:120]]
    for p, c in zip(pooled, est):
        assert np.array_equal(p.compliance, c)  # the same estimate, bit for bit
    spread = np.std(est, axis=0, ddof=1)  # 2000 draws: about 1.6 % statistical
    ratio = np.sqrt(np.mean([np.diag(p.compliance_cov) for p in pooled], axis=0)) / spread
    jack_ratio = np.sqrt(np.mean(jack, axis=0)) / spread
    print(f"\nreported/spread, fgls_pooled {np.round(ratio, 3)}; fgls (jackknife) {np.round(jack_ratio, 3)}")
    assert np.all((ratio > 0.85) & (ratio < 1.12))
    # the delete-one jackknife overstates it here (12 tests: a test's leverage is 0.5 on average)
    assert np.mean(jack_ratio) > np.mean(ratio) + 0.1


def test_fgls6_reaches_the_gls_bound_with_many_tests_but_its_analytic_std_is_optimistic():
    sigma = drift_noise()
    jac, wrench, a3 = problem(60, 7)
    bound = np.linalg.inv(np.einsum("tki,kl,tlj->ij", a3, np.linalg.inv(sigma), a3))
    weight = np.diag(1.0 / np.diag(sigma))  # the per-component weights fgls converges to
    bread = np.linalg.inv(np.einsum("tki,kl,tlj->ij", a3, weight, a3))
    diag_limit = bread @ np.einsum("tki,kl,lm,mp,tpj->ij", a3, weight, sigma, weight, a3) @ bread
    full, reported = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for d in draws(a3, sigma, 1000, 8):
            res = identify(jac, wrench, d, method="fgls6")
            full.append(res.compliance)
            reported.append(np.diag(res.compliance_cov))
    var_full = np.var(full, axis=0, ddof=1)
    efficiency = np.diag(bound) / var_full  # <= 1 up to the 1000 draws' 4.5 % scatter
    print(f"\nfgls6 efficiency {np.round(efficiency, 3)}")
    assert np.all((efficiency > 0.85) & (efficiency < 1.1))
    # (A^T Sigma^-1 A)^-1 with the estimated Sigma leaves out the 21 numbers' own scatter: about
    # 0.8 of the variance at 60 tests (docs/uncertainty.md; worse at 12-20 tests)
    optimism = np.mean(reported, axis=0) / var_full
    print(f"fgls6 reported / Monte Carlo variance {np.round(optimism, 3)}")
    assert np.all((optimism > 0.65) & (optimism < 0.95))
    # the per-component FGLS limit (closed-form sandwich) is below the bound on this noise
    assert np.all(np.diag(bound) / np.diag(diag_limit) < 0.97)


@pytest.mark.parametrize("method", ["fgls6", "fgls_pooled"])
def test_noise_free_data_give_the_truth(method):
    jac, wrench, a3 = problem(10, 9)
    res = identify(jac, wrench, a3 @ C, method=method)
    np.testing.assert_allclose(res.compliance, C, rtol=1e-9)
    assert np.all(np.sqrt(np.diag(res.compliance_cov)) < 1e-9 * C)
