"""What the truth world looks like at a static equilibrium: :class:`RigState` (a value).

Units SI; poses (4, 4) in the robot base frame; angles in DH radians; the F/T sensor's wrench in
the sensor frame, torques about the sensor origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RigState:
    """What the world looks like at equilibrium (SI; poses in the robot base frame).

    ``sensor_wrench`` is the load that everything below the sensor puts on it (gravity of the
    tool side plus the wire), as an ATI sensor reports it: (Fx, Fy, Fz, Tx, Ty, Tz) [N, N*m]
    in the sensor frame, torques about the sensor origin.
    """

    q_cmd: np.ndarray  # (n,) DH rad
    q: np.ndarray  # (n,) DH rad, true joint angles
    deflection: np.ndarray  # (n,) rad, q - q_cmd
    qpos_all: np.ndarray  # (nq,) every dof of the world, incl. effects' joints
    flange_pose: np.ndarray  # (4, 4)
    block_pose: np.ndarray  # (4, 4) block frame B
    sensor_pose: np.ndarray  # (4, 4)
    sensor_wrench: np.ndarray  # (6,)
    wire_tension: float  # N, 0 when slack
    wire_length: float  # m
    wire_rest_length: float  # m (mjcf.SLACK_LENGTH when slack)
    wire_direction: np.ndarray  # (3,) unit vector hook -> anchor
    hook_position: np.ndarray  # (3,)
    residual: float  # N*m, max |generalized force residual|
    iterations: int
