"""Identification core: delta_d = A c, stacked over tests, solved for the compliances c = 1/k.

For one test with geometric Jacobian J (6, n) at the block reference point and the external
wrench F (6,) at that point (both in one frame), the paper's model
``delta_d = J K^-1 J^T F`` is linear in the compliances: ``A[i, j] = J[i, j] (J^T F)[j]``.

Estimators (``fgls_pooled`` and ``fgls6`` in :mod:`.gls_full`, docs/uncertainty.md):

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
    is correlated between them, and the weights themselves are estimates. With fewer tests six
    variances cannot be estimated (a component's residuals can be fitted exactly) and dropping a
    test changes the design too much for the jackknife: the tests share two noise levels
    (translation, rotation; one from 3 tests down) and the analytic covariance is widened by the
    Student factor of their degrees of freedom (:mod:`.fgls`; docs/uncertainty.md, "Few tests").
``fgls_pooled``
    ``fgls``'s compliances (bit for bit) with a parametric-bootstrap covariance under one full
    6 x 6 displacement noise shared by the tests (estimated from all residuals): unbiased where
    the jackknife overstates (designed sets), and 2-3 times steadier from one data set to the next.
    Below 8 tests the 6 x 6 noise cannot be estimated: ``fgls``'s covariance, with a note.
``fgls6``
    GLS with that full 6 x 6 noise, iterated; analytic covariance, optimistic (21 numbers from
    the residuals). Less efficient than ``fgls`` at 12-20 tests; for comparison only. Below 8
    tests it is ``fgls``, with a note.
``gls_floor``
    GLS with the full 6 x 6 displacement-noise covariance of the repeat-scan noise floor
    (:mod:`.noise_floor`, passed as ``displacement_cov``): the weights come from scans of a static
    block, not from the residuals, so they are as good as the repeats (75 samples for 25 tests
    with 3 repeats) and carry the correlation between translation and rotation that ``fgls``
    ignores. Analytic covariance ``(A^T Sigma^-1 A)^-1``. Needs repeat scans.

Stiffness standard deviations follow from the compliance covariance by the delta method,
``std(k_j) = std(c_j) / c_j^2``.

Cost is linear in T: the whitening is a row scale (fgls, ols) or per-test 6 x 6 blocks (wls),
never a dense (6 T, 6 T) matrix, and the jackknife's T refits are done together on per-component
normal equations downdated by the dropped test (:func:`.fgls.jackknife_cov`). A fit of 500 tests takes
milliseconds (``benchmarks/bench_identify.py``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import OutOfRangeError, SingularPoseError, SlackWireError, UnknownNameError
from .fgls import (
    JACKKNIFE_MIN_TESTS,
    ONE_LEVEL,
    fgls,
    jackknife_cov,
    noise_levels,
    small_sample_factor,
    solve_weighted,
)
from .gls_full import POOLED_METHODS, fgls_full, fgls_pooled_cov

METHODS = ("ols", "wls", "fgls", *POOLED_METHODS, "gls_floor")
KNOWN_COV_METHODS = ("wls", "gls_floor")  # the displacement covariance is given, not estimated
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
    # (6, 6) or (T, 6, 6): the given displacement covariance of "wls" and "gls_floor", else None
    displacement_cov: np.ndarray | None = None

    def as_dict(self) -> dict:
        extra = (
            {}
            if self.displacement_cov is None
            else {"displacement_cov": np.asarray(self.displacement_cov).tolist()}
        )
        return extra | {
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
    # a_matrix for all tests at once, J * (J^T F): a batched matmul, the same products as a loop
    torques = np.matmul(jacobians.transpose(0, 2, 1), wrenches[:, :, None])[:, :, 0]
    return (jacobians * torques[:, None, :]).reshape(-1, jacobians.shape[2])


def _apply(whiten: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Whiten rows of ``x`` (6 T,) or (6 T, n): ``whiten`` is a row scale (6 T,) or per-test
    blocks (T, 6, 6). Never a dense (6 T, 6 T) matrix: that made a fit O(T^2) in memory and
    O(T^3) in time for a block-diagonal operator."""
    if whiten.ndim == 1:
        return x * (whiten if x.ndim == 1 else whiten[:, None])
    return np.matmul(whiten, x.reshape(whiten.shape[0], 6, -1)).reshape(x.shape)


