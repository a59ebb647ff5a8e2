"""Point cloud -> three block faces -> block frame -> 6-D block displacement.

The chain follows the paper (Sec. 4.2) and runs unchanged on a lab scan read from PLY:

1. crop the cloud to a box around the block's nominal pose (known in the lab from the robot's
   kinematics and the scanner-to-robot calibration; for the loaded scan, the unloaded frame);
2. segmentation into the three mutually perpendicular faces, by one of two paths:

   - **fast** (the default, numpy only): each point is seeded to the nearest nominal face, each
     face is fitted by total least squares (SVD) and refined to a fixed point of a robust residual
     gate (the scanner's outliers and the clutter fall outside it);
   - **ransac** (the fallback, open3d, in :mod:`.cloud_ransac`): statistical outlier removal,
     RANSAC (``segment_plane``) per seeded face, then the same refinement. It runs when a check
     of the fast path fails (too few points on a face, a large plane residual, a nominal pose far
     off); if the nominal pose is too far off even to seed the faces, a sequential RANSAC search
     near the nominal corner finds the three faces first;

   then one reassignment pass gives each point to the one fitted plane it lies on (points on two
   planes are dropped) and each face is refitted (SVD);
3. block frame: axes = the polar decomposition (nearest rotation) of the three fitted normals,
   origin = the intersection of the three fitted planes (the paper's O_i);
4. displacement of the block's reference point (B's origin) and rotation vector, in the scanner
   frame and, rotated with the scanner's calibrated pose, in the robot base frame. The paper's
   ``T = O1 O0^-1`` with its Euler angles is reported for comparison only: its translation
   ``o1 - R o0`` is the motion of the scanner's origin, not of the block (docs/architecture.md).

``BlockFrame.method`` tells which path gave the frame and ``fallback_reason`` why the fast one
was left.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import OutOfRangeError, ScanError
from ..transforms import rotation_vector
from .block_frame import CHAMFER_EDGE_BAND_M, FIT_METHODS, BlockFrame, FitParams
from .cloud_displacement import block_displacement, displacement_in_scanner, paper_displacement
from .cloud_ransac import coarse_pose, ransac_plane, ransac_seeds

__all__ = ["CHAMFER_EDGE_BAND_M", "FIT_METHODS", "BlockFrame", "FitParams", "block_displacement", "displacement_in_scanner", "fit_block_frame",
           "fit_plane", "paper_displacement"]  # fmt: skip

FACES = ("+x", "+y", "+z")
# The face a point belongs to from the bit code (on +x) + 2 (on +y) + 4 (on +z): one plane or none (3).
_OWNER = np.array([3, 0, 1, 3, 2, 3, 3, 3], dtype=np.int8)


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


def fit_plane(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (total) plane through points given as columns (3, N): unit normal and centroid.

    One pass, no centred copy: scatter = X X^T - N c c^T. The points must lie within about 0.1 m of
    the origin (the caller shifts them) so that the cancellation costs < 1e-14 rad in the normal.
    """
    n = cols.shape[1]
    centroid = cols @ np.full(n, 1.0 / n)  # a BLAS matvec: 10x faster than mean(axis=1) here
    _, vecs = np.linalg.eigh(cols @ cols.T - n * np.outer(centroid, centroid))
    return vecs[:, 0], centroid


def _threshold(abs_residual: np.ndarray, params: FitParams) -> float:
    """Inlier threshold from the median absolute residual about the fitted plane (robust sigma)."""
    sigma = 1.4826 * np.median(abs_residual)
    return max(params.inlier_sigmas * sigma, params.min_threshold_m)


