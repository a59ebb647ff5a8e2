"""Covariances for a displacement noise shared by all tests: one full 6 x 6 matrix in B's axes.

Why: a scan's rigid drift moves the whole cloud, so a measured displacement's error couples
translation and rotation (``-[r]x sigma_r^2``, as large as the diagonal, docs/poses.md, "The
Cramer-Rao bound"). In the block frame B the scanner stands in the same place for every test,
so the covariance ``Sigma`` (6, 6) of a displacement ``[x, y, z, rx, ry, rz]`` is, to a few per
cent, the same for all tests. Its 21 numbers can be estimated from the residuals of all tests
together: many more degrees of freedom than a per-test (cluster) estimate has.

Two estimators use it (``identify(..., method=...)``, docs/uncertainty.md):

``fgls_pooled``
    The default FGLS estimate (one variance per component; the compliances are ``fgls``'s bit
    for bit) with a covariance from a parametric bootstrap: ``Sigma`` is estimated from all
    residuals (exactly unbiased for fixed weights, :func:`shared_covariance`), and the whole
    FGLS procedure is repeated on ``A c + e``, ``e ~ N(0, Sigma)`` (:func:`fgls_pooled_cov`).
    The delete-one jackknife of ``fgls`` overstates the spread when single tests carry much of
    the information (a designed set: a test's block leverage is ``n / T`` on average, 0.5 at 12
    tests), and its std varies by 20-50 % between data sets of one design; this one is centred
    on the Monte Carlo spread and varies by 10-20 %. It assumes the noise is the same for every
    test in B's axes (to about 20 % per component between poses, :mod:`.noise_floor`);
    the jackknife does not.
``fgls6``
    Generalised least squares weighted by the full ``Sigma``, re-estimated from the residuals
    and iterated (whitening every test by the Cholesky factor of ``Sigma``), with the analytic
    covariance ``(A^T Sigma^-1 A)^-1``. Reaches the Cramer-Rao bound when ``Sigma`` is known, but
    with 21 numbers estimated from about ``T - n / 6`` degrees of freedom per component it is
    less efficient than ``fgls`` at 12-20 tests and its analytic std is optimistic (about 0.8 of
    the variance even at 60 tests). For comparison only.

The unbiased ``Sigma``: with weights ``W`` (6, 6) shared by the tests and ``P = A B A^T W`` the
(oblique) projection of the fit, the residuals ``r = (I - P) e`` have
``E[sum_t r_t r_t^T] = T Sigma - Q Sigma - Sigma Q^T + sum_t A_t B M(Sigma) B A_t^T`` with
``Q = sum_t A_t B A_t^T W`` and ``M(Sigma) = sum_t A_t^T W Sigma W A_t``. This is linear in
``Sigma``; :func:`shared_covariance` builds it as a (36, 36) matrix on the unit matrices and
solves it for the observed sum. Cost O(T n^2) for each of the 36 unit matrices: linear in T, no
(6 T, 6 T) matrix; the bootstrap costs O(draws T n) (``BOOTSTRAP_DRAWS``: 40 ms at 12 tests, 0.7 s at 500).
"""

from __future__ import annotations

import numpy as np

POOLED_METHODS = ("fgls6", "fgls_pooled")


def _weights_from(sigma: np.ndarray) -> np.ndarray:
    """Inverse of a (6, 6) covariance, or of its diagonal if it is not safely positive definite."""
    sigma = 0.5 * (sigma + sigma.T)
    d = np.sqrt(np.clip(np.diag(sigma), 0.0, None))
    if not np.all(d > 0):
        return np.eye(6)
    corr = sigma / np.outer(d, d)
    w = np.linalg.eigvalsh(corr)
    if w[0] < 1e-9 * w[-1]:
        return np.diag(1.0 / d**2)
    return np.linalg.inv(sigma)


def _solve(a3: np.ndarray, d: np.ndarray, weight: np.ndarray):
    """GLS with one (6, 6) weight for every test: c (n,) and B = (A^T W A)^-1 (n, n)."""
    normal = np.einsum("tki,kl,tlj->ij", a3, weight, a3)
    rhs = np.einsum("tki,kl,tl->i", a3, weight, d)
    scale = 1.0 / np.sqrt(np.diag(normal))
    inv = np.linalg.pinv(normal * np.outer(scale, scale), hermitian=True) * np.outer(scale, scale)
    return inv @ rhs, inv


