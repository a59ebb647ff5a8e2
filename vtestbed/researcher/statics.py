"""The clean world's statics, exactly: what the paper's linear model leaves out in every lab.

The paper predicts a test's displacement as ``J K^-1 J^T dW`` at the commanded pose. The robot
really settles where ``K (q - q_cmd) = -g(q) + J_s(q)^T W_s(q)``: its own weight ``g`` (nominal
inertias, Pinocchio RNEA) and the load the force sensor reads ``W_s`` (everything beyond the
sensor: tool weight and wire), both at the sagged pose, with the sensor's Jacobian taken there
too. The block's displacement is then the exact rigid motion between its frames at the unloaded
and the loaded equilibria. This captures gravity's geometric stiffness, the load-dependent
Jacobian (the paper's complementary stiffness matrix) and second-order kinematics at once.

:meth:`ExactStatics.gap` is the difference between that and the paper's prediction, for given
compliances: :func:`vtestbed.researcher.diagnose.fit_model` subtracts it from the measurements
(iterating with the compliances) when asked for the exact statics. Nominal model only: it reads
the robot description, the setup and the recorded F/T readings, never the world. Units: SI.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..dataset import DatasetSetup
from ..errors import ConvergenceError, DatasetError
from ..transforms import displacement_in_block_frame
from .kinematics import ArmKinematics
from .measure import TestMeasurement

MAX_ITERATIONS = 60
TOLERANCE = 1e-13  # rad: far below any deflection the scanner sees (1e-6 rad)


class ExactStatics:
    """The nominal robot's static equilibrium under its weight and the measured sensor load."""

    def __init__(self, kin: ArmKinematics, setup: DatasetSetup):
        self.kin, self.setup = kin, setup
        self._zeros = np.zeros(kin.model.nv)

    def equilibrium(self, q_cmd: np.ndarray, compliance: np.ndarray, reading: np.ndarray) -> np.ndarray:
        """(n,) joint angles [rad] where ``q = q_cmd + C (-g(q) + J_s(q)^T W_s(q))`` (fixed point).

        ``reading`` (6,) [N, N*m] is the F/T reading in the sensor frame (the load on the sensor).
        """
        kin, q = self.kin, np.array(q_cmd, dtype=float)
        for _ in range(MAX_ITERATIONS):
            sensor = kin.tool_pose(q, self.setup.sensor_in_flange)
            rot = sensor[:3, :3]
            wrench = np.concatenate([rot @ reading[:3], rot @ reading[3:]])
            jac = kin.jacobian(q, self.setup.sensor_in_flange, frame="base")
            gravity = pin.rnea(kin.model, kin.data, q, self._zeros, self._zeros)
            q_next = q_cmd + compliance * (jac.T @ wrench - gravity)
            if np.max(np.abs(q_next - q)) < TOLERANCE:
                return q_next
            q = q_next
        raise ConvergenceError(
            "exact statics: the joint deflections did not settle (compliances far too large?)"
        )

    def displacement(self, m: TestMeasurement, compliance: np.ndarray) -> np.ndarray:
        """(6,) the block's displacement [m, rad] in its unloaded frame, from the two equilibria."""
        if m.readings is None:
            raise DatasetError(f"test {m.test_id}: the exact statics need the raw F/T readings")
        poses = [
            self.kin.tool_pose(self.equilibrium(m.q, compliance, w), self.setup.block_in_flange)
            for w in m.readings
        ]
        return displacement_in_block_frame(*poses)

    def gap(self, measurements: list[TestMeasurement], compliance: np.ndarray) -> np.ndarray:
        """(6 T,) exact minus the paper's prediction, stacked, at ``compliance`` [rad/(N*m)]."""
        out = []
        for m in measurements:
            paper = m.jacobian @ (compliance * (m.jacobian.T @ m.wrench))
            out.append(self.displacement(m, compliance) - paper)
        return np.concatenate(out) if out else np.zeros(0)
