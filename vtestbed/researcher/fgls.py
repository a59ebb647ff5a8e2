"""Feasible GLS with one noise variance per displacement component, and its jackknife covariance.

The ``fgls`` estimator of :mod:`.identify` (docs/uncertainty.md): rows of the stacked system
``delta_d = A c`` (6 T, n) are scaled by the inverse noise std of their component (x, y, z [m],
rx, ry, rz [rad]), re-estimated from the residuals of the previous fit; the covariance of the
compliances [rad/(N*m)]^2 is a delete-one-test jackknife. Every cost is linear in the tests T:
the weights are a row scale, never a dense (6 T, 6 T) matrix, and the jackknife's T refits are
downdates of per-component normal equations.

With few tests the six variances cannot be estimated: a component's T residuals can be fitted
exactly once T <= n, its variance collapses to zero and its weight runs away (z-scores of 1e7
at 3 tests, 2-76 at 4-5). Below :data:`PER_COMPONENT_MIN_TESTS` the components therefore share
noise levels (:func:`noise_levels`): one for the translations [m] and one for the rotations
[rad] while each level keeps :data:`LEVEL_MIN_DOF` residual degrees of freedom, else one for
all; and the analytic covariance is widened by the Student factor ``nu / (nu - 2)`` of the
levels' degrees of freedom (:func:`small_sample_factor`). docs/uncertainty.md, "Few tests".
"""

from __future__ import annotations

import numpy as np


def solve_weighted(aw: np.ndarray, dw: np.ndarray):
    """Least squares on the whitened system (6 T, n), (6 T,); returns c and (A^T W A)^-1."""
    norms = np.linalg.norm(aw, axis=0)
    u, s, vt = np.linalg.svd(aw / norms, full_matrices=False)  # column-scaled: SVD of a (6 T, n)
    c = (vt.T @ ((u.T @ dw) / s)) / norms
    cov = ((vt.T / s**2) @ vt) / np.outer(norms, norms)
    return c, cov


PER_COMPONENT_MIN_TESTS = 8  # one variance per component from this many tests on (jackknife too)
LEVEL_MIN_DOF = 9  # residual degrees of freedom each shared noise level needs below that
PER_COMPONENT = np.arange(6)  # the noise level of each component x, y, z, rx, ry, rz
TRANSLATION_ROTATION = np.array([0, 0, 0, 1, 1, 1])
ONE_LEVEL = np.zeros(6, dtype=int)


def noise_levels(n_tests: int, n: int) -> np.ndarray:
    """Which noise level each displacement component shares (6,) for a fit of T tests, n joints.

    One per component from :data:`PER_COMPONENT_MIN_TESTS` tests on; below, translation and
    rotation while each of the two keeps :data:`LEVEL_MIN_DOF` residual degrees of freedom
    (``3 T - n / 2``: 4 tests for 6 joints), else one level for all (module docstring).
    """
    if n_tests >= PER_COMPONENT_MIN_TESTS:
        return PER_COMPONENT
    if level_dof(TRANSLATION_ROTATION, n_tests, n) >= LEVEL_MIN_DOF:
        return TRANSLATION_ROTATION
    return ONE_LEVEL


def _dof_per_level(levels: np.ndarray, n_tests: int, n: int) -> np.ndarray:
    """Residual degrees of freedom of each noise level: its ``m`` components' ``m T`` equations
    less their share ``m n / 6`` of the n parameters."""
    members = np.bincount(levels)
    return members * n_tests - members * n / 6.0


def level_dof(levels: np.ndarray, n_tests: int, n: int) -> float:
    """Residual degrees of freedom of the smallest noise level (:func:`_dof_per_level`)."""
    return float(np.min(_dof_per_level(levels, n_tests, n)))


def small_sample_factor(levels: np.ndarray, n_tests: int, n: int) -> float:
    """Variance factor ``nu / (nu - 2)`` of a Student t with the levels' ``nu`` degrees of
    freedom (:func:`level_dof`): a coefficient scaled by a variance estimated from ``nu``
    residuals is t-distributed, whose variance is that much above the normal's. ``inf`` when
    ``nu <= 2`` (no finite variance)."""
    nu = level_dof(levels, n_tests, n)
    return nu / (nu - 2.0) if nu > 2.0 else float("inf")


def next_std(ss: np.ndarray, n_tests: int, n: int, levels: np.ndarray = PER_COMPONENT):
    """FGLS update: noise std per component (..., 6) from residual sums of squares (..., 6), the
    components of a level sharing one, and whether the fit was exact (no information on the
    noise: fall back to unit weights)."""
    pooled = ss @ np.eye(levels.max() + 1)[levels]  # (..., levels); exact sums for PER_COMPONENT
    dof_share = np.maximum(_dof_per_level(levels, n_tests, n), 1.0)  # n parameters over 6
    std = np.sqrt(pooled / dof_share)[..., levels]
    exact = (6 * n_tests <= n) | ~np.any(std > 0, axis=-1)
    return np.maximum(std, 1e-9 * std.max(axis=-1, keepdims=True)), exact