def shared_covariance(a3: np.ndarray, residuals: np.ndarray, weight: np.ndarray, bread: np.ndarray):
    """Unbiased estimate of the (6, 6) noise covariance shared by all tests, from the residuals.

    Parameters
    ----------
    a3 : (T, 6, n) the tests' A matrices
    residuals : (T, 6) measured minus fitted displacements [m | rad]
    weight : (6, 6) the fit's weight W (shared by the tests)
    bread : (n, n) ``(A^T W A)^-1`` of that fit

    Returns
    -------
    (6, 6) symmetric; ``E[...] = Sigma`` exactly for a linear model with fixed W (module doc).
    Falls back to the residuals' sum over ``T - n / 6`` if the solve is singular (too few tests).
    """
    n_tests, _, n = a3.shape
    s = residuals.T @ residuals
    proj = np.einsum("tki,ij,tlj->kl", a3, bread, a3) @ weight  # Q = sum_t A_t B A_t^T W
    u = np.einsum("kl,tln->tkn", weight, a3)  # W A_t
    gram = np.einsum("tki,tlj->klij", u, u)  # M(E_kl) = sum_t (W A_t)_k^T (W A_t)_l, (6, 6, n, n)
    kern = np.einsum("ia,klab,bj->klij", bread, gram, bread)  # B M(E_kl) B
    outer = np.einsum("tpi,tqj->pqij", a3, a3)  # sum_t A_t[p, i] A_t[q, j], once: O(T)
    back = np.einsum("pqij,klij->klpq", outer, kern)  # sum_t A_t B M(E_kl) B A_t^T
    eye = np.eye(6)
    op = np.zeros((6, 6, 6, 6))  # op[k, l] = L(E_kl), a (6, 6) matrix
    for k in range(6):
        for m in range(6):
            e_km = np.outer(eye[k], eye[m])
            op[k, m] = n_tests * e_km - proj @ e_km - e_km @ proj.T + back[k, m]
    lin = op.reshape(36, 36).T  # vec(L(Sigma)) = lin @ vec(Sigma)
    try:
        sigma = np.linalg.solve(lin, s.reshape(-1)).reshape(6, 6)
    except np.linalg.LinAlgError:
        sigma = s / max(n_tests - n / 6.0, 1.0)
    return 0.5 * (sigma + sigma.T)


