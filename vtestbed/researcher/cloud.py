"""Point cloud -> three block faces -> block frame -> 6-D block displacement (open3d), and PLY files.

The chain follows the paper (Sec. 4.2) and runs unchanged on a lab scan read from PLY:

1. crop the cloud to a box around the block's nominal pose (known in the lab from the robot's
   kinematics and the scanner-to-robot calibration; for the loaded scan, the unloaded frame);
2. statistical outlier removal (open3d);
3. segmentation into the three mutually perpendicular faces: points are seeded to the nearest
   nominal face, open3d RANSAC (``segment_plane``) finds each plane among clutter, a least-squares
   (SVD) refit on the inliers with a MAD-based threshold reaches the statistical limit, and a final
   pass gives each point to the one fitted plane it lies on (points on two planes are dropped);
4. block frame: axes = the polar decomposition (nearest rotation) of the three fitted normals,
   origin = the intersection of the three fitted planes (the paper's O_i);
5. displacement of the block's reference point (B's origin) and rotation vector, in the scanner
   frame and, rotated with the scanner's calibrated pose, in the robot base frame. The paper's
   ``T = O1 O0^-1`` with its Euler angles is reported for comparison only: its translation
   ``o1 - R o0`` is the motion of the scanner's origin, not of the block (docs/architecture.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._open3d import o3d
from ..errors import OutOfRangeError, ScanError, check_range
from ..transforms import displacement, invert

FACES = ("+x", "+y", "+z")


@dataclass(frozen=True)
class FitParams:
    """Settings of :func:`fit_block_frame` (SI units).

    Attributes
    ----------
    edge_m : float
        Block edge [m]; the block occupies [-edge, 0]^3 in its frame B.
    crop_margin_m : float
        Margin [m] of the crop box around the nominal block; also how far the nominal pose may be off.
    sor_neighbors, sor_std_ratio, sor_voxel_m : int, float, float
        open3d statistical outlier removal (0 neighbours disables it), on the centroids of voxels of
        this edge [m] (0: on every point).
    ransac_threshold_m, ransac_iterations : float, int
        open3d ``segment_plane`` inlier distance [m] and iterations per face.
    inlier_sigmas, min_threshold_m, refine_iterations : float, float, int
        Least-squares refinement: inliers within ``max(inlier_sigmas * sigma, min_threshold_m)`` with
        the robust ``sigma = 1.4826 * median(|residual|)``
        of their own plane, iterated (at most ``refine_iterations`` times) until the set is stable.
    min_face_points : int
        Fewest points a face must keep.
    min_extent_fraction : float
        Each face's points must span this fraction of the edge along both in-plane axes.
    angle_tolerance_deg, max_skew_deg : float
        Largest angle between a fitted normal and its nominal axis, and largest deviation of two
        fitted normals from perpendicular.
    """

    edge_m: float = 0.08
    crop_margin_m: float = 0.010
    sor_neighbors: int = 8
    sor_std_ratio: float = 3.0
    sor_voxel_m: float = 2e-3
    ransac_threshold_m: float = 0.1e-3
    ransac_iterations: int = 50
    inlier_sigmas: float = 4.5
    min_threshold_m: float = 1e-6
    refine_iterations: int = 10
    min_face_points: int = 100
    min_extent_fraction: float = 0.5
    angle_tolerance_deg: float = 10.0
    max_skew_deg: float = 1.0

    def __post_init__(self):
        check_range("edge_m", self.edge_m, 1e-3, 1.0, "m")
        check_range("crop_margin_m", self.crop_margin_m, 0.0, self.edge_m / 2, "m")
        check_range("sor_neighbors", self.sor_neighbors, 0, 100)
        check_range("sor_voxel_m", self.sor_voxel_m, 0.0, self.edge_m / 4, "m")
        check_range("ransac_threshold_m", self.ransac_threshold_m, 1e-9, 0.01, "m")
        check_range("ransac_iterations", self.ransac_iterations, 1, 100000)
        check_range("min_face_points", self.min_face_points, 3, 1e9)
        check_range("min_extent_fraction", self.min_extent_fraction, 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class BlockFrame:
    """The fitted block frame and its diagnostics; rows ordered as the faces +x, +y, +z of B.

    Attributes
    ----------
    pose : (4, 4) array
        Pose of B in the cloud's frame (the scanner frame for a scan) [m].
    normals : (3, 3) array
        Fitted outward unit normals (rows), before orthonormalisation.
    offsets : (3,) array
        Plane offsets [m]: ``normals[k] @ x = offsets[k]`` on face k.
    counts : (3,) int array
        Points used in each face's final fit.
    rms_residual_m : (3,) array
        RMS distance [m] of those points from their plane.
    skew_rad : float
        Largest deviation of two fitted normals from perpendicular [rad].
    n_input, n_cropped, n_outliers_removed : int
        Points given, inside the crop box, and removed by the statistical outlier filter.
    """

    pose: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    counts: np.ndarray
    rms_residual_m: np.ndarray
    skew_rad: float
    n_input: int
    n_cropped: int
    n_outliers_removed: int


def _as_points(points, name: str = "points") -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise OutOfRangeError(f"{name} must be an (N, 3) array of coordinates in m, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise OutOfRangeError(f"{name} contains {np.sum(~np.isfinite(pts))} non-finite values")
    return pts


def _as_pose(pose, name: str) -> np.ndarray:
    pose = pose.pose if isinstance(pose, BlockFrame) else np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise OutOfRangeError(
            f"{name} must be a BlockFrame or a finite 4x4 transform, got shape {pose.shape}"
        )
    return pose


def _plane(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (total) plane through points given as columns (3, N): unit normal and centroid."""
    centroid = cols.mean(axis=1)
    centred = cols - centroid[:, None]
    _, vecs = np.linalg.eigh(centred @ centred.T)
    return vecs[:, 0], centroid