def _checked(jacobians, wrenches, displacements, method, joint_names, min_wrench, test_ids=None):
    """Validate the inputs once; returns the stacked A (6 T, n), d (T, 6) and the joint names.

    Errors name the tests by ``test_ids`` (T,) when given, else by their 0-based position."""
    if method not in METHODS:
        raise UnknownNameError("identification method", method, METHODS)
    d = np.asarray(displacements, dtype=float)
    wrenches = np.asarray(wrenches, dtype=float)
    a = stack(jacobians, wrenches)
    n_tests, n = wrenches.shape[0], a.shape[1]
    names = tuple(joint_names or (f"joint{i + 1}" for i in range(n)))
    if d.shape != (n_tests, 6):
        raise OutOfRangeError(f"displacements must have shape ({n_tests}, 6), got {d.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(d))):
        raise OutOfRangeError("jacobians, wrenches and displacements must be finite")
    label = (lambda i: str(test_ids[i])) if test_ids is not None else (lambda i: f"{i} (0-based)")
    slack = np.flatnonzero(np.linalg.norm(wrenches[:, :3], axis=1) < min_wrench)
    if slack.size:
        raise SlackWireError(
            f"tests {', '.join(label(i) for i in slack)} have a force change below {min_wrench:g} N: the wire was slack "
            "(no load); tighten it or drop those tests"
        )
    if 6 * n_tests < n:
        raise OutOfRangeError(
            f"n_tests = {n_tests} gives {6 * n_tests} equations for {n} unknowns; need >= 1 test"
        )
    s = np.linalg.svd(np.asarray(jacobians, dtype=float), compute_uv=False)  # (T, min(6, n))
    singular = np.flatnonzero(s[:, -1] < 1e-9 * s[:, 0])
    if singular.size:
        t = singular[0]
        raise SingularPoseError(
            f"test {label(t)}: the Jacobian is singular (sigma_min/sigma_max = {s[t, -1] / s[t, 0]:.1e})"
        )
    return a, d, names


def _wls_whitening(displacement_cov, n_tests: int) -> np.ndarray:
    """Per-test whitening blocks L^-1 (T, 6, 6) of Sigma_t = L L^T, checked."""
    if displacement_cov is None:
        raise OutOfRangeError(
            "methods 'wls' and 'gls_floor' need displacement_cov, (T, 6, 6) or (6, 6) "
            "(for 'gls_floor' the repeat-scan noise floor's covariance)"
        )
    cov = np.asarray(displacement_cov, dtype=float)
    if cov.shape not in ((6, 6), (n_tests, 6, 6)) or not np.all(np.isfinite(cov)):
        raise OutOfRangeError(
            f"displacement_cov must be finite, (6, 6) or ({n_tests}, 6, 6); got {cov.shape}"
        )
    cov = np.broadcast_to(cov, (n_tests, 6, 6))
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise OutOfRangeError("displacement_cov must be symmetric positive definite") from None
    return np.linalg.inv(chol)


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
    test_ids: tuple[str, ...] | None = None,
) -> IdentificationResult:
    """Identify joint compliances from T tests.

    Parameters
    ----------
    jacobians : (T, 6, n) Jacobians at the block reference point, in the frame of the data
    wrenches : (T, 6) external wrench change (loaded minus unloaded) at that point [N, N*m]
    displacements : (T, 6) measured displacement of that point [m, m, m, rad, rad, rad]
    method : {"ols", "wls", "fgls", "fgls6", "fgls_pooled", "gls_floor"}
    displacement_cov : (T, 6, 6) or (6, 6), required for ``"wls"`` and ``"gls_floor"`` [m^2, m*rad, rad^2]
    min_wrench : float
        A test whose force change is below this [N] has a slack wire and is refused.
    test_ids : (T,) str, optional
        The tests' names for error messages (else their 0-based position).

    Notes
    -----
    Time and memory are linear in T: the whitening is applied per test, and the jackknife
    refits work on per-component normal equations (see :func:`.fgls.jackknife_cov`).
    """
    a, d, names = _checked(jacobians, wrenches, displacements, method, joint_names, min_wrench, test_ids)
    whiten = _wls_whitening(displacement_cov, d.shape[0]) if method in KNOWN_COV_METHODS else None
    result = _fit(a, d, method, names, whiten, iterations)
    if whiten is not None:
        result = replace(result, displacement_cov=np.asarray(displacement_cov, dtype=float))
    for note in result.warnings:
        warnings.warn(note, stacklevel=2)
    return result


