"""Sequential design: the next tests after an identified dataset, with its estimate as the prior.

A lab does not know the stiffness before it measures it, and at a fixed tension the minimax design
depends on the prior. So: run a pilot set, identify, and choose the next tests for the worst
joint's relative std of *all* tests (old and new) at the current estimate,
``M = M0 + sum_new A_t^T Sigma^-1 A_t`` with ``M0`` the information of the tests already made
(:func:`vtestbed.design.minimax.design` with ``base_information``). The displacement noise is
taken from the identification's residuals (``component_std``, RMS over the three translations and
the three rotations) unless given. Researcher-side: Jacobians and wrenches from the dataset only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError
from ..researcher.identify import stack
from .minimax import MinimaxDesign, design
from .optimal import DesignReport, _prior, evaluate, measurement_covariance
from .pool import TestPool


def dataset_information(jacobians, wrenches, sigma_p: float, sigma_r: float) -> np.ndarray:
    """(n, n) information ``M0 = sum_t A_t^T Sigma^-1 A_t`` of tests made [(N*m/rad)^2].

    ``jacobians`` (T, 6, n) and ``wrenches`` (T, 6) in one frame per test (B's axes in a dataset):
    with ``Sigma = diag(sigma_p^2 I_3, sigma_r^2 I_3)`` the information does not depend on it.
    """
    a = stack(jacobians, wrenches).reshape(len(wrenches), 6, -1)
    w = 1.0 / np.diag(measurement_covariance(sigma_p, sigma_r))
    return np.einsum("tki,k,tkj->ij", a, w, a)


def noise_from_residuals(component_std) -> tuple[float, float]:
    """(sigma_p [m], sigma_r [rad]): RMS of an identification's residual std per component (6,)."""
    s = np.asarray(component_std, dtype=float)
    if s.shape != (6,) or not np.all(np.isfinite(s) & (s > 0)):
        raise OutOfRangeError(
            f"component_std must be 6 positive residual stds [m, m, m, rad, rad, rad], got {s!r}"
        )
    return float(np.sqrt(np.mean(s[:3] ** 2))), float(np.sqrt(np.mean(s[3:] ** 2)))


@dataclass(frozen=True)
class NextTests:
    """The next tests and what they are predicted to do (at the current estimate)."""

    estimate: np.ndarray  # (n,) N*m/rad, the prior of this design
    sigma_p: float  # m
    sigma_r: float  # rad
    made: int  # tests already made
    current: DesignReport | None  # the tests made, at the estimate (None: they leave M0 singular)
    result: MinimaxDesign  # the new tests, criteria of old + new
    tests: tuple  # the chosen CandidateTests

    def to_dict(self) -> dict:
        return {"estimate_Nmm_per_rad": (self.estimate * 1e3).tolist(), "sigma_p_m": self.sigma_p,
                "sigma_r_rad": self.sigma_r, "tests_made": self.made,
                "current_relative_std_percent": None if self.current is None else (self.current.relative_std * 100).tolist(),
                "current_worst_relative_std_percent": None if self.current is None else self.current.minimax_value * 100,
                "after_relative_std_percent": (self.result.selection.report.relative_std * 100).tolist(),
                "after_worst_relative_std_percent": self.result.selection.report.minimax_value * 100,
                **self.result.to_dict(), "tests": [t.to_dict() for t in self.tests]}  # fmt: skip


def next_tests(
    jacobians,
    wrenches,
    estimate,
    n: int,
    pool: TestPool,
    sigma_p: float,
    sigma_r: float,
    criterion: str = "minimax",
) -> NextTests:
    """Choose ``n`` tests from ``pool`` to add to the tests made (``jacobians`` (T, 6, n_j), ``wrenches`` (T, 6)).

    ``estimate`` (n_j,) [N*m/rad]: the current stiffness estimate, used as the prior; it must be positive.
    """
    k = np.asarray(estimate, dtype=float)
    if k.shape != (np.asarray(jacobians).shape[2],) or not np.all(np.isfinite(k) & (k > 0)):
        raise OutOfRangeError(
            f"the current stiffness estimate must be {np.asarray(jacobians).shape[2]} positive values [N*m/rad] "
            f"to serve as the prior, got {estimate!r}: identify more tests first"
        )
    k = _prior(k, len(k))
    m0 = dataset_information(jacobians, wrenches, sigma_p, sigma_r)
    a_made = stack(jacobians, wrenches).reshape(len(wrenches), 6, -1)
    try:
        current = evaluate(a_made, k, sigma_p, sigma_r)
    except OutOfRangeError:  # a pilot set too small to identify every joint on its own
        current = None
    result = design(pool.a, n, k, criterion, sigma_p, sigma_r, base_information=m0)
    chosen = tuple(pool.tests[i] for i in result.selection.indices)
    return NextTests(k, sigma_p, sigma_r, len(a_made), current, result, chosen)
