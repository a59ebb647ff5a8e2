"""Point-cloud files (PLY) as a dataset stores them: (N, 3) points in the scanner frame.

The world writes the scans with :func:`write_ply`; the researcher reads them with
:func:`read_ply`, which also takes a lab's files in millimetres. open3d does the file format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._open3d import o3d
from .errors import DatasetError, OutOfRangeError

_UNITS = {"m": 1.0, "mm": 1e-3}


def _as_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise OutOfRangeError(f"points must be a finite (N, 3) array [m], got shape {pts.shape}")
    return pts


def _unit(length_unit: str) -> float:
    if length_unit not in _UNITS:
        raise OutOfRangeError(f"length_unit = {length_unit!r} is not one of {', '.join(_UNITS)}")
    return _UNITS[length_unit]


def write_ply(path, points, length_unit: str = "m", binary: bool = True) -> Path:
    """Write (N, 3) points [m] as a PLY file in ``length_unit`` ('m' or 'mm').

    The binary default stores doubles exactly; ``binary=False`` goes through open3d's ASCII
    writer, which keeps 6 significant digits (about 1 um at 0.6 m): for reading by eye only.
    """
    scale = _unit(length_unit)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_as_points(points) / scale))
    path = Path(path)
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=not binary):
        raise DatasetError(f"could not write the point cloud file {path}")
    return path


def read_ply(path, length_unit: str = "m") -> np.ndarray:
    """(N, 3) points [m] of a PLY file whose coordinates are in ``length_unit`` ('m' or 'mm')."""
    scale = _unit(length_unit)
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"point cloud file not found: {path}")
    cloud = o3d.io.read_point_cloud(str(path), format="ply")
    points = np.asarray(cloud.points) * scale
    if len(points) == 0:
        raise DatasetError(f"point cloud file {path} holds no points (not a PLY point cloud?)")
    return points
