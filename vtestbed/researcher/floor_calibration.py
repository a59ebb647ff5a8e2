"""p-values of the discrepancy tests that allow for the noise floor being estimated.

The tests of :mod:`.diagnose` whiten by the repeat scans' floor, a 6x6 covariance estimated from
``nu`` samples (``nu = 75`` with 3 repeats of 25 tests). :class:`.model_fit.Whitener` divides out
the floor's mean inflation of a quadratic form, ``f = nu / (nu - 7)``; that fixes the mean of
chi^2, not its tail. The floor's error is shared by every test, so it moves all the statistics
together: with the plain chi^2 reference, a likelihood-ratio test at 0.01 / 14 rejected a true
baseline 2.2 times too often at ``nu = 75`` (1-df), and the detection test at 1 % rejected 2.5 %
(Monte Carlo on the paper's 20 tests with Wishart floors, 40 000 datasets;
``tests/test_floor_calibration.py`` checks this reference against such a Monte Carlo at ``nu = 40``).

The reference here is the statistic's distribution under a parametric bootstrap of the floor,
with the noise integrated out exactly. In the coordinates the floor whitens, the noise is
``N(0, I)`` if the floor is right, and a repeat of the experiment would estimate
``S* ~ Wishart(I, nu) / nu`` and whiten with ``G* = chol(S*)^-1 / sqrt(f)`` per test. Given ``S*``,
a likelihood ratio that tests the columns ``B`` beside ``A`` is ``|Q^T G*^T z|^2``, with ``Q`` an
orthonormal basis of ``G* B`` made orthogonal to ``G* A``: a sum of ``kappa_i chi^2_1``, the
``kappa_i`` the eigenvalues of ``Q^T G* G*^T Q``. Its tail is taken from a scaled chi^2 with the
same first two moments (Satterthwaite; exact for one degree of freedom), and averaged over
:data:`DRAWS` floors drawn from a Generator seeded with :data:`SEED`, so the same data give the
same p-values. The detection test (the baseline's chi^2) is the same with ``B`` the whole
complement of ``A``.

The same draws give the tests' power against a noise-free effect (:func:`lr_power`), which the
discrepancy benchmark uses to size effects "near the detection limit".

Not included: noise in the identification tests that the repeat scans do not see (the F/T
sensor's noise), which makes the tests reject more often than alpha on a lab whose floor is
underestimated, with or without this reference.

Units: dimensionless (whitened columns, chi^2).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq
from scipy.special import chdtrc, chdtri  # chi^2's survival function and its inverse, without scipy.stats

DRAWS = 400  # floors drawn per p-value: the average's relative error is about 5 % at p = 1e-3
SEED = 20231122  # the draws' Generator: p-values are a deterministic function of the data
POWER_SAMPLES = 250  # noise draws per floor draw in lr_power: 10^5 in all, a scatter of 0.2 % at 50 %
RANK_TOL = 1e-10  # singular values below this fraction of the largest: no direction


def inflation(nu: int) -> float:
    """``nu / (nu - 7)``: the mean inflation of a quadratic form in the inverse of a 6x6 covariance
    estimated from ``nu`` samples (inverse Wishart), which :class:`.model_fit.Whitener` divides out."""
    return nu / (nu - 7)


@lru_cache(maxsize=8)
def floor_whiteners(nu: int) -> np.ndarray:
    """(DRAWS, 6, 6): ``chol(S*)^-1 / sqrt(f)`` for ``S* ~ Wishart(I, nu) / nu`` (read-only).

    Bartlett's decomposition draws the Cholesky factor itself, at a cost that does not grow with
    ``nu``: ``chol(nu S*)`` is lower triangular with ``sqrt(chi^2_(nu - i))`` on its diagonal
    (``i = 0..5``) and standard normals below it."""
    rng = np.random.default_rng([SEED, nu])
    factor = np.tril(rng.standard_normal((DRAWS, 6, 6)), -1)
    factor[:, range(6), range(6)] = np.sqrt(rng.chisquare(nu - np.arange(6), size=(DRAWS, 6)))
    g = np.linalg.inv(factor / np.sqrt(nu)) / np.sqrt(inflation(nu))
    g.setflags(write=False)
    return g


def _per_test(g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(D, 6T, k): each draw's 6x6 ``g[d]`` applied to every test's 6 rows of ``x`` (6T, k)."""
    blocks = x.reshape(-1, 6, x.shape[-1])
    return np.matmul(g[:, None], blocks[None]).reshape(len(g), *x.shape)


def _basis(y: np.ndarray, rank: int | None = None) -> np.ndarray:
    """(D, N, r): orthonormal bases of the columns of each ``y[d]`` (N, k); ``rank`` directions, or
    those above :data:`RANK_TOL` of the largest (the same count for every draw: an invertible
    transform keeps the rank)."""
    if y.shape[-1] == 0:
        return y
    u, s, _ = np.linalg.svd(y, full_matrices=False)
    if rank is None:
        rank = int(np.sum(s[0] > RANK_TOL * s[0, 0]))
    return u[..., :rank]


def _tail(stat: float, s1: np.ndarray, s2: np.ndarray) -> float:
    """The mean over the draws of P(sum kappa_i chi^2_1 > stat), each from the scaled chi^2
    ``a chi^2_b`` with ``a = s2 / s1``, ``b = s1^2 / s2`` (``s1 = sum kappa``, ``s2 = sum kappa^2``)."""
    return float(np.mean(chdtrc(s1**2 / s2, stat * s1 / s2)))