def _threshold(abs_residual: np.ndarray, params: FitParams) -> float:
    """Inlier threshold from the median absolute residual about the fitted plane (robust sigma)."""
    sigma = 1.4826 * np.median(abs_residual)
    return max(params.inlier_sigmas * sigma, params.min_threshold_m)


def _seed_o3d(rng: np.random.Generator | None) -> None:
    o3d.utility.random.seed(0 if rng is None else int(rng.integers(0, 2**31 - 1)))


def _remove_outliers(cols: np.ndarray, params: FitParams) -> np.ndarray:
    """(N,) mask of the points (columns of (3, N)) that pass open3d's statistical outlier removal.

    With ``sor_voxel_m > 0`` the filter runs on voxel centroids (a point goes with its voxel): an
    isolated stray point keeps its own, isolated voxel, and the cost drops about fivefold.
    Outliers closer to a face than a voxel are left to the plane fit's inlier threshold.
    """
    if params.sor_neighbors == 0:
        return np.ones(cols.shape[1], dtype=bool)
    if params.sor_voxel_m > 0:
        cell = np.floor((cols - cols.min(axis=1, keepdims=True)) / params.sor_voxel_m).astype(np.int64)
        _, inverse = np.unique((cell[0] << 42) | (cell[1] << 21) | cell[2], return_inverse=True)
        inverse = inverse.ravel()
        count = np.bincount(inverse)
        centres = np.stack([np.bincount(inverse, c) for c in cols], axis=1) / count[:, None]
    else:
        inverse, centres = np.arange(cols.shape[1]), np.ascontiguousarray(cols.T)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centres))
    _, kept = cloud.remove_statistical_outlier(params.sor_neighbors, params.sor_std_ratio)
    mask = np.zeros(len(centres), dtype=bool)
    mask[np.asarray(kept)] = True
    return mask[inverse]


