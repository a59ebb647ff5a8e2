"""The RANSAC fallback of the block-frame fit (:mod:`vtestbed.researcher.cloud`), on open3d.

The fast path of :func:`~vtestbed.researcher.cloud.fit_block_frame` seeds each face from the
nominal pose and fits it by SVD, numpy only. When one of its checks fails (too few points on a
face, a large plane residual, a nominal pose far off), the fit falls back to the pieces here:

- :func:`ransac_seeds`: open3d statistical outlier removal, then each point seeded to the nearest
  nominal face (the seeds may hold clutter: RANSAC rejects it);
- :func:`ransac_plane`: an open3d RANSAC (``segment_plane``) plane as the start of a face's
  least-squares refinement;
- :func:`coarse_pose`: when the nominal pose is too far off even to seed the faces, a sequential
  RANSAC search near the nominal corner for the three faces.

open3d (0.5 s and more to import) is imported on the first call that needs it, never at import
time: a worker whose fits all pass the fast path never loads it.

Units and frames: points are columns of (3, N) arrays in m; ``q`` is the cloud in the nominal
block frame B, ``p`` in the cloud's own frame (the scanner frame for a scan); poses are (4, 4)
transforms of B in the cloud's frame.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .block_frame import FitParams


def _open3d():
    """open3d, imported on the RANSAC path only: a worker that never falls back never loads it."""
    from .._open3d import o3d

    return o3d


def remove_outliers(cols: np.ndarray, params: FitParams) -> np.ndarray:
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
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centres))
    _, kept = cloud.remove_statistical_outlier(params.sor_neighbors, params.sor_std_ratio)
    mask = np.zeros(len(centres), dtype=bool)
    mask[np.asarray(kept)] = True
    return mask[inverse]


def ransac_seeds(
    q: np.ndarray, in_box: np.ndarray, params: FitParams, rng: np.random.Generator | None
) -> tuple[np.ndarray, list[np.ndarray], int]:
    """Seeds of the three faces on the RANSAC path, from the cloud ``q`` (3, N) in the nominal frame.

    The points of ``in_box`` (the crop box, (N,) mask) that fail the statistical outlier removal
    leave it; each remaining point within ``crop_margin_m`` of a nominal face seeds the nearest one.
    Also seeds open3d's RANSAC from ``rng`` (None: seed 0).

    Returns the new crop mask (``in_box`` is not modified), the (N,) seed masks of the faces +x,
    +y, +z, and the number of points removed as outliers.
    """
    in_box = in_box.copy()
    sel = np.flatnonzero(in_box)
    keep = remove_outliers(q[:, sel], params)
    in_box[sel[~keep]], removed = False, int(len(keep) - keep.sum())
    _open3d().utility.random.seed(0 if rng is None else int(rng.integers(0, 2**31 - 1)))
    dist = np.abs(q)
    # elementwise: argmin over the short axis of (3, N) walks the memory with a stride
    nearest = np.where(
        dist[0] < dist[1], np.where(dist[0] < dist[2], 0, 2), np.where(dist[1] < dist[2], 1, 2)
    )
    nearest[~in_box | (np.minimum(np.minimum(dist[0], dist[1]), dist[2]) >= params.crop_margin_m)] = 3
    return in_box, [nearest == k for k in range(3)], removed


def ransac_plane(cols: np.ndarray, params: FitParams) -> tuple[np.ndarray, float, np.ndarray]:
    """open3d RANSAC plane of one face's seeds (3, M): unit normal, offset [m] and (M,) inlier mask.

    The start of the face's least-squares refinement (``normal @ x = offset`` on the plane).
    """
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(cols.T)))
    model, _ = cloud.segment_plane(params.ransac_threshold_m, 3, params.ransac_iterations)
    normal, offset = np.asarray(model[:3]), -float(model[3])
    return normal, offset, np.abs(normal @ cols - offset) < params.ransac_threshold_m


def coarse_pose(p: np.ndarray, nom: np.ndarray, params: FitParams) -> np.ndarray | None:
    """Pose (4, 4) of B from the three largest mutually perpendicular planes near the nominal corner.

    For a nominal pose too far off to seed the faces: open3d RANSAC takes planes one after the
    other out of 2 mm voxel centroids within a sphere around the nominal corner that holds the
    whole block in any orientation. The faces are the largest mutually perpendicular triple (5 deg)
    meeting within an edge of the nominal corner, named after the nominal axes (each within 60 deg).
    None if there is no such triple.
    """
    from .cloud import fit_plane  # here, not at the top: cloud imports this module

    o3d = _open3d()
    o3d.utility.random.seed(0)  # open3d's generator is global: the search must not depend on call order
    e, voxel = params.edge_m, max(params.sor_voxel_m, params.edge_m / 40)
    near = np.sum((p - nom[:3, 3:4]) ** 2, axis=0) < (np.sqrt(3) * e + params.crop_margin_m) ** 2
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(p[:, near].T)))
    cloud = cloud.voxel_down_sample(voxel)
    fewest = int(0.1 * (e / voxel) ** 2)  # a tenth of a face's voxels
    planes = []  # (normal, offset, centroid, count)
    for _ in range(8):
        if len(cloud.points) < fewest:
            break
        _, idx = cloud.segment_plane(voxel / 2, 3, 1000)
        if len(idx) < fewest:
            break
        normal, centroid = fit_plane(np.asarray(cloud.points)[idx].T)
        planes.append((normal, normal @ centroid, centroid, len(idx)))
        cloud = cloud.select_by_index(idx, invert=True)
    best, best_count = None, 0
    for trio in itertools.combinations(planes, 3):
        normals = np.array([t[0] for t in trio])
        offsets = np.array([t[1] for t in trio])
        count = sum(t[3] for t in trio)
        if np.abs(normals @ normals.T - np.eye(3)).max() > np.sin(np.radians(5)) or count <= best_count:
            continue
        corner = np.linalg.solve(normals, offsets)
        if np.linalg.norm(corner - nom[:3, 3]) > e:
            continue
        for k in range(3):  # outward: the other two faces lie behind each face
            behind = np.mean([trio[j][2] for j in range(3) if j != k], axis=0)
            if normals[k] @ behind > offsets[k]:
                normals[k], offsets[k] = -normals[k], -offsets[k]
        best, best_count = (normals, offsets, corner), count
    if best is None:
        return None
    normals, offsets, corner = best
    orders = [list(o) for o in itertools.permutations(range(3)) if np.linalg.det(normals[list(o)]) > 0]
    order = max(orders, key=lambda o: np.trace(nom[:3, :3].T @ normals[o].T))
    if np.min(np.einsum("ij,ji->i", normals[order], nom[:3, :3])) < 0.5:
        return None
    u, _, vt = np.linalg.svd(normals[order].T)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = u @ vt, corner
    return pose
