"""Joint influence on the criterion (paper Sec. 3.2, Figures 3-4 and Table 2).

The criterion is swept along each of joints 2-5 through a pose (normally the optimum) over the
joint's whole range; the influence of a joint is the curvature of that curve at the pose
(``d2 inv_kappa / d theta^2`` in 1/deg^2, as the paper's Table 2), by central finite
differences on the criterion itself, or, as the paper did, from an eighth-order Fourier fit
``a_0 + sum_k a_k cos(k w theta) + b_k sin(k w theta)`` of the sampled curve (``w`` fitted as
MATLAB's ``fourier8`` does, or fixed at one period over the joint range).

Angles are DH angles in rad inside; curvatures are reported per deg^2 to compare with the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, UnknownNameError
from ..robots import RobotDescription
from .kappa import (
    PAPER_RANKING,
    PAPER_TABLE2_PER_DEG2,
    check_wrist,
    finite_difference,
    inv_kappa_batch,
    optimize,
    paper_optimum,
    point_name,
)

DEG2 = np.radians(1.0) ** 2  # rad^2 per deg^2
METHODS = ("fd", "fourier")


@dataclass(frozen=True)
class FourierFit:
    """``y = a0 + sum_k a_k cos(k w x) + b_k sin(k w x)`` with x in deg."""

    coefficients: np.ndarray  # (2 order + 1,) a0, a1, b1, a2, b2, ...
    w: float  # rad per deg
    rms: float  # residual, units of y

    @property
    def order(self) -> int:
        return (self.coefficients.size - 1) // 2

    def _design(self, x: np.ndarray, derivative: int = 0) -> np.ndarray:
        return _fourier_design(np.asarray(x, dtype=float), self.w, self.order, derivative)

    def __call__(self, x) -> np.ndarray:
        return self._design(x) @ self.coefficients

    def second_derivative(self, x) -> np.ndarray:
        """d2y/dx2 [units of y per deg^2]."""
        return self._design(x, 2) @ self.coefficients


def _fourier_design(x: np.ndarray, w: float, order: int, derivative: int = 0) -> np.ndarray:
    cols = [np.full_like(x, 1.0 if derivative == 0 else 0.0)]
    for k in range(1, order + 1):
        kw = k * w
        if derivative == 0:
            cols += [np.cos(kw * x), np.sin(kw * x)]
        else:  # second derivative
            cols += [-(kw**2) * np.cos(kw * x), -(kw**2) * np.sin(kw * x)]
    return np.stack(cols, axis=-1)


def fourier_fit(x_deg, y, order: int = 8, fit_frequency: bool = True) -> FourierFit:
    """Least-squares Fourier series of ``order`` through samples (x [deg], y).

    ``w`` is one period over the sampled range, or (``fit_frequency``) the best ``w`` in
    ``[0.3, 1.0]`` times that, found by a grid and golden-section search on the residual.
    """
    x, y = np.asarray(x_deg, dtype=float), np.asarray(y, dtype=float)
    if order < 1 or x.size < 2 * order + 2:
        raise OutOfRangeError(f"fourier order = {order} needs >= 1 and at least {2 * order + 2} samples")
    w0 = 2 * np.pi / (x.max() - x.min())

    def solve(w: float) -> tuple[float, np.ndarray]:
        design = _fourier_design(x, w, order)
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        return float(np.sqrt(np.mean((design @ coef - y) ** 2))), coef

    w = w0
    if fit_frequency:
        grid = w0 * np.linspace(0.3, 1.0, 36)
        best = int(np.argmin([solve(g)[0] for g in grid]))
        lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
        golden = (np.sqrt(5) - 1) / 2
        for _ in range(40):
            a, b = hi - golden * (hi - lo), lo + golden * (hi - lo)
            lo, hi = (lo, b) if solve(a)[0] < solve(b)[0] else (a, hi)
        w = (lo + hi) / 2
    rms, coef = solve(w)
    return FourierFit(coefficients=coef, w=float(w), rms=rms)


@dataclass(frozen=True)
class JointCurve:
    """The criterion along one joint through a pose."""

    joint: int  # 1-based joint number
    angles: np.ndarray  # (m,) DH rad, the joint's range
    values: np.ndarray  # (m,) criterion
    at: float  # DH rad, the joint's value in the pose
    curvature_fd: float  # 1/deg^2
    curvature_fourier: float | None  # 1/deg^2
    fourier_rms: float | None

    def curvature(self, method: str) -> float:
        return self.curvature_fd if method == "fd" else float(self.curvature_fourier)


@dataclass(frozen=True)
class Influence:
    """Influence of joints on the criterion at one pose; ranking by |curvature|, largest first."""

    q: np.ndarray  # (6,) DH rad
    point: str
    method: str
    curves: tuple[JointCurve, ...]

    @property
    def joints(self) -> tuple[int, ...]:
        return tuple(c.joint for c in self.curves)

    @property
    def curvature_per_deg2(self) -> np.ndarray:
        return np.array([c.curvature(self.method) for c in self.curves])

    @property
    def ranking(self) -> tuple[int, ...]:
        order = np.argsort(-np.abs(self.curvature_per_deg2), kind="stable")
        return tuple(self.joints[i] for i in order)

    def to_dict(self) -> dict:
        return {
            "q_deg": np.degrees(self.q).tolist(),
            "point": self.point,
            "method": self.method,
            "joints": list(self.joints),
            "curvature_per_deg2": self.curvature_per_deg2.tolist(),
            "curvature_fd_per_deg2": [c.curvature_fd for c in self.curves],
            "curvature_fourier_per_deg2": [c.curvature_fourier for c in self.curves],
            "ranking": list(self.ranking),
            "paper": compare_with_paper(self),
        }


def joint_influence(
    robot: RobotDescription,
    q,
    point="wrist",
    joints=(2, 3, 4, 5),
    samples: int = 721,
    step_deg: float = 0.5,
    method: str = "fd",
    fourier_order: int = 8,
    fit_frequency: bool = True,
) -> Influence:
    """Sweep each joint over its range through ``q`` (6,) [rad] and measure the curvature there.

    Parameters
    ----------
    joints : 1-based joint numbers to sweep
    samples : points per sweep (the curves; the Fourier fit uses them)
    step_deg : finite-difference step [deg] (Richardson-extrapolated central differences)
    method : ``"fd"`` ranks by finite differences, ``"fourier"`` by the Fourier fit (both are
        always reported when ``method == "fourier"``)
    """
    check_wrist(robot)
    if method not in METHODS:
        raise UnknownNameError("influence method", method, METHODS)
    q = robot.check_pose(q, field="influence pose")
    curves = []
    for joint in joints:
        if not 1 <= joint <= robot.dof:
            raise OutOfRangeError(f"joint = {joint} is outside the valid range [1, {robot.dof}]")
        i = joint - 1
        angles = np.linspace(robot.lower[i], robot.upper[i], samples)
        sweep = np.tile(q, (samples, 1))
        sweep[:, i] = angles
        values = inv_kappa_batch(robot, sweep, point)

        def along(t: np.ndarray, i: int = i) -> float:
            pose = q.copy()
            pose[i] = np.clip(t[0], robot.lower[i], robot.upper[i])
            return float(inv_kappa_batch(robot, pose[None], point)[0])

        _, curv = finite_difference(along, np.array([q[i]]), step=np.radians(step_deg))
        fourier, rms = None, None
        if method == "fourier":
            fit = fourier_fit(np.degrees(angles), values, order=fourier_order, fit_frequency=fit_frequency)
            fourier, rms = float(fit.second_derivative(np.degrees(q[i]))), fit.rms
        curves.append(JointCurve(joint, angles, values, float(q[i]), float(curv[0] * DEG2), fourier, rms))
    return Influence(q=q.copy(), point=point_name(point), method=method, curves=tuple(curves))


def compare_with_paper(influence: Influence) -> dict:
    """Ranking and magnitudes against the paper's Table 2 (joints 2-5 only).

    Returns the Kendall tau between the two rankings (1 = same order) and, per joint, the
    ratio |ours| / |paper| with the RMS of its log10 over the joints.
    """
    paper = dict(zip((2, 3, 4, 5), PAPER_TABLE2_PER_DEG2))
    ours = dict(zip(influence.joints, influence.curvature_per_deg2))
    common = [j for j in (2, 3, 4, 5) if j in ours]
    rank_ours = [influence.ranking.index(j) for j in common if j in influence.ranking]
    paper_rank = [j for j in PAPER_RANKING if j in common]
    rank_paper = [paper_rank.index(j) for j in common]
    from scipy.stats import kendalltau  # here: scipy.stats costs campaign workers 0.4 s and ~25 MiB

    tau = float(kendalltau(rank_ours, rank_paper).statistic) if len(common) > 1 else float("nan")
    ratio = {j: float(abs(ours[j]) / abs(paper[j])) for j in common}
    with np.errstate(divide="ignore"):
        logs = np.log10([max(r, 1e-300) for r in ratio.values()])
    return {
        "paper_ranking": list(PAPER_RANKING),
        "ranking": list(influence.ranking),
        "same_ranking": list(influence.ranking) == paper_rank,
        "kendall_tau": tau,
        "paper_curvature_per_deg2": [paper[j] for j in common],
        "ratio_to_paper": [ratio[j] for j in common],
        "log10_ratio_rms": float(np.sqrt(np.mean(logs**2))),
    }


def reference_point_study(
    robot: RobotDescription, points=("wrist", "flange", "block"), seed: int = 0, method="fd"
):
    """For each reference point: its optimum, the influence there and at the paper's pose.

    Returns a list of dicts (one per point) with the comparison against Table 2, to see which
    reference point the paper's Jacobian was most likely taken at.
    """
    rows = []
    for point in points:
        opt = optimize(robot, point=point, seed=seed)
        at_opt = joint_influence(robot, opt.q, point=point, method=method)
        at_paper = joint_influence(robot, paper_optimum(robot), point=point, method=method)
        rows.append(
            {
                "point": point_name(point),
                "optimum_q_deg": np.degrees(opt.q).tolist(),
                "optimum_inv_kappa": opt.inv_kappa,
                "at_optimum": at_opt.to_dict(),
                "at_paper_pose": at_paper.to_dict(),
            }
        )
    return rows
