"""Cramer-Rao bound of the joint stiffnesses for a test set, from the scanner's point-noise model.

Chain (docs/poses.md, "The Cramer-Rao bound"):

1. **Block frame from one scan.** The scanner sees the block's +x, +y, +z faces (B occupies
   ``[-edge, 0]^3``; the origin is the visible corner). A small pose error ``(do, omega)`` of B (its
   origin [m] and rotation [rad], both in B's axes) moves face k (outward normal ``e_k``) at a point
   ``x`` by ``e_k . (do + omega x x)`` along its normal. The scanner errs along its ray with
   ``s = range_std / cos(theta)^g``, i.e. ``s cos(theta)`` along the normal
   (:class:`vtestbed.world.scan_noise.ScanNoise`, docs/scanner.md), independently per point, so the
   Fisher information of the rigid 6-D pose is
   ``J = sum_i kappa_i g_i g_i^T / (s_i cos theta_i)^2``, ``g_i = [e_k ; x_i x e_k]``, with
   ``kappa_i`` the probability that point i is kept (no dropout, no outlier).
2. **Drift.** The scan's rigid drift ``(t_d, omega_d)`` moves the whole cloud: the block appears at
   ``D T``, an additive Gaussian pose error ``[t_d - [r]x omega_d ; omega_d]`` (``r`` from the
   scanner to B's origin). Marginalising it (Woodbury): the frame's bound is ``J^-1 + P_drift``.
3. **Displacement.** Two independent scans (unloaded, loaded; the geometry moves by well under a
   millimetre): ``Sigma_t = 2 R (J^-1 + P_drift) R^T`` in base axes, ``R = blockdiag(R_B, R_B)``.
4. **Stiffness.** ``delta_d_t = A_t c + e_t``: ``M = sum_t A_t^T Sigma_t^-1 A_t``, ``cov(c) >= M^-1``
   and, by the delta method, ``std(k_j) >= k_j^2 sqrt((M^-1)_jj)``. The wrench is taken as known
   (the F/T sensor's noise is left out).

The ray cast here is the nominal one (a pinhole grid on the block's three faces, no occluders),
so the design room needs no MuJoCo. ``noise`` is any object with :class:`ScanNoise`'s fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError
from ..lab import DEFAULT_SCANNER_DISTANCE_M, PAPER_LAB, LabSetup
from ..researcher.kinematics import ArmKinematics
from ..robots import RobotDescription

NOISE_FIELDS = ("range_std_m", "grazing_exponent", "dropout_start_deg", "dropout_full_deg",
                "outlier_fraction", "drift_translation_std_m", "drift_rotation_std_rad")  # fmt: skip
DEFAULT_SPACING_M = 0.5e-3  # the scanner's point spacing at the stand-off (docs/scanner.md)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True, eq=False)
class ScanPoints:
    """Noise-free hits on the block's three faces, in the block frame B [m].

    ``points`` (N, 3), ``directions`` (N, 3) unit rays, ``face`` (N,) 0/1/2 for +x/+y/+z,
    ``scanner`` (4, 4) pose of the scanner frame S in B.
    """

    points: np.ndarray
    directions: np.ndarray
    face: np.ndarray
    scanner: np.ndarray

    @property
    def normals(self) -> np.ndarray:
        """(N, 3) outward unit normals (B axes)."""
        return np.eye(3)[self.face]

    @property
    def cos_incidence(self) -> np.ndarray:
        """(N,) cosine of the angle between each ray and its face's normal."""
        return np.clip(-np.take_along_axis(self.directions, self.face[:, None], axis=1)[:, 0], 0.0, 1.0)


