"""Helpers shared by the scan-mean tests: synthetic frames and an independent frame average."""

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from vtestbed.transforms import homogeneous, matrix_from_rotation_vector


@dataclasses.dataclass(frozen=True)
class Reduced:  # the fields of a TestMeasurement that against_scan_mean reads and replaces
    test_id: str
    frame_unloaded: np.ndarray
    frame_loaded: np.ndarray
    displacement: np.ndarray


def perturbed(pose: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """(4, 4) ``pose`` moved by the twist ``xi`` (translation [m], rotation vector [rad]) in its axes."""
    return pose @ homogeneous(matrix_from_rotation_vector(xi[3:]), xi[:3])


def scipy_mean_frame(frames) -> np.ndarray:
    """(4, 4): translations averaged, rotations by scipy's quaternion (chordal) mean: an
    independent average, equal to the researcher's to second order in the microradian scatter."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(np.array([f[:3, :3] for f in frames])).mean().as_matrix()
    out[:3, 3] = np.mean([f[:3, 3] for f in frames], axis=0)
    return out