def identify_prefixes(
    jacobians,
    wrenches,
    displacements,
    *,
    method: str = "fgls",
    displacement_cov=None,
    joint_names: tuple[str, ...] | None = None,
    min_wrench: float = 1.0,
    iterations: int = 5,
    test_ids: tuple[str, ...] | None = None,
) -> list[IdentificationResult]:
    """:func:`identify` on the first n tests, for n = 1..T (a convergence study).

    Same parameters as :func:`identify`. The inputs are checked and stacked (for ``"wls"`` the
    whitening blocks factored) once, and each prefix is a slice of them; a fit on n tests costs
    O(n), so the study costs O(T^2). Result ``n - 1`` equals ``identify`` on the first n tests
    (the same arithmetic); its notes are in its ``warnings`` field, not emitted as warnings.
    """
    a, d, names = _checked(jacobians, wrenches, displacements, method, joint_names, min_wrench, test_ids)
    whiten = _wls_whitening(displacement_cov, d.shape[0]) if method in KNOWN_COV_METHODS else None
    return [
        _fit(a[: 6 * n], d[:n], method, names, None if whiten is None else whiten[:n], iterations)
        for n in range(1, d.shape[0] + 1)
    ]


def _fit(a, d, method, names, wls_whiten, iterations) -> IdentificationResult:
    """One identification on checked, stacked inputs: A (6 T, n), d (T, 6)."""
    n_tests, n = d.shape[0], a.shape[1]
    d_flat = d.reshape(-1)
    notes = []
    levels = noise_levels(n_tests, n)  # the fgls weights' noise levels, shared below 8 tests
    few = n_tests < JACKKNIFE_MIN_TESTS and method in ("fgls", *POOLED_METHODS)
    if few and method != "fgls":
        notes.append(
            f"{method} needs at least {JACKKNIFE_MIN_TESTS} tests to estimate a 6 x 6 noise; "
            f"with {n_tests} its estimate and std are fgls's"
        )
    if method in KNOWN_COV_METHODS:
        whiten = wls_whiten
        c, cov_c = solve_weighted(_apply(whiten, a), _apply(whiten, d_flat))
    elif method == "fgls6" and not few:
        c, cov_c, whiten, _ = fgls_full(a, d_flat, iterations)
    else:
        c, cov_c, whiten = fgls(a, d_flat, n_tests, n, 1 if method == "ols" else iterations, levels)
    # Condition number of the joints' contributions to the (weighted) displacements: a joint
    # whose torque is small in every test contributes little and makes this large.
    sv = np.linalg.svd(_apply(whiten, a) * np.abs(c)[None, :], compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    residuals = d_flat - a @ c
    res6 = residuals.reshape(n_tests, 6)
    dof = max(6 * n_tests - n, 1)
    if method == "ols":
        sigma2 = residuals @ residuals / dof
        cov_c = cov_c * sigma2  # whiten = I: cov = s^2 (A^T A)^-1
        chi2 = 1.0
    else:
        white = _apply(whiten, residuals)
        chi2 = float(white @ white / dof)
        if method == "fgls" and not few:
            cov_c = jackknife_cov(a, d_flat, c, iterations)
        elif few and 6 * n_tests > n:  # variances from few residuals: their scale, t-widened
            factor = small_sample_factor(levels, n_tests, n)
            if np.isfinite(factor):
                cov_c = cov_c * chi2 * factor
                if np.array_equal(levels, ONE_LEVEL):
                    notes.append(
                        f"{n_tests} tests are too few to estimate the translation [m] and rotation "
                        "[rad] noise apart: one noise level is assumed for both, and the std is as "
                        "good as that assumption; add tests, or weight with repeat scans (gls_floor)"
                    )
            else:
                notes.append(
                    f"{6 * n_tests} equations for {n} unknowns leave too few residuals to estimate "
                    "the noise: no uncertainty (std = nan); add tests"
                )
                cov_c = np.full_like(cov_c, np.nan)
        elif method == "fgls_pooled":  # fgls's estimate, its covariance under a shared 6 x 6 noise
            cov_c = fgls_pooled_cov(a, d_flat, c, whiten, iterations)
    component_std = np.sqrt(np.mean(res6**2, axis=0))
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
