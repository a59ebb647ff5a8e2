"""Feasible GLS with one noise variance per displacement component, and its jackknife covariance.

The ``fgls`` estimator of :mod:`.identify` (docs/uncertainty.md): rows of the stacked system
``delta_d = A c`` (6 T, n) are scaled by the inverse noise std of their component (x, y, z [m],
rx, ry, rz [rad]), re-estimated from the residuals of the previous fit; the covariance of the
compliances [rad/(N*m)]^2 is a delete-one-test jackknife. Every cost is linear in the tests T:
the weights are a row scale, never a dense (6 T, 6 T) matrix, and the jackknife's T refits are
downdates of per-component normal equations.
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


def next_std(ss: np.ndarray, n_tests: int, n: int):
    """FGLS update: per-component noise std (..., 6) from residual sums of squares (..., 6), and
    whether the fit was exact (no information on the noise: fall back to unit weights)."""
    dof_share = max(n_tests - n / 6.0, 1.0)  # n parameters spread over 6 components
    std = np.sqrt(ss / dof_share)
    exact = (6 * n_tests <= n) | ~np.any(std > 0, axis=-1)
    return np.maximum(std, 1e-9 * std.max(axis=-1, keepdims=True)), exact


def fgls(a: np.ndarray, d_flat: np.ndarray, n_tests: int, n: int, iterations: int):
    """Least squares weighted by per-component noise variances re-estimated from the residuals.

    Returns the compliances, the unscaled covariance (A^T W A)^-1 and the whitening as a row
    scale (6 T,). ``iterations = 1`` is ordinary least squares.
    """
    comp_std = np.ones(6)
    for it in range(iterations):
        scale = np.tile(1.0 / comp_std, n_tests)
        c, cov_c = solve_weighted(a * scale[:, None], d_flat * scale)
        if it == iterations - 1:
            break
        res = (d_flat - a @ c).reshape(n_tests, 6)
        comp_std, exact = next_std(np.sum(res**2, axis=0), n_tests, n)
        if exact:
            comp_std = np.ones(6)  # an exact fit carries no information on the noise
            scale = np.tile(1.0 / comp_std, n_tests)
            c, cov_c = solve_weighted(a * scale[:, None], d_flat * scale)
            break
    return c, cov_c, scale


JACKKNIFE_MIN_TESTS = 8  # below this the analytic FGLS covariance (spread/std about 1.3 at 6 tests)


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
