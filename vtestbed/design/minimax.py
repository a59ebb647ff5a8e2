"""Minimax design: minimise the worst joint's relative std, with a certified lower bound.

Notation as in :mod:`vtestbed.design.optimal`: a test t contributes ``I_t = C_t^T C_t`` to the
relative information ``M_rel = sum_t I_t``, with the whitened, prior-scaled
``C_t = Sigma^-1/2 A_t S`` (6, n), ``S = diag(1/k_prior)``. The criteria, on ``d_j = (M_rel^-1)_jj
= (std(k_j)/k_j)^2``:

* minimax: ``f = max_j d_j`` (minimise; reported as ``sqrt(f)``, the worst relative std),
* A: ``sum_j d_j`` (minimise), D: ``log det M_rel`` (maximise).

**Discrete choice** (:func:`design`): N distinct tests by greedy addition and Fedorov exchange on
the exact criterion (:func:`vtestbed.design.optimal.select_tests`), and a second exchange started
from the rounded relaxation; the better one is kept.

**Convex relaxation** (:func:`relax`): design weights ``0 <= w_t <= 1``, ``sum w = N``, ``M(w) =
sum_t w_t I_t``. Every set of N distinct tests is such a ``w``, so the relaxed optimum is at most
the discrete one. ``d_j(w)`` is convex in ``w`` (matrix-fractional), hence so are ``max_j d_j``
and, for any joint weights ``lambda`` on the simplex, ``phi_lambda(w) = sum_j lambda_j d_j(w) <=
max_j d_j(w)``. Convexity gives, at any feasible ``w``, the Frank-Wolfe bound

    min_w' max_j d_j(w') >= min_w' phi_lambda(w') >= phi_lambda(w) + min_v grad phi_lambda(w) . (v - w)

where ``v`` ranges over the same polytope (the N candidates of smallest gradient get 1):
a **certified lower bound** for every ``lambda`` and ``w``. ``w`` comes from Frank-Wolfe on the
smooth ``(sum_j d_j^p)^(1/p)`` (>= max, at most ``n^(1/p)`` times it), ``lambda`` from
exponentiated-gradient ascent on the bound. ``grad_t d_j = -||C_t M^-1 e_j||^2`` (one matmul).
For A the bound is the same with ``lambda`` uniform; for D the upper bound is
``log det M(w) + max_v tr(M^-1 (M(v) - M(w)))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, UnknownNameError
from .optimal import (
    SIGMA_P,
    SIGMA_R,
    Selection,
    _a_stack,
    _prior,
    evaluate,
    exchange,
    measurement_covariance,
    select_tests,
    test_information,
)

RELAXED = ("minimax", "A", "D")  # the criteria with a relaxation and a bound


def whitened(tests, stiffness_prior, sigma_p: float = SIGMA_P, sigma_r: float = SIGMA_R) -> np.ndarray:
    """(T, 6, n) ``C_t = Sigma^-1/2 A_t diag(1/k_prior)`` (dimensionless), ``I_t = C_t^T C_t``."""
    a = _a_stack(tests)
    w = 1.0 / np.sqrt(np.diag(measurement_covariance(sigma_p, sigma_r)))
    s = 1.0 / _prior(stiffness_prior, a.shape[2])
    return a * w[None, :, None] * s[None, None, :]


def _info(c: np.ndarray, w: np.ndarray, base=None) -> np.ndarray:
    """(n, n) ``base + sum_t w_t C_t^T C_t`` (``base``: relative information of tests already made)."""
    cw = c * np.sqrt(w)[:, None, None]
    flat = cw.reshape(-1, c.shape[2])
    return flat.T @ flat if base is None else base + flat.T @ flat


def _value(m: np.ndarray, criterion: str) -> float:
    """Criterion value of one (n, n) relative information (minimax: max d_j; A: sum d_j; D: log det)."""
    if criterion == "D":
        sign, logdet = np.linalg.slogdet(m)
        return float(logdet) if sign > 0 else -np.inf
    try:
        d = np.diag(np.linalg.inv(m))
    except np.linalg.LinAlgError:
        return np.inf
    return float(d.max() if criterion == "minimax" else d.sum())


def _smallest_sum(g: np.ndarray, n: int) -> tuple[float, np.ndarray]:
    """Sum and indices of the ``n`` smallest entries of ``g`` (the vertex ``v`` of the polytope)."""
    idx = np.argpartition(g, n - 1)[:n] if n < len(g) else np.arange(len(g))
    return float(g[idx].sum()), idx


@dataclass(frozen=True)
class Relaxation:
    """Continuous design and its certified bound.

    ``value``: the criterion at ``weights`` (an upper bound on the relaxed optimum for minimax/A,
    a lower bound for D); ``bound``: certified lower (minimax, A) or upper (D) bound on every design
    of N distinct tests from the pool. Minimax values are variances ``max_j d_j``.
    """

    criterion: str
    n_tests: int
    weights: np.ndarray  # (T,) in [0, 1], summing to n_tests
    value: float
    bound: float
    joint_weights: np.ndarray  # (n,) lambda of the bound (minimax), uniform for A, empty for D
    iterations: int

    def to_dict(self) -> dict:
        out = {"criterion": self.criterion, "iterations": self.iterations,
               "support": int(np.sum(self.weights > 1e-6)), "joint_weights": self.joint_weights.tolist()}  # fmt: skip
        if self.criterion == "minimax":
            return out | {"relaxed_worst_relative_std_percent": float(np.sqrt(self.value)) * 100,
                          "lower_bound_worst_relative_std_percent": float(np.sqrt(self.bound)) * 100}  # fmt: skip
        return out | {"relaxed_value": self.value, "bound": self.bound}


def _minimax_bound(c, n, w, base=None, iterations: int = 300):
    """Best lambda (exponentiated-gradient ascent) for the Frank-Wolfe lower bound at ``w``."""
    b = np.linalg.inv(_info(c, w, base))
    d = np.diag(b)
    h = -np.einsum("tkj,tkj->tj", *(2 * [c @ b]))  # (T, n) grad of d_j w.r.t. w_t
    hw = w @ h
    lam = d / d.sum()
    best, best_lam = -np.inf, lam
    for it in range(iterations):
        g = h @ lam
        low, idx = _smallest_sum(g, n)
        bound = lam @ d + low - hw @ lam
        if bound > best:
            best, best_lam = bound, lam.copy()
        sub = d + h[idx].sum(axis=0) - hw  # supergradient of the bound in lambda
        step = 2.0 / (np.abs(sub).max() + 1e-300) / np.sqrt(it + 1)
        lam = lam * np.exp(step * sub)
        lam /= lam.sum()
    return best, best_lam


def relax(
    c: np.ndarray, n: int, criterion: str = "minimax", iterations: int = 400, p: float = 32.0, base=None
) -> Relaxation:
    """Frank-Wolfe on the relaxed design (weights in [0, 1], sum ``n``) and its certified bound.

    Parameters
    ----------
    c : (T, 6, n_joints) array from :func:`whitened`.
    n : int, the number of tests N (1 <= n <= T).
    criterion : "minimax", "A" or "D".
    iterations : Frank-Wolfe steps (each one matmul over the pool and a line search).
    p : exponent of the smooth surrogate of the max (minimax only).
    base : (n_joints, n_joints) relative information ``S M0 S`` of tests already made, or None.
    """
    if criterion not in RELAXED:
        raise UnknownNameError("relaxed design criterion", criterion, RELAXED)
    t_count = c.shape[0]
    if not 1 <= n <= t_count:
        raise OutOfRangeError(f"n = {n} tests is outside the valid range [1, {t_count}] (the candidates)")
    w = np.full(t_count, n / t_count)
    if np.linalg.matrix_rank(_info(c, w, base)) < c.shape[2]:
        raise OutOfRangeError(
            f"the {t_count} candidates do not identify all {c.shape[2]} joints (M is singular)"
        )

    def surrogate(ms):
        """Values of the minimised objective at a batch (G, n, n) of information matrices."""
        if criterion == "D":
            sign_, logdet = np.linalg.slogdet(ms)
            return np.where(sign_ > 0, -logdet, np.inf)
        try:
            d = np.diagonal(np.linalg.inv(ms), axis1=1, axis2=2)
        except np.linalg.LinAlgError:
            return np.array([_value(m, criterion) if criterion == "A" else _value(m, "minimax") for m in ms])
        if criterion == "A":
            return d.sum(axis=1)
        top = d.max(axis=1, keepdims=True)
        out = top[:, 0] * np.sum((d / top) ** p, axis=1) ** (1 / p)
        return np.where(np.all(d > 0, axis=1), out, np.inf)

    def line_search(m, mv):
        """Best step on a geometric grid of 49 steps in [1e-6, 1], refined linearly (one batch each)."""
        grid = np.r_[0.0, np.logspace(-6, 0, 48)]
        f = surrogate((1 - grid)[:, None, None] * m + grid[:, None, None] * mv)
        i = int(np.argmin(f))
        fine = np.linspace(grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)], 33)
        f2 = surrogate((1 - fine)[:, None, None] * m + fine[:, None, None] * mv)
        return float(fine[int(np.argmin(f2))])

    it = 0
    while it < iterations:
        it += 1
        m = _info(c, w, base)
        b = np.linalg.inv(m)
        cb = c @ b
        if criterion == "D":
            g = -np.einsum("tkj,tkj->t", cb, c)
        else:
            d = np.diag(b)
            lam = (d / d.max()) ** (p - 1) if criterion == "minimax" else np.ones_like(d)
            g = -np.einsum("tkj,tkj,j->t", cb, cb, lam)
        _, idx = _smallest_sum(g, n)
        v = np.zeros(t_count)
        v[idx] = 1.0
        mv = _info(c[idx], v[idx], base)  # M at the vertex: (1 - gamma) m + gamma mv stays affine
        gamma = line_search(m, mv)
        if gamma < 1e-12:
            break
        w = (1 - gamma) * w + gamma * v
    m = _info(c, w, base)
    value = _value(m, criterion)
    b = np.linalg.inv(m)
    if criterion == "minimax":
        bound, lam = _minimax_bound(c, n, w, base)
    elif criterion == "A":
        h = -np.einsum("tkj,tkj->t", *(2 * [c @ b]))
        bound, lam = value + _smallest_sum(h, n)[0] - h @ w, np.full(c.shape[2], 1.0 / c.shape[2])
    else:
        h = np.einsum("tkj,tkj->t", c @ b, c)
        bound, lam = value - _smallest_sum(-h, n)[0] - h @ w, np.zeros(0)
    return Relaxation(criterion, n, w, value, float(bound), lam, it)


@dataclass(frozen=True)
class MinimaxDesign:
    """A discrete design with its relaxation: ``ratio`` = chosen / bound (>= 1; 1/ratio for D)."""

    selection: Selection
    relaxation: Relaxation | None
    starts: dict  # criterion value from each start ("greedy", "relaxation")

    @property
    def ratio(self) -> float | None:
        """How far the chosen set is from the best the pool allows (worst relative std for minimax)."""
        if self.relaxation is None:
            return None
        rep, bound = self.selection.report, self.relaxation.bound
        if self.selection.criterion == "minimax":
            return rep.minimax_value / np.sqrt(bound)
        if self.selection.criterion == "A":
            return rep.a_value / bound
        return float(np.exp((bound - rep.d_value) / rep.information.shape[0]))  # geometric-mean ratio

    def to_dict(self) -> dict:
        out = {"selection": self.selection.to_dict(), "starts": self.starts, "chosen_over_bound": self.ratio}
        if self.relaxation is not None:
            out["relaxation"] = self.relaxation.to_dict()
        return out


def design(
    tests,
    n: int,
    stiffness_prior,
    criterion: str = "minimax",
    sigma_p: float = SIGMA_P,
    sigma_r: float = SIGMA_R,
    iterations: int = 400,
    bound: bool = True,
    base_information=None,
    starts=None,
) -> MinimaxDesign:
    """Choose ``n`` distinct tests: exchange from greedy and from the rounded relaxation, keep the better.

    ``tests``: CandidateTests or a (T, 6, n_joints) stack of A matrices. For E no relaxation is
    computed (greedy + exchange only). ``bound=False`` skips the relaxation for A/D/minimax too.
    ``base_information`` (n, n) [(N*m/rad)^2]: the information ``M0`` of tests already made
    (sequential design); the criteria and the bound are then those of the old and new tests together.
    ``starts``: further named starts, name -> ``n`` indices into ``tests`` (e.g. an earlier choice
    from a pool that grew, :mod:`vtestbed.design.refine`); each is exchanged too and kept if better.
    """
    a = _a_stack(tests)
    greedy = select_tests(a, n, stiffness_prior, criterion, "exchange", sigma_p, sigma_r,
                          base_information=base_information)  # fmt: skip
    values = {"greedy": _score(greedy, criterion)}
    better, rel = greedy, None
    if criterion in RELAXED and bound:
        s = 1.0 / _prior(stiffness_prior, a.shape[2])
        base = (
            None if base_information is None else np.asarray(base_information, dtype=float) * np.outer(s, s)
        )
        rel = relax(whitened(a, stiffness_prior, sigma_p, sigma_r), n, criterion, iterations, base=base)
        top = np.argsort(-rel.weights, kind="stable")[:n]
        rounded = _exchange_from(a, top, stiffness_prior, criterion, sigma_p, sigma_r, base_information)
        values["relaxation"] = _score(rounded, criterion)
        better = rounded if _better(rounded, greedy, criterion) else greedy
    for name, start in (starts or {}).items():
        other = _exchange_from(a, start, stiffness_prior, criterion, sigma_p, sigma_r, base_information)
        values[name] = _score(other, criterion)
        better = other if _better(other, better, criterion) else better
    return MinimaxDesign(better, rel, values)


def _score(sel: Selection, criterion: str) -> float:
    rep = sel.report
    return {"minimax": rep.minimax_value, "A": rep.a_value, "D": rep.d_value, "E": rep.e_value}[criterion]


def _better(x: Selection, y: Selection, criterion: str) -> bool:
    sx, sy = _score(x, criterion), _score(y, criterion)
    return sx > sy if criterion in ("D", "E") else sx < sy


def _exchange_from(
    a, start, prior, criterion, sigma_p, sigma_r, base_information=None, max_passes=20
) -> Selection:
    """Fedorov exchange on the exact criterion from the tests ``start`` (indices into ``a``)."""
    info = test_information(a, sigma_p, sigma_r)
    s = 1.0 / _prior(prior, info.shape[1])
    info = info * np.outer(s, s)
    total = info[[int(i) for i in start]].sum(axis=0)
    if base_information is not None:
        total = total + np.asarray(base_information, dtype=float) * np.outer(s, s)
    chosen, swaps = exchange(info, [int(i) for i in start], total, criterion, max_passes)
    report = evaluate(a[chosen], 1.0 / s, sigma_p, sigma_r, base_information)
    return Selection(tuple(chosen), criterion, "relaxation+exchange", report, swaps)