def _fit_face(
    cols: np.ndarray, n_seeds: int, label: str, params: FitParams, ransac: bool
) -> tuple[np.ndarray, float, float]:
    """Plane of one face from its seeds (3, M): unit normal, offset [m] and inlier threshold [m].

    The start is the SVD plane of all seeds (fast path) or an open3d RANSAC plane; from there each
    refit keeps the points within the robust threshold of the previous plane. The RANSAC path
    iterates to the fixed point, so its frame does not depend on which of the (equally good)
    RANSAC planes was drawn (open3d draws samples in threads, not repeatably on a busy machine);
    the fast path stops after ``fast_refits`` fits: the plane only sets the reassignment's gate.
    """
    if n_seeds < params.min_face_points:
        raise ScanError(
            f"fewer than three block faces found: face {label} has {n_seeds} points near its nominal "
            f"plane (need min_face_points = {params.min_face_points}); the face is hidden, seen edge-on, or "
            "the nominal pose is off by more than crop_margin_m"
        )
    if ransac:
        normal, offset, inliers = ransac_plane(cols, params)
    else:
        inliers = np.ones(cols.shape[1], dtype=bool)
    for _ in range(params.refine_iterations if ransac else params.fast_refits):
        normal, centroid = fit_plane(np.compress(inliers, cols, axis=1))
        offset = float(normal @ centroid)
        residual = np.abs(normal @ cols - offset)
        threshold = _threshold(residual[inliers], params)
        new = residual < threshold
        if np.array_equal(new, inliers):
            break
        inliers = new
    if not ransac and threshold > params.inlier_sigmas * params.fast_max_sigma_m:
        raise ScanError(
            f"face {label}: robust plane residual {threshold / params.inlier_sigmas * 1e6:.1f} um "
            f"> fast_max_sigma_m = {params.fast_max_sigma_m * 1e6:g} um (clutter among the seeds?)"
        )
    return normal, offset, threshold


