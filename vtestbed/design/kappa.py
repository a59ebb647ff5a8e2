"""Pose selection away from singularities: the arm-wrist criterion kappa(J_AW)^-1 (paper Sec. 3).

The paper's Eq. 18-19 are garbled in its text; vtestbed uses (docs/poses.md): the geometric
Jacobian ``J = [J_P; J_O]`` of a reference point ``p`` in base axes, split into 3x3 blocks::

    J11 = [z_1 x (p - p_1), z_2 x (p - p_2), z_3 x (p - p_3)]   [m]
    J22 = [z_4, z_5, z_6]                                        [1]
    inv_kappa = 1 / (kappa_F(J11) kappa_F(J22)),  kappa_F(M) = ||M||_F ||M^-1||_F / 3
              = 9 |det J11| |det J22| / (||J11||_F ||adj J11||_F ||J22||_F ||adj J22||_F)

evaluated in the second form: exactly 0 at a singular pose, in [0, 1], free of the length unit.
The default point is the wrist point (:func:`.wrist.wrist_point`): for a spherical wrist the origin of
DH frame 5 (axes 4-6 meet), where ``J12 = 0`` and ``det J = det J11 det J22`` (wrist, elbow and
shoulder singularities separate exactly; joints 1, 4, 6 cannot change the criterion); for an
offset wrist (UR type) the least-squares point of axes 4-6, where ``J12 != 0`` and the split is
an approximation whose size :func:`coupling_ratio` reports. Other points (``"flange"``,
``"block"`` or an offset in the flange frame) keep the same block formula.

All angles are DH angles in rad; lengths in m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution

from ..errors import OutOfRangeError, UnknownNameError
from ..lab import PAPER_LAB
from ..robots import RobotDescription
from .wrist import (  # re-exported: the criterion's geometry, defined in wrist.py
    NotSphericalWristError,
    check_wrist,
    dh_frames,
    least_squares_wrist_point,
    wrist_point,
)

POINTS = ("wrist", "flange", "block")
# The paper's reported optimum (Sec. 3.1), as printed [deg]; read as KUKA controller angles
# (theta_3 = A3 - 90 deg for the KR60-3) it is a high-criterion pose, read as DH it is not.
PAPER_OPTIMUM_DEG = (0.0, -4.4822, -99.912, 111.7901, 59.4099, 45.0)
# Paper Table 2: "rate of change" (second derivative at the maximum) of joints 2..5 [1/deg^2].
PAPER_TABLE2_PER_DEG2 = (1.4172e-4, -1.0774e-4, -3.6893e-5, -1.5070e-4)
PAPER_RANKING = (5, 2, 3, 4)


def reference_offset(point="wrist", block_in_flange: np.ndarray | None = None) -> np.ndarray | None:
    """The reference point as an offset [m] in the flange frame; ``None`` for the wrist centre.

    ``point`` is ``"wrist"``, ``"flange"``, ``"block"`` (origin of the lab's block frame B) or a
    (3,) offset in the flange frame [m].
    """
    if isinstance(point, str):
        if point == "wrist":
            return None
        if point == "flange":
            return np.zeros(3)
        if point == "block":
            if block_in_flange is None:
                block_in_flange = PAPER_LAB.block_in_flange
            return np.asarray(block_in_flange, dtype=float)[:3, 3].copy()
        raise UnknownNameError("reference point", point, POINTS)
    offset = np.asarray(point, dtype=float)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise OutOfRangeError(f"reference point offset must be 3 finite numbers [m], got {point!r}")
    return offset


def arm_wrist_blocks(robot: RobotDescription, q: np.ndarray, point="wrist"):
    """The blocks J11 (N, 3, 3) [m] and J22 (N, 3, 3) and the point (N, 3) [m], base axes.

    ``point`` as in :func:`reference_offset`; ``"wrist"`` is :func:`wrist_point` (the origin of
    DH frame 5 for a spherical wrist, the least-squares point of axes 4-6 otherwise).
    """
    j11, j22, p, _ = _blocks(robot, q, point)
    return j11, j22, p


def _blocks(robot: RobotDescription, q: np.ndarray, point, with_j12: bool = False):
    """:func:`arm_wrist_blocks` plus, if asked, the block J12 (N, 3, 3) [m] (else ``None``)."""
    offset = reference_offset(point)
    spherical = check_wrist(robot)
    rot, pos = dh_frames(robot, q)
    z = rot[..., :, 2]  # (N, n, 3)
    if offset is not None:  # the offset is in the flange frame: move it into the last DH frame
        flange = robot.flange_transform
        p = pos[:, 5] + rot[:, 5] @ (flange[:3, :3] @ offset + flange[:3, 3])
    elif spherical:
        p = pos[:, 4]
    else:
        p = least_squares_wrist_point(z[:, 3:6], pos[:, 3:6])[0]
    j11 = np.stack([_cross(z[:, i], p - pos[:, i]) for i in range(3)], axis=-1)
    j12 = np.stack([_cross(z[:, i], p - pos[:, i]) for i in range(3, 6)], axis=-1) if with_j12 else None
    j22 = z[:, 3:6].transpose(0, 2, 1)
    return j11, j22, p, j12


def coupling_ratio(robot: RobotDescription, q: np.ndarray, point="wrist") -> np.ndarray:
    """``||J12||_F / ||J11||_F`` (N,) at poses ``q`` (N, 6): what the arm-wrist split neglects.

    0 at a spherical wrist's centre; at the UR10's least-squares wrist point ``||J12||_F`` is
    ``d_5 / sqrt(2)`` at every pose (two wrist columns of length ``d_5 / 2``).
    """
    j11, _, _, j12 = _blocks(robot, np.atleast_2d(q), point, with_j12=True)
    return np.linalg.norm(j12, axis=(1, 2)) / np.linalg.norm(j11, axis=(1, 2))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product along the last axis (faster than np.cross for small batches)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def inv_kappa_frobenius(m: np.ndarray) -> np.ndarray:
    """``3 |det M| / (||M||_F ||adj M||_F)`` = 1/kappa_F(M) in [0, 1] for (..., 3, 3) matrices.

    ``adj M`` has the cross products of M's columns as rows, finite at singular matrices.
    """
    m = np.asarray(m, dtype=float)
    c1, c2, c3 = m[..., 0], m[..., 1], m[..., 2]
    x23, x31, x12 = _cross(c2, c3), _cross(c3, c1), _cross(c1, c2)
    det = (c1 * x23).sum(-1)
    adj = np.sqrt((x23**2).sum(-1) + (x31**2).sum(-1) + (x12**2).sum(-1))
    norm = np.sqrt((m**2).sum((-1, -2)))
    denom = norm * adj
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(denom > 0, 3.0 * np.abs(det) / np.where(denom > 0, denom, 1.0), 0.0)
    return np.minimum(out, 1.0)


def inv_kappa_batch(robot: RobotDescription, q: np.ndarray, point="wrist") -> np.ndarray:
    """The criterion (N,) at poses ``q`` (N, 6) [rad]; no limit check (see :func:`criterion`)."""
    j11, j22, _ = arm_wrist_blocks(robot, q, point)
    return inv_kappa_frobenius(j11) * inv_kappa_frobenius(j22)


@dataclass(frozen=True)
class CriterionValue:
    """The criterion at one pose and its two factors."""

    q: np.ndarray  # (6,) DH rad
    point: str
    inv_kappa: float  # in [0, 1]
    inv_kappa_arm: float  # 1/kappa_F(J11)
    inv_kappa_wrist: float  # 1/kappa_F(J22)
    det_j11: float  # m^3
    det_j22: float
    position: np.ndarray  # (3,) reference point in the base frame [m]
    wrist_axis_distances: np.ndarray  # (3,) non-sphericity: the wrist point's distance from axes 4-6 [m]
    coupling: float  # ||J12||_F / ||J11||_F at the point (0: the arm-wrist split is exact)

    def to_dict(self) -> dict:
        return {
            "q_deg": np.degrees(self.q).tolist(),
            "point": self.point,
            "inv_kappa": self.inv_kappa,
            "inv_kappa_arm": self.inv_kappa_arm,
            "inv_kappa_wrist": self.inv_kappa_wrist,
            "det_j11_m3": self.det_j11,
            "det_j22": self.det_j22,
            "position_m": self.position.tolist(),
            "wrist_axis_distances_m": self.wrist_axis_distances.tolist(),
            "coupling_j12_over_j11": self.coupling,
        }


def point_name(point) -> str:
    return point if isinstance(point, str) else "offset:" + ",".join(f"{v:g}" for v in np.ravel(point))


def criterion(robot: RobotDescription, q, point="wrist", check_limits: bool = True) -> CriterionValue:
    """The criterion at one DH pose ``q`` (6,) [rad]; raises on a pose outside the limits.

    Besides the factors it reports how far the wrist is from spherical at ``q`` (the wrist
    point's distances from axes 4-6, see :func:`wrist_point`) and the neglected coupling
    ``||J12||_F / ||J11||_F`` at the reference point (0 at a spherical wrist's centre).
    """
    check_wrist(robot)
    q = robot.check_pose(q, field="pose") if check_limits else np.asarray(q, dtype=float)
    if q.shape != (robot.dof,) or not np.all(np.isfinite(q)):
        raise OutOfRangeError(f"pose must be {robot.dof} finite DH angles [rad], got {q!r}")
    j11, j22, p = arm_wrist_blocks(robot, q[None], point)
    a, w = inv_kappa_frobenius(j11)[0], inv_kappa_frobenius(j22)[0]
    return CriterionValue(
        q=q.copy(), point=point_name(point), inv_kappa=float(a * w), inv_kappa_arm=float(a),
        inv_kappa_wrist=float(w), det_j11=float(np.linalg.det(j11[0])),
        det_j22=float(np.linalg.det(j22[0])), position=p[0],
        wrist_axis_distances=wrist_point(robot, q[None])[1][0],
        coupling=float(coupling_ratio(robot, q, point)[0]),
    )  # fmt: skip


def elbow_singular_theta3(robot: RobotDescription) -> tuple[float, float]:
    """theta_3 [rad] of the stretched and the folded elbow singularity (W in line with link 2-3).

    With axes 2, 3 parallel (``alpha_2 = 0``), W sits at ``(a_3, -sin(alpha_3) d_4)`` in the
    plane of frame 3; it lines up with ``x_2`` (the link 2-3) when
    ``a_3 sin(theta_3) - sin(alpha_3) d_4 cos(theta_3) = 0``. KR60-3: -79.97 and 100.03 deg.
    """
    j3, j4 = robot.joints[2], robot.joints[3]
    if abs(np.sin(j3.alpha_prev)) > 1e-12:
        raise NotSphericalWristError(f"{j3.name}.alpha_prev must be 0 (axes 2 and 3 parallel)")
    x, y = j4.a_prev, -np.sin(j4.alpha_prev) * j4.d
    stretched = float(np.arctan2(-y, x))
    folded = float((stretched + 2 * np.pi) % (2 * np.pi) - np.pi)
    return stretched, folded


def _free_bounds(robot: RobotDescription, joints) -> np.ndarray:
    return np.array([[robot.lower[j], robot.upper[j]] for j in joints])


@dataclass(frozen=True)
class Optimum:
    """The maximum of the criterion over joints 2-5 (DH, rad) with joints 1 and 6 fixed."""

    q: np.ndarray  # (6,) DH rad
    inv_kappa: float
    point: str
    seed: int
    nfev: int  # poses evaluated by the search and its polish
    gradient: np.ndarray  # (4,) d inv_kappa / d q_j, j = 2..5 [1/rad] (central differences)
    curvature: np.ndarray  # (4,) d2 inv_kappa / d q_j^2 [1/rad^2]
    at_limit: tuple[bool, ...]  # (4,) joint within 1e-6 rad of a limit

    def to_dict(self) -> dict:
        return {
            "q_deg": np.degrees(self.q).tolist(),
            "inv_kappa": self.inv_kappa,
            "point": self.point,
            "seed": self.seed,
            "nfev": self.nfev,
            "gradient_per_rad": self.gradient.tolist(),
            "curvature_per_rad2": self.curvature.tolist(),
            "curvature_per_deg2": (self.curvature * np.radians(1.0) ** 2).tolist(),
            "at_limit": list(self.at_limit),
        }


def finite_difference(f, x: np.ndarray, step: float = np.radians(0.5)) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradient and diagonal curvature of scalar ``f`` at ``x`` (Richardson).

    Returns ``(gradient (k,), curvature (k,))`` in units of f per unit (squared) of x.
    """
    x = np.asarray(x, dtype=float)
    grad, curv = np.empty(x.size), np.empty(x.size)
    f0 = f(x)
    for k in range(x.size):
        e = np.zeros(x.size)
        e[k] = 1.0
        g, c = [], []
        for h in (step, step / 2):
            fp, fm = f(x + h * e), f(x - h * e)
            g.append((fp - fm) / (2 * h))
            c.append((fp - 2 * f0 + fm) / h**2)
        grad[k] = (4 * g[1] - g[0]) / 3
        curv[k] = (4 * c[1] - c[0]) / 3
    return grad, curv


def optimize(
    robot: RobotDescription,
    point="wrist",
    seed: int = 0,
    q1: float = 0.0,
    q6: float = np.radians(45.0),
    maxiter: int = 400,
    popsize: int = 40,
    tol: float = 1e-10,
) -> Optimum:
    """Maximise the criterion over joints 2-5 within their limits (differential evolution).

    Joints 1 and 6 are fixed (``q1``, ``q6`` [rad], the paper's 0 and 45 deg). The same seed
    gives the same numbers; the result is polished by L-BFGS-B inside the bounds. At the wrist
    centre of a spherical wrist joint 4 has no influence, so its optimal value is arbitrary there.
    """
    check_wrist(robot)
    free = (1, 2, 3, 4)
    bounds = _free_bounds(robot, free)

    def full(x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        q = np.empty((x.shape[0], 6))
        q[:, 0], q[:, 5] = q1, q6
        q[:, 1:5] = x
        return q

    evaluations = [0]

    def neg(x: np.ndarray) -> np.ndarray:  # x: (4,) or (4, S) from the vectorised DE
        x = np.asarray(x, dtype=float)
        evaluations[0] += x.shape[1] if x.ndim == 2 else 1
        values = -inv_kappa_batch(robot, full(x.T if x.ndim == 2 else x), point)
        return values if x.ndim == 2 else float(values[0])

    result = differential_evolution(
        neg, bounds, seed=seed, maxiter=maxiter, popsize=popsize, tol=tol, polish=True,
        vectorized=True, updating="deferred", init="sobol",
    )  # fmt: skip
    n_eval = evaluations[0]
    x = np.clip(result.x, bounds[:, 0], bounds[:, 1])
    grad, curv = finite_difference(lambda v: -neg(np.clip(v, bounds[:, 0], bounds[:, 1])), x)
    at_limit = tuple(bool(min(x[k] - bounds[k, 0], bounds[k, 1] - x[k]) < 1e-6) for k in range(4))
    return Optimum(
        q=full(x)[0], inv_kappa=float(-neg(x)), point=point_name(point), seed=seed,
        nfev=n_eval, gradient=grad, curvature=curv, at_limit=at_limit,
    )  # fmt: skip


def paper_optimum(robot: RobotDescription, as_controller: bool = True) -> np.ndarray:
    """The paper's optimum as DH angles [rad]: read as controller angles (default) or as DH."""
    q = np.radians(PAPER_OPTIMUM_DEG)
    return robot.controller_to_dh(q) if as_controller else q
