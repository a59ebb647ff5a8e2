"""Small rigid-transform helpers (4x4 homogeneous matrices, rotation vectors), SI units."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# The six components of a displacement twist [v; w] (m, m, m, rad, rad, rad), and of its rows.
DISPLACEMENT_COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")


def rot_x(angle: float) -> np.ndarray:
    """Rotation about x by ``angle`` [rad], shape (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation about z by ``angle`` [rad], shape (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rotation: np.ndarray, translation) -> np.ndarray:
    """4x4 transform from a (3, 3) rotation and a (3,) translation [m]."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def invert(transform: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    rot, pos = transform[:3, :3], transform[:3, 3]
    return homogeneous(rot.T, -rot.T @ pos)


def modified_dh(alpha_prev: float, a_prev: float, theta: float, d: float) -> np.ndarray:
    """Craig's modified DH link transform Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i).

    Angles in rad, lengths in m; returns the (4, 4) pose of frame i in frame i-1.
    """
    ca, sa, ct, st = np.cos(alpha_prev), np.sin(alpha_prev), np.cos(theta), np.sin(theta)
    return np.array(
        [
            [ct, -st, 0.0, a_prev],
            [st * ca, ct * ca, -sa, -sa * d],
            [st * sa, ct * sa, ca, ca * d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) [rad] of a (3, 3) rotation matrix."""
    return Rotation.from_matrix(rotation).as_rotvec()


def matrix_from_rotation_vector(rotvec) -> np.ndarray:
    """(3, 3) rotation matrix of a rotation vector [rad]."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix()


def quat_wxyz(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a (3, 3) rotation matrix, as MuJoCo stores it."""
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return np.array([w, x, y, z])


def displacement(pose_before: np.ndarray, pose_after: np.ndarray) -> np.ndarray:
    """6-D small displacement of a frame between two poses, both expressed in one fixed frame.

    Returns ``[p1 - p0, rotvec(R1 R0^T)]`` (m, rad), in the fixed frame: the motion of the
    frame's own origin, not of the fixed frame's origin (the O1 O0^-1 pitfall, docs/architecture.md).
    """
    trans = pose_after[:3, 3] - pose_before[:3, 3]
    rot = rotation_vector(pose_after[:3, :3] @ pose_before[:3, :3].T)
    return np.concatenate([trans, rot])


def displacement_in_block_frame(frame_unloaded: np.ndarray, frame_loaded: np.ndarray) -> np.ndarray:
    """Small displacement of a body frame, in the unloaded frame's own axes (6,) [m, rad].

    ``[R0^T (o1 - o0), rotvec(R0^T R1)]`` from two (4, 4) poses given in any one fixed frame (the
    scanner's, or the world's): the result does not depend on which, so it needs no
    scanner-to-robot calibration.
    """
    rot0 = frame_unloaded[:3, :3]
    trans = rot0.T @ (frame_loaded[:3, 3] - frame_unloaded[:3, 3])
    return np.concatenate([trans, rotation_vector(rot0.T @ frame_loaded[:3, :3])])
