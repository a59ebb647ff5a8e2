"""The wrist geometry the arm-wrist criterion rests on: vectorised DH frames, the wrist point.

For a spherical wrist (axes 4-6 meet) the wrist point is the origin of DH frame 5; for an offset
wrist (UR type) the least-squares point of axes 4-6. Robots the criterion is undefined for (not
6R, two wrist axes parallel at every pose) are refused with :class:`NotSphericalWristError`.

All angles are DH angles in rad; lengths in m; frames from the robot's base frame.
"""

from __future__ import annotations

import numpy as np

from ..errors import VtestbedError
from ..robots import RobotDescription


def dh_frames(robot: RobotDescription, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised modified-DH forward kinematics, from the robot's base frame.

    Parameters
    ----------
    q : (N, n) DH angles [rad]

    Returns
    -------
    rot : (N, n, 3, 3) orientation of DH frames 1..n in the base frame
    pos : (N, n, 3) their origins [m]

    Frame 0 is the description's ``dh0_in_base`` (identity for a robot written as DH from its base).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n_pose = q.shape[0]
    rot = np.empty((n_pose, robot.dof, 3, 3))
    pos = np.empty((n_pose, robot.dof, 3))
    base = robot.base_transform
    r_prev = np.broadcast_to(base[:3, :3], (n_pose, 3, 3))
    p_prev = np.broadcast_to(base[:3, 3], (n_pose, 3))
    local = np.zeros((n_pose, 3, 3))
    for i, joint in enumerate(robot.joints):
        ca, sa = np.cos(joint.alpha_prev), np.sin(joint.alpha_prev)
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        local[:, 0, 0], local[:, 0, 1] = ct, -st
        local[:, 1, 0], local[:, 1, 1], local[:, 1, 2] = st * ca, ct * ca, -sa
        local[:, 2, 0], local[:, 2, 1], local[:, 2, 2] = st * sa, ct * sa, ca
        offset = np.array([joint.a_prev, -sa * joint.d, ca * joint.d])
        p_prev = p_prev + r_prev @ offset
        r_prev = r_prev @ local
        rot[:, i], pos[:, i] = r_prev, p_prev
    return rot, pos


class NotSphericalWristError(VtestbedError, ValueError):
    """A robot the criterion is undefined for (not 6R, two wrist axes always parallel); historical name."""


def check_wrist(robot: RobotDescription, tol: float = 1e-12) -> bool:
    """Whether ``robot``'s wrist is spherical; raise where the criterion is undefined.

    Axes 4, 5, 6 meet iff ``a_4 = a_5 = d_5 = 0``; other 6R wrists are accepted. Refused with
    :class:`NotSphericalWristError`: not 6R, or ``sin(alpha_4)``/``sin(alpha_5)`` = 0 (two wrist
    axes parallel at every pose: ``det J22 = 0`` everywhere, nothing to maximise).
    """
    if robot.dof != 6:
        raise NotSphericalWristError(
            f"robot {robot.name!r}: the arm-wrist criterion needs 6 revolute joints, got {robot.dof}"
        )
    j = robot.joints
    for k in (4, 5):
        if abs(np.sin(j[k].alpha_prev)) < 1e-9:
            raise NotSphericalWristError(
                f"robot {robot.name!r}: {j[k].name}.alpha_prev = {np.degrees(j[k].alpha_prev):g} deg "
                "makes two wrist axes parallel at every pose (the criterion would be 0 everywhere); "
                "it must not be 0 or 180 deg"
            )
    return max(abs(j[4].a_prev), abs(j[5].a_prev), abs(j[4].d)) <= tol


def least_squares_wrist_point(z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The point nearest to three lines in the least-squares sense, and its distance to each.

    Parameters
    ----------
    z : (N, 3, 3) unit directions of the lines, ``z[:, i]`` for line i
    p : (N, 3, 3) a point on each line [m]

    Returns
    -------
    x : (N, 3) the minimiser of ``sum_i |P_i (x - p_i)|^2``, ``P_i = I - z_i z_i^T`` [m], from
        ``(sum_i P_i) x = sum_i P_i p_i`` (singular only for three parallel lines)
    dist : (N, 3) ``|P_i (x - p_i)|``, the distance of ``x`` from each line [m]
    """
    proj = np.eye(3) - z[..., :, None] * z[..., None, :]  # (N, 3 lines, 3, 3)
    x = np.linalg.solve(proj.sum(1), (proj @ p[..., None]).sum(1))[..., 0]
    dist = np.linalg.norm((proj @ (x[:, None, :] - p)[..., None])[..., 0], axis=-1)
    return x, dist


def wrist_point(robot: RobotDescription, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The criterion's wrist point (N, 3) [m] and its distances (N, 3) [m] from axes 4, 5, 6.

    For a spherical wrist this is the origin of DH frame 5 (distances exactly 0), bit for bit as
    before; otherwise the least-squares point of the three wrist axes, whose distances measure
    how far the wrist is from spherical (UR10: d_5/2, 0, d_5/2 at every pose).
    """
    spherical = check_wrist(robot)
    rot, pos = dh_frames(robot, q)
    if spherical:
        return pos[:, 4], np.zeros((pos.shape[0], 3))
    return least_squares_wrist_point(rot[:, 3:6, :, 2], pos[:, 3:6])