def fgls(a: np.ndarray, d_flat: np.ndarray, n_tests: int, n: int, iterations: int, levels=None):
    """Least squares weighted by noise variances re-estimated from the residuals: one per
    component, or shared by the components of a level with few tests (``levels`` (6,), default
    :func:`noise_levels`).

    Returns the compliances, the unscaled covariance (A^T W A)^-1 and the whitening as a row
    scale (6 T,). ``iterations = 1`` is ordinary least squares.
    """
    levels = noise_levels(n_tests, n) if levels is None else np.asarray(levels)
    comp_std = np.ones(6)
    for it in range(iterations):
        scale = np.tile(1.0 / comp_std, n_tests)
        c, cov_c = solve_weighted(a * scale[:, None], d_flat * scale)
        if it == iterations - 1:
            break
        res = (d_flat - a @ c).reshape(n_tests, 6)
        comp_std, exact = next_std(np.sum(res**2, axis=0), n_tests, n, levels)
        if exact:
            comp_std = np.ones(6)  # an exact fit carries no information on the noise
            scale = np.tile(1.0 / comp_std, n_tests)
            c, cov_c = solve_weighted(a * scale[:, None], d_flat * scale)
            break
    return c, cov_c, scale


JACKKNIFE_MIN_TESTS = PER_COMPONENT_MIN_TESTS  # below, the analytic covariance, widened (module docstring)


def jackknife_cov(a: np.ndarray, d_flat: np.ndarray, c_full: np.ndarray, iterations: int) -> np.ndarray:
    """Delete-one-test jackknife covariance of the FGLS compliances.

    The analytic (A^T W A)^-1 ignores that the weights were estimated from the same data and
    that a test's six errors are correlated (a scanner's drift rotation also moves the block);
    refitting without each test in turn captures both. Slightly conservative by construction.

    The T refits repeat :func:`fgls` (same start, same number of iterations) on the normal
    equations, all at once: each displacement component k has a Gram matrix G_k = A_k^T A_k
    (n, n) over all tests, and dropping test t subtracts its rank-one term a_tk a_tk^T (a
    downdate, exact for a linear model). The unknown is the step delta = c - c_full from the
    full fit and the residual sums are taken about the full fit's residuals e, so the sums
    ``sum (e - A delta)^2 = s - 2 delta.g + delta^T G delta`` do not cancel catastrophically.
    Cost O(T n^3) per iteration instead of a (6 T, n) SVD per refit (O(T^2)).
    """
    n = a.shape[1]
    a3 = a.reshape(-1, 6, n)
    n_tests = a3.shape[0]
    e = (d_flat - a @ c_full).reshape(n_tests, 6)
    gram = np.einsum("tki,tkj->kij", a3, a3)  # (6, n, n)
    g = np.einsum("tki,tk->ki", a3, e)  # (6, n): A_k^T e_k
    s = np.sum(e**2, axis=0)  # (6,)
    weights = np.ones((n_tests, 6))
    frozen = np.zeros(n_tests, dtype=bool)  # refits that met an exact fit keep unit weights
    for it in range(iterations):
        aw = a3 * weights[:, :, None]
        normal = np.einsum("tk,kij->tij", weights, gram) - np.einsum("tki,tkj->tij", aw, a3)
        rhs = weights @ g - np.einsum("tki,tk->ti", aw, e)
        delta = _solve_batched(normal, rhs)
        if it == iterations - 1:
            break
        u = np.einsum("tki,ti->tk", a3, delta)  # the dropped test's predicted change
        ss = s - 2.0 * delta @ g.T + np.einsum("ti,kij,tj->tk", delta, gram, delta) - (e - u) ** 2
        std, exact = next_std(np.clip(ss, 0.0, None), n_tests - 1, n)
        frozen |= exact
        weights = 1.0 / np.where(frozen[:, None], 1.0, std) ** 2
    dev = delta - delta.mean(axis=0)  # estimates c_full + delta, less their mean
    return (n_tests - 1) / n_tests * dev.T @ dev


def _solve_batched(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve (T, n, n) symmetric normal equations for (T, n) right-hand sides, equilibrated to a
    unit diagonal as the SVD path scales A's columns. If one is exactly singular (a refit that
    cannot see a joint) all get the pseudo-inverse's minimum-norm step instead of an exception."""
    scale = 1.0 / np.sqrt(np.diagonal(normal, axis1=1, axis2=2))
    scaled = normal * scale[:, :, None] * scale[:, None, :]
    try:
        y = np.linalg.solve(scaled, (rhs * scale)[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        y = np.einsum("tij,tj->ti", np.linalg.pinv(scaled), rhs * scale)
    return y * scale