def pooled_sandwich(a3: np.ndarray, weight: np.ndarray, bread: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(n, n) covariance ``B (sum_t A_t^T W Sigma W A_t) B`` of a fit with weight W (6, 6)."""
    meat = np.einsum("tki,kl,lm,mp,tpj->ij", a3, weight, sigma, weight, a3)
    return bread @ meat @ bread


BOOTSTRAP_DRAWS = 1000  # the std of a reported std from them: about 1 / sqrt(2 * 1000) = 2 %
BOOTSTRAP_SEED = 0  # fixed: an identification is a deterministic function of its data


def fgls_pooled_cov(
    a: np.ndarray,
    d_flat: np.ndarray,
    c: np.ndarray,
    row_scale: np.ndarray,
    iterations: int = 5,
    draws: int = BOOTSTRAP_DRAWS,
    seed: int = BOOTSTRAP_SEED,
) -> np.ndarray:
    """Covariance of the per-component FGLS compliances ``c``: a parametric bootstrap under the
    shared full 6 x 6 noise estimated from the residuals.

    Parameters
    ----------
    a : (6 T, n) stacked A; d_flat : (6 T,) stacked displacements [m | rad]
    c : (n,) the FGLS compliances [rad/(N*m)]
    row_scale : (6 T,) the FGLS whitening (1 / std per component, tiled over the tests)
    iterations : the FGLS iterations to repeat on every draw (as the fit made them)
    draws, seed : bootstrap draws and the seed of their generator (fixed: deterministic)

    Returns
    -------
    (n, n) [(rad/(N*m))^2]

    Notes
    -----
    ``Sigma`` is :func:`shared_covariance` at the fit's weights, made positive semi-definite.
    Each draw is ``A c + e``, ``e ~ N(0, Sigma)`` per test, refitted by the whole FGLS procedure
    (weights re-estimated, same iterations): the spread of the refits carries what the analytic
    sandwich :func:`pooled_sandwich` misses, the weights' own estimation noise (the sandwich's std
    is 0.76-1.06 of the Monte Carlo's at 12 tests, median 0.87; docs/uncertainty.md). Cost
    O(draws T n), linear in T.
    """
    n = a.shape[1]
    a3, d = a.reshape(-1, 6, n), d_flat.reshape(-1, 6)
    weight = np.diag(row_scale[:6] ** 2)
    _, bread = _solve(a3, d, weight)
    sigma = shared_covariance(a3, d - a3 @ c, weight, bread)
    val, vec = np.linalg.eigh(sigma)
    root = vec * np.sqrt(np.clip(val, 0.0, None))  # Sigma_+ = root root^T
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((draws, a3.shape[0], 6)) @ root.T
    steps = fgls_batch(a3, noise, iterations)  # refits of A c + e, less c
    return np.cov(steps.T)


def fgls_batch(a3: np.ndarray, d: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Per-component FGLS (``identify``'s ``fgls`` iteration) of B data sets at once.

    ``a3`` (T, 6, n), ``d`` (B, T, 6) [m | rad]; returns the compliances (B, n). The same
    iteration as :func:`vtestbed.researcher.fgls.fgls` with 8 tests or more (unit weights first,
    one variance per component from the residual sums over ``T - n / 6``, floored at 1e-9 of the
    largest; ``fgls_pooled`` bootstraps only such fits, fewer tests share noise levels) on the
    normal equations, equilibrated to a unit diagonal. The residual sums are expanded
    (``sum d^2 - 2 c.g + c^T G c`` per component, O(B n^2)): pass noise (the fit is equivariant,
    a refit of ``A c + e`` is ``c`` plus the refit of ``e``), whose sums do not cancel.
    """
    n_tests, _, n = a3.shape
    gram = np.einsum("tki,tkj->kij", a3, a3)  # (6, n, n)
    ad = np.matmul(d.transpose(2, 0, 1), a3.transpose(1, 0, 2)).transpose(1, 0, 2)  # (B, 6, n)
    dd = np.sum(d**2, axis=1)  # (B, 6)
    w = np.ones((d.shape[0], 6))
    dof_share = max(n_tests - n / 6.0, 1.0)
    for it in range(iterations):
        normal = np.einsum("bk,kij->bij", w, gram)
        scale = 1.0 / np.sqrt(np.diagonal(normal, axis1=1, axis2=2))
        rhs = np.einsum("bk,bki->bi", w, ad) * scale
        c = np.linalg.solve(normal * scale[:, :, None] * scale[:, None, :], rhs[:, :, None])[:, :, 0] * scale
        if it == iterations - 1:
            break
        ss = dd - 2.0 * np.einsum("bi,bki->bk", c, ad) + np.einsum("bi,kij,bj->bk", c, gram, c)
        ss = np.clip(ss, 0.0, None)
        std = np.sqrt(ss / dof_share)
        if 6 * n_tests <= n:
            break  # an exact fit: no information on the noise, unit weights (as fgls.fgls)
        exact = ~np.any(std > 0, axis=1, keepdims=True)  # a noise-free draw: unit weights
        floored = np.maximum(std, 1e-9 * std.max(axis=1, keepdims=True))
        w = np.where(exact, 1.0, 1.0 / np.where(exact, 1.0, floored) ** 2)
    return c


def fgls_full(a: np.ndarray, d_flat: np.ndarray, iterations: int = 5):
    """GLS weighted by one full (6, 6) noise covariance re-estimated from the residuals, iterated.

    Parameters
    ----------
    a : (6 T, n) stacked A; d_flat : (6 T,) stacked displacements [m | rad]
    iterations : fits in all; the first is ordinary least squares.

    Returns
    -------
    c : (n,) compliances [rad/(N*m)]
    cov : (n, n) ``(A^T Sigma^-1 A)^-1`` with the final ``Sigma``
    whiten : (T, 6, 6) the per-test whitening ``L^-1`` (``Sigma = L L^T``), the same for all tests
    sigma : (6, 6) the estimated displacement covariance [m^2 | m*rad | rad^2]
    """
    n = a.shape[1]
    a3, d = a.reshape(-1, 6, n), d_flat.reshape(-1, 6)
    weight = np.eye(6)
    sigma = np.eye(6)
    for it in range(iterations):
        c, bread = _solve(a3, d, weight)
        if it == iterations - 1:
            break
        sigma = shared_covariance(a3, d - a3 @ c, weight, bread)
        weight = _weights_from(sigma)
    sigma_used = np.linalg.inv(weight)
    chol = np.linalg.cholesky(0.5 * (sigma_used + sigma_used.T))
    whiten = np.broadcast_to(np.linalg.inv(chol), (a3.shape[0], 6, 6))
    return c, bread, whiten, sigma