def nominal_scan(
    edge_m: float,
    distance_m: float = DEFAULT_SCANNER_DISTANCE_M,
    view_direction_block=(1.0, 1.0, 1.0),
    up_block=(0.0, 0.0, 1.0),
    spacing_m: float = DEFAULT_SPACING_M,
) -> ScanPoints:
    """Ray-cast the block's +x, +y, +z faces as ``Scanner.place`` + ``Scanner.cast`` would.

    The scanner stands ``distance_m`` from the block centre along ``view_direction_block`` (B axes),
    looks at the centre, has ``up_block`` (the world's up in B) up in its image and casts a pinhole
    grid of ``spacing_m / distance_m`` in normalised image coordinates (``spacing_m`` [m] between
    points on a plane facing it at the stand-off).
    """
    if not (edge_m > 0 and distance_m > 0 and spacing_m > 0):
        raise OutOfRangeError(
            f"edge_m = {edge_m!r}, distance_m = {distance_m!r} and spacing_m = {spacing_m!r} must be > 0 [m]"
        )
    view = np.asarray(view_direction_block, dtype=float)
    if view.shape != (3,) or not np.all(view > 0):
        raise OutOfRangeError(
            f"view_direction_block must have three positive components, got {view_direction_block!r}"
        )
    view = view / np.linalg.norm(view)
    z_axis, up = -view, np.asarray(up_block, dtype=float)
    y_axis = -(up - (up @ z_axis) * z_axis)
    if np.linalg.norm(y_axis) < 1e-6:
        y_axis = np.cross(z_axis, [1.0, 0.0, 0.0])
    y_axis /= np.linalg.norm(y_axis)
    rot = np.column_stack([np.cross(y_axis, z_axis), y_axis, z_axis])
    position = np.full(3, -edge_m / 2) + distance_m * view
    corners = np.array([[x, y, z] for x in (0, -edge_m) for y in (0, -edge_m) for z in (0, -edge_m)])
    cs = (corners - position) @ rot
    u, v = cs[:, 0] / cs[:, 2], cs[:, 1] / cs[:, 2]
    step = spacing_m / distance_m
    us = np.arange(np.ceil(u.min() / step), np.floor(u.max() / step) + 1) * step
    vs = np.arange(np.ceil(v.min() / step), np.floor(v.max() / step) + 1) * step
    uu, vv = np.meshgrid(us, vs)
    dirs_s = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)
    dirs = (dirs_s / np.linalg.norm(dirs_s, axis=1, keepdims=True)) @ rot.T
    best_t, face = np.full(len(dirs), np.inf), np.full(len(dirs), -1)
    for k in range(3):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -position[k] / dirs[:, k]
        hit = position + t[:, None] * dirs
        others = [j for j in range(3) if j != k]
        ok = (dirs[:, k] < 0) & np.all((hit[:, others] >= -edge_m) & (hit[:, others] <= 0), axis=1)
        better = ok & (t < best_t)
        best_t[better], face[better] = t[better], k
    keep = face >= 0
    points = position + best_t[keep, None] * dirs[keep]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, position
    return ScanPoints(points, dirs[keep], face[keep], pose)


def _noise(noise) -> dict:
    missing = [f for f in NOISE_FIELDS if not hasattr(noise, f)]
    if missing:
        raise OutOfRangeError(f"noise needs the ScanNoise fields {', '.join(missing)} (docs/scanner.md)")
    return {f: float(getattr(noise, f)) for f in NOISE_FIELDS}


def frame_information(scan: ScanPoints, noise) -> np.ndarray:
    """(6, 6) Fisher information of B's pose ``(do [m], omega [rad])`` (B axes) from one scan's points.

    Units [1/m^2 | 1/(m*rad) | 1/rad^2]. Infinite for a scanner without point noise.
    """
    p = _noise(noise)
    cos = scan.cos_incidence
    if p["range_std_m"] == 0.0:
        return np.full((6, 6), np.inf)
    cos_full = np.cos(np.radians(p["dropout_full_deg"]))
    along = p["range_std_m"] / np.maximum(cos, cos_full) ** p["grazing_exponent"]
    theta = np.degrees(np.arccos(cos))
    span = max(p["dropout_full_deg"] - p["dropout_start_deg"], 1e-12)
    kept = (1.0 - np.clip((theta - p["dropout_start_deg"]) / span, 0.0, 1.0)) * (1.0 - p["outlier_fraction"])
    normals = scan.normals
    g = np.hstack([normals, np.cross(scan.points, normals)])  # (N, 6)
    weight = kept / (along * np.maximum(cos, 1e-12)) ** 2
    return (g * weight[:, None]).T @ g


def drift_covariance(scan: ScanPoints, noise) -> np.ndarray:
    """(6, 6) covariance of B's apparent pose error from the scan's rigid drift (B axes)."""
    p = _noise(noise)
    r = -scan.scanner[:3, 3]  # from the scanner's optical centre to B's origin, B axes
    lin = np.eye(6)
    lin[:3, 3:] = -_skew(r)
    d = np.diag([p["drift_translation_std_m"] ** 2] * 3 + [p["drift_rotation_std_rad"] ** 2] * 3)
    return lin @ d @ lin.T


