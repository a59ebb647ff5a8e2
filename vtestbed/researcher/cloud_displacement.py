"""The block displacement from two fitted frames (the last step of :mod:`.cloud`, re-exported there).

The identification uses the translation of the block's reference point (B's origin) and the
rotation vector of ``R1 R0^T``; the paper's ``T = O1 O0^-1`` with its Euler angles is given for
comparison only: its translation ``o1 - R o0`` is the motion of the scanner's origin, not of the
block (docs/architecture.md).
"""

from __future__ import annotations

import numpy as np

from ..errors import OutOfRangeError
from ..transforms import displacement, invert


def _as_pose(pose, name: str) -> np.ndarray:
    pose = getattr(pose, "pose", pose)  # a cloud.BlockFrame or a (4, 4) transform
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise OutOfRangeError(
            f"{name} must be a BlockFrame or a finite 4x4 transform, got shape {pose.shape}"
        )
    return pose


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