def _tested_directions(g: np.ndarray, design: np.ndarray, tested: np.ndarray, df: int):
    """Per draw: ``Q`` (D, 6T, df), the orthonormal directions the tested columns add beside the
    others, and ``C = Q^T G* G*^T Q`` (D, df, df), the covariance of ``Q^T`` times the whitened noise."""
    y = _per_test(g, np.asarray(design, float))
    tested = np.asarray(tested, bool)
    base = _basis(y[..., ~tested])
    rest = y[..., tested]
    if base.shape[-1]:
        rest = rest - base @ (np.swapaxes(base, 1, 2) @ rest)
    q = _basis(rest, min(int(df), rest.shape[-1]))
    h = np.matmul(np.swapaxes(g, 1, 2)[:, None], q.reshape(len(g), -1, 6, q.shape[-1]))  # G*^T Q per test
    h = h.reshape(q.shape)
    return q, np.swapaxes(h, 1, 2) @ h


def lr_p_value(lr: float, design: np.ndarray, tested: np.ndarray, df: int, nu: int) -> float:
    """p-value of a likelihood ratio ``lr`` that tests the columns ``tested`` of ``design``.

    Parameters
    ----------
    lr : float
        ``chi2(model without the tested columns) - chi2(model with them)``, whitened as by
        :class:`.model_fit.Whitener`.
    design : (6T, k) array
        The whitened columns of the model with the tested columns.
    tested : (k,) bool array
        Which columns the test is about (a term's parameters).
    df : int
        Independent directions they add (the rank difference of the two fits).
    nu : int
        The noise floor's sample count.
    """
    if df <= 0 or not lr > 0:
        return 1.0
    _, c = _tested_directions(floor_whiteners(int(nu)), design, tested, df)
    return _tail(lr, np.trace(c, axis1=1, axis2=2), np.sum(c**2, axis=(1, 2)))


def lr_critical_value(design: np.ndarray, tested: np.ndarray, df: int, nu: int, level: float) -> float:
    """The likelihood ratio at which :func:`lr_p_value` equals ``level`` (the test rejects above it)."""
    _, c = _tested_directions(floor_whiteners(int(nu)), design, tested, df)
    return _critical_value(c, df, level)


def _critical_value(c: np.ndarray, df: int, level: float) -> float:
    """Where the tail of the draws' weighted chi^2 (``c``: :func:`_tested_directions`) is ``level``."""
    s1, s2 = np.trace(c, axis1=1, axis2=2), np.sum(c**2, axis=(1, 2))
    low, high = float(chdtri(df, level)) / 2, float(chdtri(df, level)) * 2
    while _tail(high, s1, s2) > level:  # the estimated floor widens the tail: look further out
        high *= 2
    return float(brentq(lambda lr: _tail(lr, s1, s2) - level, low, high, xtol=1e-9 * high))


def lr_power(
    residual: np.ndarray, design: np.ndarray, tested: np.ndarray, df: int, nu: int, level: float,
    samples: int = POWER_SAMPLES,
) -> float:  # fmt: skip
    """Power of the likelihood-ratio test at ``level`` against a noise-free effect, allowing for the
    floor being estimated from ``nu`` samples.

    Parameters
    ----------
    residual : (6T,) array
        The effect's noise-free residual of the model without the tested columns, whitened by the
        true floor: ``chol(floor)^-1`` per test, in which the noise is ``N(0, I)`` (so without the
        :class:`.model_fit.Whitener`'s division by ``sqrt(inflation(nu))``). A part in the span
        of the other columns does not count.
    design, tested, df, nu :
        As :func:`lr_p_value`.
    level : float
        The test's level: it rejects where :func:`lr_p_value` is below it.
    samples : int
        Noise draws per floor draw, from a Generator seeded with :data:`SEED`.

    Returns
    -------
    float
        The fraction of (floor, noise) draws whose likelihood ratio ``|Q^T G* (r + e)|^2`` exceeds
        :func:`lr_critical_value`; with the floor known it would be ``ncx2.sf(crit, df, |r|^2)``.
    """
    if df <= 0:
        return 0.0
    g = floor_whiteners(int(nu))
    q, c = _tested_directions(g, design, tested, df)
    crit = _critical_value(c, df, level)  # lr_critical_value, on the directions already computed
    shift = np.einsum("dnk,dn->dk", q, _per_test(g, np.asarray(residual, float)[:, None])[..., 0])
    z = np.random.default_rng([SEED, int(nu), int(df)]).standard_normal((len(g), samples, q.shape[-1]))
    stat = np.sum((shift[:, None, :] + z @ np.swapaxes(np.linalg.cholesky(c), 1, 2)) ** 2, axis=-1)
    return float(np.mean(stat > crit))


def fit_p_value(chi2: float, design: np.ndarray, nu: int) -> float:
    """p-value of a fit's chi^2 (the detection test): the residual of ``design`` (6T, k), whitened,
    tested against the floor; the degrees of freedom are ``6T`` less the design's rank."""
    g = floor_whiteners(int(nu))
    y = _per_test(g, np.asarray(design, float))
    qa = _basis(y)
    m = g @ np.swapaxes(g, 1, 2)  # G* G*^T per test (the same 6x6 for every test)
    n_tests = y.shape[1] // 6
    tr_m = n_tests * np.trace(m, axis1=1, axis2=2)
    tr_m2 = n_tests * np.sum(m * np.swapaxes(m, 1, 2), axis=(1, 2))
    mq = np.matmul(m[:, None], qa.reshape(len(g), n_tests, 6, -1)).reshape(qa.shape)
    qmq = np.swapaxes(qa, 1, 2) @ mq
    s1 = tr_m - np.trace(qmq, axis1=1, axis2=2)
    s2 = tr_m2 - 2 * np.sum(mq * mq, axis=(1, 2)) + np.sum(qmq**2, axis=(1, 2))
    return _tail(chi2, s1, s2)