def frame_covariance(scan: ScanPoints, noise) -> np.ndarray:
    """(6, 6) Cramer-Rao bound of B's pose ``(do, omega)`` (B axes) from one scan: ``J^-1 + P_drift``."""
    info = frame_information(scan, noise)
    point_part = np.zeros((6, 6)) if np.isinf(info).any() else np.linalg.inv(info)
    return point_part + drift_covariance(scan, noise)


def displacement_covariance(frame_cov_block: np.ndarray, block_rotation: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of a displacement (two independent scans) in base axes [m^2 | rad^2]."""
    rot = np.zeros((6, 6))
    rot[:3, :3] = rot[3:, 3:] = np.asarray(block_rotation, dtype=float)
    return 2.0 * rot @ np.asarray(frame_cov_block, dtype=float) @ rot.T


@dataclass(frozen=True)
class StiffnessBound:
    """Cramer-Rao bound of the compliances and (delta method) the stiffnesses of a test set."""

    information: np.ndarray  # (n, n) M [(N*m/rad)^2]
    compliance_cov: np.ndarray  # (n, n) M^-1 [(rad/(N*m))^2]
    stiffness_std: np.ndarray  # (n,) N*m/rad
    relative_std: np.ndarray  # (n,) std(k_j)/k_j
    displacement_std: np.ndarray  # (T, 6) per test, base axes [m | rad]

    def to_dict(self) -> dict:
        return {"crlb_stiffness_std_Nmm_per_rad": (self.stiffness_std * 1e3).tolist(),
                "crlb_relative_std_percent": (self.relative_std * 100).tolist()}  # fmt: skip


def stiffness_bound(a, covariances, stiffness) -> StiffnessBound:
    """Bound for tests with ``A`` (T, 6, n) and displacement covariances (T, 6, 6) or one (6, 6).

    ``stiffness`` (n,) [N*m/rad]: where the delta method is taken (the truth for a Monte Carlo).
    """
    a = np.asarray(a, dtype=float)
    if a.ndim != 3 or a.shape[1] != 6:
        raise OutOfRangeError(f"A matrices must have shape (T, 6, n), got {a.shape}")
    cov = np.broadcast_to(np.asarray(covariances, dtype=float), (a.shape[0], 6, 6))
    k = np.asarray(stiffness, dtype=float)
    if k.shape != (a.shape[2],) or not np.all(k > 0):
        raise OutOfRangeError(f"stiffness must be {a.shape[2]} positive values [N*m/rad], got {stiffness!r}")
    m = np.einsum("tki,tkl,tlj->ij", a, np.linalg.inv(cov), a)
    if np.linalg.matrix_rank(m * np.outer(1 / k, 1 / k)) < a.shape[2]:
        raise OutOfRangeError(
            f"the {a.shape[0]} tests do not identify all {a.shape[2]} joints (M is singular)"
        )
    c_cov = np.linalg.inv(m)
    std_c = np.sqrt(np.diag(c_cov))
    disp = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    return StiffnessBound(m, c_cov, std_c * k**2, std_c * k, disp)


def pose_covariances(
    robot: RobotDescription,
    poses,
    noise,
    lab: LabSetup = PAPER_LAB,
    distance_m: float = DEFAULT_SCANNER_DISTANCE_M,
    view_direction_block=(1.0, 1.0, 1.0),
    spacing_m: float = DEFAULT_SPACING_M,
) -> np.ndarray:
    """(T, 6, 6) displacement covariance bound of each test pose (base axes), scanner placed as in the lab."""
    kin = ArmKinematics(robot, lab.block_in_flange)
    out = []
    for q in np.atleast_2d(poses):
        rot = kin.tool_pose(robot.check_pose(q, field="pose"), lab.block_in_flange)[:3, :3]
        scan = nominal_scan(
            lab.block.edge, distance_m, view_direction_block, rot.T @ [0.0, 0.0, 1.0], spacing_m
        )
        out.append(displacement_covariance(frame_covariance(scan, noise), rot))
    return np.array(out)