def _frame(normals: np.ndarray, offsets: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(4, 4) block frame from the fitted planes (offsets about ``origin`` (3, 1)), in the cloud's frame."""
    u, _, vt = np.linalg.svd(normals.T)
    pose = np.eye(4)
    pose[:3, :3] = u @ vt  # nearest rotation to [n_x n_y n_z]; det > 0 since all are near the nominal
    pose[:3, 3] = np.linalg.solve(normals, offsets) + origin[:, 0]  # where the three planes meet
    return pose


BEYOND_EDGE_FRACTION = 0.01  # of a face's points beyond the declared edge: the block is larger


def _check_edge_fits(p: np.ndarray, owner: np.ndarray, pose: np.ndarray, e: float, m: float) -> None:
    """Each face must end where the declared edge ``e`` says: the block occupies [-e, 0] along B's
    axes from the fitted corner. A face whose points reach on, more than a quarter of the crop
    margin ``m`` past -e, belongs to a larger block (``block_edge_m`` too small): the crop then keeps
    only part of each face, and the frame, fitted to it, scatters more than the dataset's noise
    floor and plausibility checks assume (on a 10-test dataset with half the edge declared, joint
    errors moved by 3-5 percentage points without a word). Every 4th point, in the fitted frame."""
    sub = p[:, ::4]
    local = pose[:3, :3].T @ (sub - pose[:3, 3][:, None])
    tol = 0.25 * m
    for k in range(3):
        mine = owner[::4] == k
        if not np.any(mine):
            continue
        for j in (j for j in range(3) if j != k):
            beyond = float(np.mean(local[j, mine] < -e - tol))
            if beyond > BEYOND_EDGE_FRACTION:
                raise ScanError(
                    f"face {FACES[k]} goes on past the block edge: {beyond:.0%} of its points lie more than "
                    f"{tol * 1e3:.1f} mm beyond the {e * 1e3:g} mm edge along the block's {'xyz'[j]} axis; "
                    "the block is larger than block_edge_m says (setup.json; the scenario's lab.block_edge_m)"
                )


def _fit(p: np.ndarray, nom: np.ndarray, params: FitParams, ransac: bool, rng) -> BlockFrame:
    """One path of :func:`fit_block_frame` on the points as columns (3, N) [m]."""
    e, m, n_input = params.edge_m, params.crop_margin_m, p.shape[1]
    # The nominal block frame (q) only selects and names points; the planes are fitted to the
    # points as given (p), so that the frame does not depend on the nominal pose's rounding.
    rot_n = nom[:3, :3]
    q = rot_n.T @ p
    q -= (rot_n.T @ nom[:3, 3])[:, None]  # in place: numpy's broadcast temporaries cost 10x here
    in_box = (q[0] >= -e - m) & (q[0] <= m) & (q[1] >= -e - m) & (q[1] <= m) & (q[2] >= -e - m)
    in_box &= q[2] <= m
    n_box, removed = int(np.count_nonzero(in_box)), 0
    if n_box < 3 * params.min_face_points:
        raise ScanError(
            f"block not found: only {n_box} of {n_input} points lie within crop_margin_m = {m * 1e3:g} "
            f"mm of the nominal block (need {3 * params.min_face_points}); the block is out of view or the "
            "nominal pose is wrong (the pose's angles and their convention, the scanner's pose)"
        )
    if ransac:
        in_box, seed_masks, removed = ransac_seeds(q, in_box, params, rng)
    else:
        # Seeds away from the face's edges by as much as the nominal pose may be off, so that no
        # point of a neighbouring face is among them; RANSAC is not needed to reject them.
        inset = params.fast_max_offset_m + e * np.sin(np.radians(params.fast_max_angle_deg))
        inner = [(row > -e + inset) & (row < -inset) for row in q]
        seed_masks = [(np.abs(q[k]) < m) & inner[k - 1] & inner[k - 2] for k in range(3)]
    # Planes are fitted to points shifted to a point of the cloud (not of the nominal pose: see
    # above), which keeps the one-pass scatter of fit_plane exact to 1e-14. np.take and np.compress,
    # not p[:, idx]: five times faster on (3, N).
    origin = p[:, np.argmax(in_box)].copy()[:, None]
    stride = 1 if ransac else params.fast_seed_stride
    seeds = []
    for k in range(3):
        idx = np.flatnonzero(seed_masks[k])
        cols = np.take(p, idx[::stride], axis=1)
        cols -= origin
        seeds.append(_fit_face(cols, len(idx), FACES[k], params, ransac))
    normals = np.array([s[0] for s in seeds])
    offsets = np.array([s[1] for s in seeds]) + normals @ origin[:, 0]  # in the cloud's frame
    # One reassignment pass: each point goes to the one plane it lies on; edge points (on two
    # planes) are left out, and so are outliers and clutter (on none).
    residual = normals @ p
    residual -= offsets[:, None]
    within = np.abs(residual, out=residual) < np.array([s[2] for s in seeds])[:, None]
    code = within[0].view(np.uint8) + 2 * within[1].view(np.uint8) + 4 * within[2].view(np.uint8)
    owner = _OWNER[code]
    owner[~in_box] = 3
    counts, rms = np.zeros(3, dtype=int), np.zeros(3)
    for k in range(3):
        mine = owner == k
        face = np.compress(mine, p, axis=1)
        face -= origin
        if face.shape[1] < params.min_face_points:
            raise ScanError(
                f"face {FACES[k]} keeps only {face.shape[1]} points after segmentation (need "
                f"min_face_points = {params.min_face_points})"
            )
        normal, centroid = fit_plane(face)
        normal = normal if normal @ rot_n[:, k] > 0 else -normal
        angle = np.degrees(np.arccos(np.clip(normal @ rot_n[:, k], -1, 1)))
        if angle > params.angle_tolerance_deg:
            raise ScanError(
                f"face {FACES[k]}: fitted normal is {angle:.1f} deg from the nominal axis (> "
                f"angle_tolerance_deg = {params.angle_tolerance_deg:g})"
            )
        # the extent from every 4th point: within 2 mm, against a limit of half the edge
        extent = min(np.ptp(q[j, ::4][mine[::4]]) for j in range(3) if j != k)
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
    pose = _frame(normals, offsets, origin)
    if params.edge_band_m > 0:  # chamfers: drop each face's boundary band, in the fitted frame
        for k in range(3):
            face = np.compress(owner == k, p, axis=1)
            face -= origin
            local = pose[:3, :3].T @ (face - (pose[:3, 3] - origin[:, 0])[:, None])
            keep = np.ones(face.shape[1], dtype=bool)
            for j in (j for j in range(3) if j != k):
                lo, hi = local[j].min(), local[j].max()
                keep &= (local[j] > lo + params.edge_band_m) & (local[j] < hi - params.edge_band_m)
            face = np.compress(keep, face, axis=1)
            if face.shape[1] < params.min_face_points:
                raise ScanError(f"face {FACES[k]} keeps only {face.shape[1]} points inside edge_band_m = "
                                f"{params.edge_band_m * 1e3:g} mm of its boundary (need {params.min_face_points})")  # fmt: skip
            normal, centroid = fit_plane(face)
            normals[k] = normal if normal @ normals[k] > 0 else -normal
            offsets[k] = normals[k] @ centroid
            counts[k], rms[k] = face.shape[1], np.sqrt(np.mean((normals[k] @ face - offsets[k]) ** 2))
        pose = _frame(normals, offsets, origin)
    _check_edge_fits(p, owner, pose, e, m)
    offsets += normals @ origin[:, 0]  # back to the cloud's frame
    if not ransac:
        # Seeds from a nominal pose far off may have named or mixed the faces wrongly.
        angle = np.degrees(np.linalg.norm(rotation_vector(rot_n.T @ pose[:3, :3])))
        offset = np.linalg.norm(pose[:3, 3] - nom[:3, 3])
        if angle > params.fast_max_angle_deg or offset > params.fast_max_offset_m:
            raise ScanError(
                f"the nominal pose is {angle:.2f} deg and {offset * 1e3:.2f} mm from the fitted frame (> "
                f"fast_max_angle_deg = {params.fast_max_angle_deg:g} or fast_max_offset_m = "
                f"{params.fast_max_offset_m * 1e3:g} mm)"
            )
    method = "ransac" if ransac else "fast"
    return BlockFrame(pose, normals, offsets, counts, rms, skew, n_input, n_box, removed, method)


def fit_block_frame(
    points, nominal, params: FitParams | None = None, rng: np.random.Generator | None = None
) -> BlockFrame:
    """Fit the block frame B to a point cloud of the block and its surroundings.

    Parameters
    ----------
    points : (N, 3) array
        The cloud [m] in the scanner frame (or any frame; the result is in the same frame).
    nominal : (4, 4) array or BlockFrame
        Approximate pose of B in that frame: it crops the clutter and names the faces. The fast
        path needs it to ``fast_max_offset_m`` and ``fast_max_angle_deg``; the fallback to
        ``crop_margin_m`` and ``angle_tolerance_deg``, or, with the RANSAC search for the faces,
        its corner to half an edge and its axes to about 45 deg.
    params : FitParams, optional
        ``params.method`` chooses the path ("auto": fast, RANSAC when a check fails).
    rng : numpy.random.Generator, optional
        Seeds open3d's RANSAC on the fallback path (None: seed 0); the fast path draws nothing.
        Same seed, same frame.

    Returns
    -------
    BlockFrame
        ``method`` says which path gave it, ``fallback_reason`` why the fast path was left.

    Raises
    ------
    ScanError
        Fewer than three faces, a face cut off (block partly out of view), or faces not perpendicular.
    """
    params = params or FitParams()
    p = np.ascontiguousarray(_as_points(points).T)  # columns (3, N): fast row-wise numpy
    nom = _as_pose(nominal, "nominal")
    reason = ""
    if params.method != "ransac":
        try:
            return _fit(p, nom, params, False, None)
        except ScanError as exc:
            if params.method == "fast":
                raise
            reason = str(exc)
    try:
        frame = _fit(p, nom, params, True, rng)
    except ScanError as exc:
        coarse = None if params.method == "ransac" else coarse_pose(p, nom, params)
        if coarse is None:
            raise
        try:
            frame = _fit(p, coarse, params, True, rng)
        except ScanError:
            raise exc from None  # the error against the nominal pose the caller gave
        off = np.degrees(np.linalg.norm(rotation_vector(nom[:3, :3].T @ frame.pose[:3, :3])))
        reason += f"; the faces found by a RANSAC search, {off:.1f} deg from the nominal pose"
    return replace(frame, fallback_reason=reason)
