"""The values of the block-frame fit: its settings (:class:`FitParams`) and its result
(:class:`BlockFrame`), SI units, rows ordered as the faces +x, +y, +z of the block frame B
(the block occupies [-edge, 0]^3 in B). The fit itself is :func:`vtestbed.researcher.cloud.fit_block_frame`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, check_range

FIT_METHODS = ("auto", "fast", "ransac")
# FitParams.edge_band_m for targets with chamfered or rounded edges: wider than the gate (4.5 sigma,
# about 0.06 mm at 45 deg) over which chamfer points reach into it; measured in docs/targets.md.
CHAMFER_EDGE_BAND_M = 0.5e-3


@dataclass(frozen=True)
class FitParams:
    """Settings of :func:`fit_block_frame` (SI units).

    Attributes
    ----------
    edge_m : float
        Block edge [m]; the block occupies [-edge, 0]^3 in its frame B.
    crop_margin_m : float
        Margin [m] of the crop box around the nominal block; also how far the nominal pose may be off.
    method : {"auto", "fast", "ransac"}
        "auto": the fast path, the RANSAC path when a check fails; "fast": the fast path only (a
        failed check raises ScanError); "ransac": the RANSAC path only, with the nominal pose as given.
    sor_neighbors, sor_std_ratio, sor_voxel_m : int, float, float
        RANSAC path: open3d statistical outlier removal (0 neighbours disables it), on the centroids
        of voxels of this edge [m] (0: on every point).
    ransac_threshold_m, ransac_iterations : float, int
        RANSAC path: open3d ``segment_plane`` inlier distance [m] and iterations per face.
    inlier_sigmas, min_threshold_m, refine_iterations : float, float, int
        Least-squares refinement (both paths): inliers within ``max(inlier_sigmas * sigma,
        min_threshold_m)`` with the robust ``sigma = 1.4826 * median(|residual|)`` of their own plane,
        iterated (at most ``refine_iterations`` times) until the set is stable.
    fast_seed_stride, fast_refits : int
        Fast path: each face's plane before the reassignment is fitted to every
        ``fast_seed_stride``-th seed, ``fast_refits`` times (each refit keeps the points within the
        robust threshold of the previous plane); it only sets the gate of the reassignment.
    fast_max_sigma_m : float
        Fast path: largest robust residual sigma [m] of a face; above it the seeds held clutter.
    fast_max_angle_deg, fast_max_offset_m : float
        Fast path: largest rotation [deg] and corner offset [m] of the fitted frame from the
        nominal pose; a nominal pose further off may have seeded the faces wrongly.
    min_face_points : int
        Fewest points a face must keep.
    edge_band_m : float
        Targets whose faces end in chamfers or rounded edges (a mesh target's ``face_margin_m`` > 0
        in setup.json): each face's points within this distance [m] of the boundary of its flat
        region (as its points, in the fitted frame, show it) are dropped and the faces refitted, so
        that the chamfer points that lie within the gate do not tilt or shift the plane. 0 (the
        plain box): no band is dropped.
    min_extent_fraction : float
        Each face's points must span this fraction of the edge along both in-plane axes.
    angle_tolerance_deg, max_skew_deg : float
        Largest angle between a fitted normal and its nominal axis, and largest deviation of two
        fitted normals from perpendicular.
    """

    edge_m: float = 0.08
    crop_margin_m: float = 0.010
    method: str = "auto"
    sor_neighbors: int = 8
    sor_std_ratio: float = 3.0
    sor_voxel_m: float = 2e-3
    ransac_threshold_m: float = 0.1e-3
    ransac_iterations: int = 50
    inlier_sigmas: float = 4.5
    min_threshold_m: float = 1e-6
    refine_iterations: int = 10
    fast_seed_stride: int = 4
    fast_refits: int = 2
    fast_max_sigma_m: float = 0.1e-3
    fast_max_angle_deg: float = 3.0
    fast_max_offset_m: float = 8e-3
    min_face_points: int = 100
    edge_band_m: float = 0.0
    min_extent_fraction: float = 0.5
    angle_tolerance_deg: float = 10.0
    max_skew_deg: float = 1.0

    def __post_init__(self):
        check_range("edge_m", self.edge_m, 1e-3, 1.0, "m")
        check_range("crop_margin_m", self.crop_margin_m, 0.0, self.edge_m / 2, "m")
        if self.method not in FIT_METHODS:
            raise OutOfRangeError(f"method = {self.method!r} is not one of {', '.join(FIT_METHODS)}")
        check_range("sor_neighbors", self.sor_neighbors, 0, 100)
        check_range("sor_voxel_m", self.sor_voxel_m, 0.0, self.edge_m / 4, "m")
        check_range("ransac_threshold_m", self.ransac_threshold_m, 1e-9, 0.01, "m")
        check_range("ransac_iterations", self.ransac_iterations, 1, 100000)
        check_range("fast_seed_stride", self.fast_seed_stride, 1, 100)
        check_range("fast_refits", self.fast_refits, 1, 100)
        check_range("fast_max_sigma_m", self.fast_max_sigma_m, 1e-9, 0.01, "m")
        check_range("fast_max_angle_deg", self.fast_max_angle_deg, 0.0, 45.0, "deg")
        check_range("fast_max_offset_m", self.fast_max_offset_m, 0.0, self.edge_m, "m")
        check_range("min_face_points", self.min_face_points, 3, 1e9)
        check_range("edge_band_m", self.edge_band_m, 0.0, self.edge_m / 8, "m")
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
        Points given, inside the crop box, and removed by the statistical outlier filter (RANSAC path).
    method : {"fast", "ransac"}
        The path that gave the frame.
    fallback_reason : str
        Why the fast path was left ("" if it was not, or not tried).
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
    method: str = "fast"
    fallback_reason: str = ""