def _fit_face(cols: np.ndarray, label: str, params: FitParams) -> tuple[np.ndarray, float, float]:
    """RANSAC (open3d) then least-squares refinement of one face (3, N): normal, offset, threshold."""
    if cols.shape[1] < params.min_face_points:
        raise ScanError(
            f"fewer than three block faces found: face {label} has {cols.shape[1]} points near its nominal "
            f"plane (need min_face_points = {params.min_face_points}); the face is hidden, seen edge-on, or "
            "the nominal pose is off by more than crop_margin_m"
        )
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(cols.T)))
    model, _ = cloud.segment_plane(params.ransac_threshold_m, 3, params.ransac_iterations)
    normal, offset = np.asarray(model[:3]), -float(model[3])
    # Refine to a fixed point of "inliers = points within the MAD threshold of their own LS plane",
    # so that the result does not depend on which of the (equally good) RANSAC planes was drawn:
    # open3d draws RANSAC samples in parallel threads, not repeatably on a busy machine.
    inliers = np.abs(normal @ cols - offset) < params.ransac_threshold_m
    for _ in range(params.refine_iterations):
        normal, centroid = _plane(cols[:, inliers])
        offset = float(normal @ centroid)
        residual = np.abs(normal @ cols - offset)
        threshold = _threshold(residual[inliers], params)
        new = residual < threshold
        if np.array_equal(new, inliers):
            break
        inliers = new
    return normal, offset, threshold


def fit_block_frame(
    points, nominal, params: FitParams | None = None, rng: np.random.Generator | None = None
) -> BlockFrame:
    """Fit the block frame B to a point cloud of the block and its surroundings.

    Parameters
    ----------
    points : (N, 3) array
        The cloud [m] in the scanner frame (or any frame; the result is in the same frame).
    nominal : (4, 4) array or BlockFrame
        Approximate pose of B in that frame, good to ``crop_margin_m`` and ``angle_tolerance_deg``:
        it crops the clutter and names the faces.
    params : FitParams, optional
    rng : numpy.random.Generator, optional
        Seeds open3d's RANSAC (None: seed 0). Same seed, same frame.

    Raises
    ------
    ScanError
        Fewer than three faces, a face cut off (block partly out of view), or faces not perpendicular.
    """
    params = params or FitParams()
    pts = _as_points(points)
    nom = _as_pose(nominal, "nominal")
    e, m = params.edge_m, params.crop_margin_m
    # Columns (3, N) for fast row-wise numpy. The nominal block frame (q) only selects and names
    # points; the planes are fitted to the points as given (p), so that the frame does not depend
    # on the nominal pose's rounding.
    p = np.ascontiguousarray(pts.T)
    rot_n = nom[:3, :3]
    q = rot_n.T @ (p - nom[:3, 3:4])
    in_box = np.ones(q.shape[1], dtype=bool)
    for row in q:
        in_box &= (row >= -e - m) & (row <= m)
    n_box = int(in_box.sum())
    if n_box < 3 * params.min_face_points:
        raise ScanError(
            f"block not found: only {n_box} of {len(pts)} points lie within crop_margin_m = {m * 1e3:g} mm "
            f"of the nominal block (need {3 * params.min_face_points}); the block is out of view or the "
            "nominal pose is wrong"
        )
    keep = _remove_outliers(q[:, in_box], params)
    sel = np.flatnonzero(in_box)[keep]
    p, q = p[:, sel], q[:, sel]
    _seed_o3d(rng)
    dist = np.abs(q)
    nearest = np.where(
        dist[0] < dist[1], np.where(dist[0] < dist[2], 0, 2), np.where(dist[1] < dist[2], 1, 2)
    )
    nearest[np.minimum(np.minimum(dist[0], dist[1]), dist[2]) >= m] = 3
    seeds = [_fit_face(p[:, nearest == k], FACES[k], params) for k in range(3)]
    normals = np.array([s[0] for s in seeds])
    offsets = np.array([s[1] for s in seeds])
    within = np.abs(normals @ p - offsets[:, None]) < np.array([s[2] for s in seeds])[:, None]
    owner = np.where(within[0], 0, np.where(within[1], 1, np.where(within[2], 2, 3)))
    owner[within.sum(axis=0) > 1] = 3  # on two planes: an edge point, left out
    counts, rms = np.zeros(3, dtype=int), np.zeros(3)
    for k in range(3):
        face = p[:, owner == k]
        if face.shape[1] < params.min_face_points:
            raise ScanError(
                f"face {FACES[k]} keeps only {face.shape[1]} points after segmentation (need "
                f"min_face_points = {params.min_face_points})"
            )
        normal, centroid = _plane(face)
        normal = normal if normal @ rot_n[:, k] > 0 else -normal
        angle = np.degrees(np.arccos(np.clip(normal @ rot_n[:, k], -1, 1)))
        if angle > params.angle_tolerance_deg:
            raise ScanError(
                f"face {FACES[k]}: fitted normal is {angle:.1f} deg from the nominal axis (> "
                f"angle_tolerance_deg = {params.angle_tolerance_deg:g})"
            )
        extent = min(np.ptp(q[j, owner == k]) for j in range(3) if j != k)
        if extent < params.min_extent_fraction * e:
            raise ScanError(
                f"face {FACES[k]} spans only {extent * 1e3:.1f} mm of the {e * 1e3:g} mm block edge "
                f"(min_extent_fraction = {params.min_extent_fraction:g}): the block is partly outside the "
                "measuring volume or occluded"
            )
        normals[k], offsets[k] = normal, normal @ centroid
        counts[k], rms[k] = face.shape[1], np.sqrt(np.mean((normal @ face - offsets[k]) ** 2))
    cosines = np.abs([normals[0] @ normals[1], normals[0] @ normals[2], normals[1] @ normals[2]])
    skew = float(np.arcsin(min(cosines.max(), 1.0)))
    if np.degrees(skew) > params.max_skew_deg:
        raise ScanError(
            f"the three fitted faces are not mutually perpendicular: off by {np.degrees(skew):.2f} deg "
            f"(> max_skew_deg = {params.max_skew_deg:g}); segmentation picked clutter"
        )
    u, _, vt = np.linalg.svd(normals.T)
    pose = np.eye(4)
    pose[:3, :3] = u @ vt  # nearest rotation to [n_x n_y n_z]; det > 0 since all are near the nominal
    pose[:3, 3] = np.linalg.solve(normals, offsets)  # the corner where the three planes meet
    removed = int(len(keep) - keep.sum())
    return BlockFrame(pose, normals, offsets, counts, rms, skew, len(pts), n_box, removed)


