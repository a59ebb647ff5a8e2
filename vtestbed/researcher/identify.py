"""Identification core: delta_d = A c, stacked over tests, solved for the compliances c = 1/k.

For one test with geometric Jacobian J (6, n) at the block reference point and the external
wrench F (6,) at that point (both in one frame), the paper's model
``delta_d = J K^-1 J^T F`` is linear in the compliances: ``A[i, j] = J[i, j] (J^T F)[j]``.

Three estimators:

``ols``
    The paper's ordinary least squares on the stacked system. Its covariance assumes one noise
    level for translations [m] and rotations [rad] alike, which is rarely true.
``wls``
    Weighted least squares with a known per-test displacement covariance Sigma_t (6, 6).
``fgls`` (default)
    Feasible generalised least squares: one noise variance per displacement component
    (x, y, z, rx, ry, rz) estimated from the residuals of the previous fit, iterated. Needs no
    noise model, so it runs unchanged on lab data. Its covariance is a delete-one-test
    jackknife from 8 tests on: honest when the noise differs between translation and rotation,
    is correlated between them, and the weights themselves are estimates. With fewer tests,
    dropping one changes the design too much and the jackknife overstates the std, so the
    analytic covariance (somewhat optimistic, spread/std about 1.3 at 6 tests) is used.

Stiffness standard deviations follow from the compliance covariance by the delta method,
``std(k_j) = std(c_j) / c_j^2``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import OutOfRangeError, SingularPoseError, SlackWireError, UnknownNameError

METHODS = ("ols", "wls", "fgls")
ILL_CONDITIONED = 1e3  # condition number of the joints' weighted displacement contributions


def a_matrix(jacobian: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """The (6, n) matrix A of one test: ``delta_d = A @ c`` (paper Eq. 25).

    Parameters
    ----------
    jacobian : (6, n) geometric Jacobian ``[v; omega]`` at the point the wrench acts on [m, 1]
    wrench : (6,) external wrench ``[f; tau]`` at that point, same frame [N, N*m]
    """
    jacobian = np.asarray(jacobian, dtype=float)
    joint_torque = jacobian.T @ np.asarray(wrench, dtype=float)
    return jacobian * joint_torque[None, :]


@dataclass(frozen=True)
class IdentificationResult:
    """Estimated joint compliances and stiffnesses with their uncertainty (SI)."""

    joint_names: tuple[str, ...]
    method: str
    n_tests: int
    compliance: np.ndarray  # (n,) rad/(N*m)
    compliance_cov: np.ndarray  # (n, n)
    stiffness: np.ndarray  # (n,) N*m/rad
    stiffness_std: np.ndarray  # (n,) N*m/rad
    residuals: np.ndarray  # (6 * n_tests,) measured - predicted displacement [m | rad]
    component_std: np.ndarray  # (6,) residual std per displacement component [m, m, m, rad, rad, rad]
    condition_number: float  # of the weighted system scaled by the estimated compliances
    chi2_reduced: float
    warnings: tuple[str, ...] = field(default=())

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "n_tests": self.n_tests,
            "joint_names": list(self.joint_names),
            "compliance": self.compliance.tolist(),
            "compliance_cov": self.compliance_cov.tolist(),
            "stiffness": self.stiffness.tolist(),
            "stiffness_std": self.stiffness_std.tolist(),
            "component_std": self.component_std.tolist(),
            "condition_number": self.condition_number,
            "chi2_reduced": self.chi2_reduced,
            "warnings": list(self.warnings),
        }


def stack(jacobians, wrenches) -> np.ndarray:
    """Stacked A (6 T, n) of T tests from their Jacobians (T, 6, n) and wrenches (T, 6)."""
    jacobians = np.asarray(jacobians, dtype=float)
    wrenches = np.asarray(wrenches, dtype=float)
    if jacobians.ndim != 3 or jacobians.shape[1] != 6 or wrenches.shape != (jacobians.shape[0], 6):
        raise OutOfRangeError(
            f"jacobians must have shape (T, 6, n) and wrenches (T, 6); got {jacobians.shape} and {wrenches.shape}"
        )
    return np.concatenate([a_matrix(j, f) for j, f in zip(jacobians, wrenches)])


def _solve_weighted(a: np.ndarray, d: np.ndarray, whiten: np.ndarray):
    """Least squares on the whitened system; returns c, (A^T W A)^-1, cond of the normalised system."""
    aw = whiten @ a
    dw = whiten @ d
    norms = np.linalg.norm(aw, axis=0)
    scaled = aw / norms
    u, s, vt = np.linalg.svd(scaled, full_matrices=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    c = (vt.T @ ((u.T @ dw) / s)) / norms
    inv_scaled = (vt.T / s**2) @ vt
    cov = inv_scaled / np.outer(norms, norms)
    return c, cov, cond


def identify(
    jacobians,
    wrenches,
    displacements,
    *,
    method: str = "fgls",
    displacement_cov=None,
    joint_names: tuple[str, ...] | None = None,
    min_wrench: float = 1.0,
    iterations: int = 5,
) -> IdentificationResult:
    """Identify joint compliances from T tests.

    Parameters
    ----------
    jacobians : (T, 6, n) Jacobians at the block reference point, in the frame of the data
    wrenches : (T, 6) external wrench change (loaded minus unloaded) at that point [N, N*m]
    displacements : (T, 6) measured displacement of that point [m, m, m, rad, rad, rad]
    method : {"ols", "wls", "fgls"}
    displacement_cov : (T, 6, 6) or (6, 6), required for ``"wls"``
    min_wrench : float
        A test whose force change is below this [N] has a slack wire and is refused.
    """
    if method not in METHODS:
        raise UnknownNameError("identification method", method, METHODS)
    d = np.asarray(displacements, dtype=float)
    wrenches = np.asarray(wrenches, dtype=float)
    a = stack(jacobians, wrenches)
    n_tests, n = d.shape[0], a.shape[1]
    names = tuple(joint_names or (f"joint{i + 1}" for i in range(n)))
    if d.shape != (n_tests, 6) or a.shape[0] != 6 * n_tests:
        raise OutOfRangeError(f"displacements must have shape ({a.shape[0] // 6}, 6), got {d.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(d))):
        raise OutOfRangeError("jacobians, wrenches and displacements must be finite")
    slack = np.flatnonzero(np.linalg.norm(wrenches[:, :3], axis=1) < min_wrench)
    if slack.size:
        raise SlackWireError(
            f"tests {slack.tolist()} have a force change below {min_wrench:g} N: the wire was slack "
            "(no load); tighten it or drop those tests"
        )
    if 6 * n_tests < n:
        raise OutOfRangeError(
            f"n_tests = {n_tests} gives {6 * n_tests} equations for {n} unknowns; need >= 1 test"
        )
    for t, jac in enumerate(np.asarray(jacobians)):
        s = np.linalg.svd(jac, compute_uv=False)
        if s[-1] < 1e-9 * s[0]:
            raise SingularPoseError(
                f"test {t}: the Jacobian is singular (sigma_min/sigma_max = {s[-1] / s[0]:.1e})"
            )
    d_flat = d.reshape(-1)
    if method == "wls":
        if displacement_cov is None:
            raise OutOfRangeError("method 'wls' needs displacement_cov, (T, 6, 6) or (6, 6)")
        cov = np.broadcast_to(np.asarray(displacement_cov, dtype=float), (n_tests, 6, 6))
        whiten = _block_diag([np.linalg.inv(np.linalg.cholesky(c)) for c in cov])
        c, cov_c, cond = _solve_weighted(a, d_flat, whiten)
    else:
        c, cov_c, whiten = _fgls(a, d_flat, n_tests, n, iterations if method == "fgls" else 1)
    # Condition number of the joints' contributions to the (weighted) displacements: a joint
    # whose torque is small in every test contributes little and makes this large.
    contrib = (whiten @ a) * np.abs(c)[None, :]
    sv = np.linalg.svd(contrib, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    residuals = d_flat - a @ c
    res6 = residuals.reshape(n_tests, 6)
    dof = max(6 * n_tests - n, 1)
    if method == "ols":
        sigma2 = residuals @ residuals / dof
        cov_c = cov_c * sigma2  # whiten = I: cov = s^2 (A^T A)^-1
        chi2 = 1.0
    else:
        white = whiten @ residuals
        chi2 = float(white @ white / dof)
        if method == "fgls" and n_tests >= JACKKNIFE_MIN_TESTS:
            cov_c = _jackknife_cov(a, d_flat, n_tests, n, iterations)
        elif method == "fgls":  # the variances were estimated: carry their scale (wls keeps Sigma)
            cov_c = cov_c * chi2
    component_std = np.sqrt(np.mean(res6**2, axis=0))
    notes = []
    if cond > ILL_CONDITIONED:
        notes.append(
            f"ill-conditioned stacked problem: condition number {cond:.3g} > {ILL_CONDITIONED:g}; "
            "add tests at other poses or anchors"
        )
    if np.any(c <= 0):
        bad = [names[i] for i in np.flatnonzero(c <= 0)]
        notes.append(f"non-positive compliance for {', '.join(bad)}: not identifiable from these tests")
    if 6 * n_tests == n:
        notes.append(
            "one test gives as many equations as unknowns: no residual, so no uncertainty (std = nan)"
        )
        cov_c = np.full_like(cov_c, np.nan)
    for note in notes:
        warnings.warn(note, stacklevel=2)
    with np.errstate(divide="ignore"):
        k = 1.0 / c
    std_c = np.sqrt(np.clip(np.diag(cov_c), 0.0, None)) if np.all(np.isfinite(cov_c)) else np.diag(cov_c)
    return IdentificationResult(
        joint_names=names,
        method=method,
        n_tests=n_tests,
        compliance=c,
        compliance_cov=cov_c,
        stiffness=k,
        stiffness_std=std_c / c**2,
        residuals=residuals,
        component_std=component_std,
        condition_number=cond,
        chi2_reduced=chi2,
        warnings=tuple(notes),
    )


def _fgls(a: np.ndarray, d_flat: np.ndarray, n_tests: int, n: int, iterations: int):
    """Least squares weighted by per-component noise variances re-estimated from the residuals.

    Returns the compliances, the unscaled covariance (A^T W A)^-1 and the whitening matrix.
    ``iterations = 1`` is ordinary least squares.
    """
    comp_std = np.ones(6)
    for it in range(iterations):
        whiten = np.diag(np.tile(1.0 / comp_std, n_tests))
        c, cov_c, _ = _solve_weighted(a, d_flat, whiten)
        if it == iterations - 1:
            break
        res = (d_flat - a @ c).reshape(n_tests, 6)
        dof_share = max(n_tests - n / 6.0, 1.0)  # n parameters spread over 6 components
        comp_std = np.sqrt(np.sum(res**2, axis=0) / dof_share)
        if 6 * n_tests <= n or not np.any(comp_std > 0):
            comp_std = np.ones(6)  # an exact fit carries no information on the noise
            whiten = np.diag(np.tile(1.0 / comp_std, n_tests))
            c, cov_c, _ = _solve_weighted(a, d_flat, whiten)
            break
        comp_std = np.maximum(comp_std, 1e-9 * comp_std.max())
    return c, cov_c, whiten


JACKKNIFE_MIN_TESTS = 8  # below this the analytic FGLS covariance (spread/std about 1.3 at 6 tests)


def _jackknife_cov(a: np.ndarray, d_flat: np.ndarray, n_tests: int, n: int, iterations: int) -> np.ndarray:
    """Delete-one-test jackknife covariance of the FGLS compliances.

    The analytic (A^T W A)^-1 ignores that the weights were estimated from the same data and
    that a test's six errors are correlated (a scanner's drift rotation also moves the block);
    refitting without each test in turn captures both. Slightly conservative by construction.
    """
    keep = np.ones(6 * n_tests, dtype=bool)
    estimates = np.empty((n_tests, n))
    for t in range(n_tests):
        keep[:] = True
        keep[6 * t : 6 * t + 6] = False
        estimates[t] = _fgls(a[keep], d_flat[keep], n_tests - 1, n, iterations)[0]
    dev = estimates - estimates.mean(axis=0)
    return (n_tests - 1) / n_tests * dev.T @ dev


def _block_diag(blocks) -> np.ndarray:
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        out[i : i + b.shape[0], i : i + b.shape[1]] = b
        i += b.shape[0]
    return out
