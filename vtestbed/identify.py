"""Identification core: delta_d = A c, stacked over tests, solved for the compliances c = 1/k.

For one test with geometric Jacobian J (6, n) at the block reference point and the external
wrench F (6,) at that point (both in one frame), the paper's model
``delta_d = J K^-1 J^T F`` is linear in the compliances: ``A[i, j] = J[i, j] (J^T F)[j]``.
"""

from __future__ import annotations

import numpy as np


def a_matrix(jacobian: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """The (6, n) matrix A of one test: ``delta_d = A @ c`` (paper Eq. 25).

    Parameters
    ----------
    jacobian : (6, n) geometric Jacobian ``[v; omega]`` at the point the wrench acts on [m, 1]
    wrench : (6,) external wrench ``[f; tau]`` at that point, same frame [N, N*m]
    """
    jacobian = np.asarray(jacobian, dtype=float)
    joint_torque = jacobian.T @ np.asarray(wrench, dtype=float)
    return jacobian * joint_torque[None, :]