# ---------------------------------------------------------------------- displacement
def displacement_in_scanner(frame0, frame1) -> np.ndarray:
    """(6,) block displacement [o1 - o0 (m), rotvec(R1 R0^T) (rad)] in the scanner frame."""
    return displacement(_as_pose(frame0, "frame0"), _as_pose(frame1, "frame1"))


def block_displacement(frame0, frame1, scanner_pose) -> np.ndarray:
    """(6,) block displacement in the robot base frame: translation of B's origin [m], rotation vector [rad].

    ``scanner_pose`` (4, 4) is the scanner's pose in the base frame (scanner-to-robot calibration).
    """
    s = _as_pose(scanner_pose, "scanner_pose")
    return displacement(s @ _as_pose(frame0, "frame0"), s @ _as_pose(frame1, "frame1"))


def paper_displacement(frame0, frame1) -> np.ndarray:
    """(6,) the paper's form [dx, dy, dz (m), gamma, beta, alpha (rad)] of T = O1 O0^-1 (scanner frame).

    R = Rz(alpha) Ry(beta) Rx(gamma) (X-Y-Z fixed angles; the extracted paper text lost the minus
    sign of beta = atan2(-r31, sqrt(r11^2 + r21^2))). The translation is o1 - R o0: the motion of
    the scanner frame's origin, not of the block. For comparison only.
    """
    t = _as_pose(frame1, "frame1") @ invert(_as_pose(frame0, "frame0"))
    r = t[:3, :3]
    beta = np.arctan2(-r[2, 0], np.hypot(r[0, 0], r[1, 0]))
    cb = np.cos(beta)
    alpha = np.arctan2(r[1, 0] / cb, r[0, 0] / cb)
    gamma = np.arctan2(r[2, 1] / cb, r[2, 2] / cb)
    return np.concatenate([t[:3, 3], [gamma, beta, alpha]])
