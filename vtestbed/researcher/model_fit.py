"""The model fit the discrepancy workflow tests: the paper's model plus candidate terms, by
generalised least squares against the repeat scans' noise floor (:class:`Whitener`), with its
chi^2 and its leave-one-test-out prediction error (the cross-validated error the search ranks
candidates by, :func:`vtestbed.researcher.diagnose.name_effects`).

Units: SI; displacements in the unloaded block frame [m, rad], compliances in rad/(N*m).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import OutOfRangeError
from .candidates import Candidate, ModelContext
from .floor_calibration import fit_p_value, inflation, lr_p_value
from .identify import stack
from .noise_floor import NoiseFloor


@dataclass(frozen=True)
class ModelFit:
    """The paper's model plus ``terms``, fitted against the noise floor (SI)."""

    terms: tuple[str, ...]
    compliance: np.ndarray  # (n,) rad/(N*m)
    theta: dict  # term label -> {parameter: value}
    theta_std: dict
    chi2: float
    dof: int
    residuals: np.ndarray  # (T, 6) measured - predicted
    x: np.ndarray = field(repr=False)
    compliance_std: np.ndarray = field(default=None, repr=False)  # (n,) rad/(N*m), noise floor as known
    rank: int = 0  # independent columns of the fitted design: the parameters the data determine
    press: float = float("nan")  # whitened leave-one-test-out prediction error (:func:`leave_one_test_out`)
    design: np.ndarray = field(
        default=None, repr=False
    )  # (6T, k) the whitened columns at the last linearisation
    column_terms: tuple = ()  # (k,) the term label of each column ("" for a compliance)
    nu: int = 0  # the noise floor's sample count

    @property
    def stiffness(self) -> np.ndarray:
        return 1.0 / self.compliance

    @cached_property
    def p_value(self) -> float:
        """The detection test's p-value: chi^2 against the floor, allowing for its estimation
        (:func:`.floor_calibration.fit_p_value`)."""
        return fit_p_value(self.chi2, self.design, self.nu)

    def likelihood_ratio_test(self, other: ModelFit, label: str) -> tuple[float, float, int]:
        """The likelihood-ratio test of term ``label`` of this fit against ``other``, the fit
        without it: (likelihood ratio, p-value allowing for the floor's estimation, degrees of
        freedom: the rank it adds)."""
        lr, df = max(other.chi2 - self.chi2, 0.0), self.rank - other.rank
        tested = np.array([t == label for t in self.column_terms])
        return lr, lr_p_value(lr, self.design, tested, df, self.nu), df

    @property
    def stiffness_std(self) -> np.ndarray:
        """(n,) N*m/rad, first order: std(c) / c^2."""
        return self.compliance_std / self.compliance**2

    def to_dict(self) -> dict:
        return {"terms": list(self.terms), "stiffness_Nm_per_rad": self.stiffness.tolist(),
                "stiffness_std_Nm_per_rad": self.stiffness_std.tolist(),
                "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                "parameters": self.theta, "parameters_std": self.theta_std}  # fmt: skip


class Whitener:
    """x -> C^-1 x / sqrt(f) per test, with ``C C^T`` the noise floor's 6x6 covariance (the
    scans' plus the F/T readings' where known: ``NoiseFloor.displacement_covariance``).

    The floor is estimated from ``nu`` samples, so a quadratic form in its inverse is inflated by
    ``f = nu / (nu - 7)`` on average (inverse Wishart, 6 components: :func:`.floor_calibration.inflation`);
    dividing it out keeps the mean of chi^2 at its degrees of freedom (measured: chi^2 124 +- 17 on
    114 degrees of freedom with nu = 75 before, the expected 114 * 75 / 68 = 126). Its tail is
    wider than chi^2's: the tests take their p-values from :mod:`.floor_calibration`. The
    readings' part is known, not estimated, so ``f`` slightly overstates the sum's inflation
    (by 0.2 % with the readings at 2 % of the floor).
    """

    def __init__(self, floor: NoiseFloor):
        cov = np.asarray(floor.displacement_covariance, dtype=float)
        nu = int(floor.n_samples)
        if nu <= 7:  # first: too few samples is also why a covariance is singular
            raise OutOfRangeError(
                f"the noise floor rests on {nu} repeat-scan samples; at least 8 are needed to test a model "
                "against it (record more repeat scans: 2 or more per test)"
            )
        if cov.shape != (6, 6) or not np.all(np.isfinite(cov)) or np.linalg.eigvalsh(cov).min() <= 0:
            raise OutOfRangeError(
                "the noise floor's covariance must be a finite positive definite 6x6 matrix"
            )
        self.n_samples = nu
        self.inflation = inflation(nu)
        self.inv_chol = np.linalg.inv(np.linalg.cholesky(cov)) / np.sqrt(self.inflation)

    def __call__(self, stacked: np.ndarray) -> np.ndarray:
        shape = stacked.shape
        blocks = stacked.reshape(-1, 6, *shape[1:])
        return np.einsum("ij,tj...->ti...", self.inv_chol, blocks).reshape(shape)


def term_slices(terms, n: int) -> list[tuple[Candidate, slice]]:
    """Each term and where its parameters sit in a fit's ``x``: after the ``n`` compliances, in
    the terms' order."""
    out, k = [], n
    for term in terms:
        out.append((term, slice(k, k + len(term.params))))
        k += len(term.params)
    return out


def fit_model(
    ctx: ModelContext, white: Whitener, terms: list[Candidate], iterations: int | None = None
) -> ModelFit:
    """Fit the compliances and the terms' parameters by GLS against the noise floor.

    Bilinear terms, and the clean world's exact statics when ``ctx.statics`` is set (its gap to the
    paper's model is subtracted from the measurements), are re-evaluated at the updated
    compliances ``iterations`` times at most (default 4; 8 with a term nonlinear in its own
    parameters, whose secant columns are re-evaluated at the updated parameters too:
    :meth:`.Candidate.design`).
    """
    ms = ctx.measurements
    a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
    d = np.concatenate([m.displacement for m in ms])
    n = a.shape[1]
    c = _lstsq(white(a), white(d))[0]
    cols, gap, params = [], np.zeros_like(d), {}
    repeat = any(t.bilinear for t in terms) or ctx.statics is not None
    if iterations is None:
        iterations = 8 if any(t.secant for t in terms) else 4
    for _ in range(iterations if repeat else 1):
        if ctx.statics is not None:
            gap = ctx.statics.gap(ms, c)
        cols = [t.design(ctx, c, params.get(t.label)) for t in terms]
        x_mat = np.hstack([a, *cols]) if cols else a
        x, cov, rank, basis = _lstsq(white(x_mat), white(d - gap))
        c = x[:n]
        params = {t.label: x[at] for t, at in term_slices(terms, n)}  # for a secant term's next columns
    x_mat = np.hstack([a, *cols]) if cols else a
    residuals = d - gap - x_mat @ x
    white_residuals = white(residuals)
    chi2 = float(np.sum(white_residuals**2))
    theta, theta_std = {}, {}
    std = np.sqrt(np.diag(cov))
    for term, at in term_slices(terms, n):
        theta[term.label] = dict(zip(term.params, x[at].tolist()))
        theta_std[term.label] = dict(zip(term.params, std[at].tolist()))
    dof = len(d) - rank
    labels = tuple(t.label for t in terms)
    press = leave_one_test_out(basis, white_residuals)
    owners = ("",) * n + tuple(t.label for t, block in zip(terms, cols) for _ in range(block.shape[1]))
    return ModelFit(labels, c, theta, theta_std, chi2, dof, residuals.reshape(-1, 6), x, std[:n], rank, press,
                    white(x_mat), owners, white.n_samples)  # fmt: skip


def leave_one_test_out(basis: np.ndarray, white_residuals: np.ndarray) -> float | np.ndarray:
    """The whitened prediction error of each test from a fit without it, summed (PRESS, per test).

    For a linear fit with orthonormal basis ``U`` of its whitened columns, test ``t``'s
    leave-one-out residual is ``(I - U_t U_t^T)^-1 e_t`` (``U_t``, ``e_t``: its 6 rows). A test the
    fit cannot do without (a leverage of 1 in some direction) makes it ``inf``. For bilinear terms
    and the exact statics it is the error at the fit's last linearisation (the columns and the
    statics' gap are not re-evaluated without the test).

    Parameters
    ----------
    basis : (6T, r) array
        Orthonormal basis of the fit's whitened columns, a test's 6 rows together.
    white_residuals : (6T,) or (6T, K) array
        The fit's whitened residuals; K columns are K datasets fitted with the same columns
        (the forecasts in benchmarks/ draw them in batches).

    Returns
    -------
    float, or (K,) array for (6T, K) residuals
    """
    u = basis.reshape(-1, 6, basis.shape[1])
    e = white_residuals.reshape(len(u), 6, -1)
    hat = np.eye(6) - np.einsum("tik,tjk->tij", u, u)
    if np.linalg.eigvalsh(hat).min() <= 1e-9:
        err = np.full(e.shape[2], np.inf)
    else:
        err = np.sum(np.linalg.solve(hat, e) ** 2, axis=(0, 1))
    return float(err[0]) if white_residuals.ndim == 1 else err


def _lstsq(xw: np.ndarray, dw: np.ndarray):
    """Column-scaled least squares; returns the solution, its covariance (whitened units) and the
    rank, and an orthonormal basis of the kept column space. Directions below 1e-12 of the largest singular value are left out (minimum norm): the
    likelihood-ratio tests count degrees of freedom by rank, so a term that adds none is never
    significant (a link 2 bending in plane is joints 2 and 3 plus their coupling)."""
    u, s, vt, norms = scaled_svd(xw)
    x = (vt.T @ ((u.T @ dw) / s)) / norms
    cov = ((vt.T / s**2) @ vt) / np.outer(norms, norms)
    return x, cov, len(s), u


def scaled_svd(xw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The thin SVD ``U S V^T`` of the columns ``xw`` (m, k) each scaled to unit norm, keeping the
    directions above 1e-12 of the largest singular value (the fits' rank), and the column norms:
    ``(U (m, r), s (r,), V^T (r, k), norms (k,))``; a zero column keeps norm 1."""
    norms = np.linalg.norm(xw, axis=0)
    norms[norms == 0] = 1.0
    u, s, vt = np.linalg.svd(xw / norms, full_matrices=False)
    keep = s > s[0] * 1e-12
    return u[:, keep], s[keep], vt[keep], norms
