"""The clean world's statics, exactly: what the paper's linear model leaves out in every lab.

The paper predicts a test's displacement as ``J K^-1 J^T dW`` at the commanded pose. The robot
really settles where ``K (q - q_cmd) = -g(q) + J_s(q)^T W_s(q)``: its own weight ``g`` (nominal
inertias, Pinocchio RNEA) and the load the force sensor reads ``W_s`` (everything beyond the
sensor: tool weight and wire), both at the sagged pose, with the sensor's Jacobian taken there
too. The block's displacement is then the exact rigid motion between its frames at the unloaded
and the loaded equilibria. This captures gravity's geometric stiffness, the load-dependent
Jacobian (the paper's complementary stiffness matrix) and second-order kinematics at once.

Each of the three can be switched on alone (``terms``, names in :data:`CLEAN_WORLD_TERMS`):
``gravity_stiffness`` evaluates the weight at the sagged pose (off: at the commanded one, so it
does not change under the load); ``load_dependent_jacobian`` takes the sensor's Jacobian and
its axes at the sagged pose (off: at the commanded one); ``exact_kinematics`` takes the rigid
motion between the two sagged block frames (off: ``J(q_cmd) (q_loaded - q_unloaded)``). With
none on, the displacement is the paper's prediction (tested to round-off), so the gap each term
opens alone is its own part of the clean world's gap: :mod:`.candidates` offers the three as
named candidate terms when the baseline is the paper's model.

:meth:`ExactStatics.gap` is the difference between that and the paper's prediction, for given
compliances: :func:`vtestbed.researcher.diagnose.fit_model` subtracts it from the measurements
(iterating with the compliances) when asked for the exact statics. Nominal model only: it reads
the robot description, the setup and the recorded F/T readings, never the world. Units: SI.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..dataset import DatasetSetup
from ..errors import ConvergenceError, DatasetError, UnknownNameError
from ..transforms import displacement_in_block_frame
from .kinematics import ArmKinematics
from .measure import TestMeasurement

MAX_ITERATIONS = 60
TOLERANCE = 1e-13  # rad: far below any deflection the scanner sees (1e-6 rad)
CLEAN_WORLD_TERMS = ("gravity_stiffness", "load_dependent_jacobian", "exact_kinematics")


def sensor_load_torque(
    kin: ArmKinematics, setup: DatasetSetup, q: np.ndarray, reading: np.ndarray
) -> np.ndarray:
    """(n,) joint torques [N*m] of an F/T ``reading`` (6,) [N, N*m] (sensor frame: the load on the
    sensor) with the arm at ``q``: ``J_s(q)^T W_s``, the wrench in base axes at the sensor."""
    rot = kin.tool_pose(q, setup.sensor_in_flange)[:3, :3]
    wrench = np.concatenate([rot @ reading[:3], rot @ reading[3:]])
    return kin.jacobian(q, setup.sensor_in_flange, frame="base").T @ wrench


class ExactStatics:
    """The nominal robot's static equilibrium under its weight and the measured sensor load.

    ``terms``: which of :data:`CLEAN_WORLD_TERMS` the statics include (default: all three, the
    clean world's exact statics; none: the paper's linear model).
    """

    def __init__(self, kin: ArmKinematics, setup: DatasetSetup, terms=CLEAN_WORLD_TERMS):
        unknown = [t for t in terms if t not in CLEAN_WORLD_TERMS]
        if unknown:
            raise UnknownNameError("clean-world term", unknown[0], CLEAN_WORLD_TERMS)
        self.kin, self.setup, self.terms = kin, setup, frozenset(terms)
        self._zeros = np.zeros(kin.model.nv)
        # the last compliance's equilibria per test: the gap and a term's columns ask for the same
        self._equilibria_at: bytes = b""
        self._equilibria: dict[int, tuple] = {}  # id -> (the measurement, kept alive: ids stay unique; q's)

    def equilibrium(self, q_cmd: np.ndarray, compliance: np.ndarray, reading: np.ndarray) -> np.ndarray:
        """(n,) joint angles [rad] where ``q = q_cmd + C (-g(q) + J_s(q)^T W_s(q))`` (fixed point).

        ``reading`` (6,) [N, N*m] is the F/T reading in the sensor frame (the load on the sensor).
        """
        kin, q_cmd = self.kin, np.array(q_cmd, dtype=float)
        q = q_cmd
        for _ in range(MAX_ITERATIONS):
            at_load = q if "load_dependent_jacobian" in self.terms else q_cmd
            load = sensor_load_torque(kin, self.setup, at_load, reading)
            at_weight = q if "gravity_stiffness" in self.terms else q_cmd
            gravity = pin.rnea(kin.model, kin.data, at_weight, self._zeros, self._zeros)
            q_next = q_cmd + compliance * (load - gravity)
            if np.max(np.abs(q_next - q)) < TOLERANCE:
                return q_next
            q = q_next
        raise ConvergenceError(
            "exact statics: the joint deflections did not settle (compliances far too large?)"
        )

    def equilibria(self, m: TestMeasurement, compliance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The test's unloaded and loaded equilibria, each (n,) [rad], at ``compliance``
        [rad/(N*m)] (kept for the last compliance asked: the gap and a term's columns share them)."""
        if m.readings is None:
            raise DatasetError(f"test {m.test_id}: the exact statics need the raw F/T readings")
        key = np.asarray(compliance, dtype=float).tobytes()
        if key != self._equilibria_at:
            self._equilibria_at, self._equilibria = key, {}
        if id(m) not in self._equilibria:
            self._equilibria[id(m)] = (m, *(self.equilibrium(m.q, compliance, w) for w in m.readings))
        return self._equilibria[id(m)][1:]

    def displacement(self, m: TestMeasurement, compliance: np.ndarray) -> np.ndarray:
        """(6,) the block's displacement [m, rad] in its unloaded frame, from the two equilibria."""
        q_unloaded, q_loaded = self.equilibria(m, compliance)
        if "exact_kinematics" not in self.terms:
            jac = self.kin.jacobian(m.q, self.setup.block_in_flange, frame="tool")
            return jac @ (q_loaded - q_unloaded)
        poses = [self.kin.tool_pose(q, self.setup.block_in_flange) for q in (q_unloaded, q_loaded)]
        return displacement_in_block_frame(*poses)

    def gap(self, measurements: list[TestMeasurement], compliance: np.ndarray) -> np.ndarray:
        """(6 T,) exact minus the paper's prediction, stacked, at ``compliance`` [rad/(N*m)]."""
        out = []
        for m in measurements:
            paper = m.jacobian @ (compliance * (m.jacobian.T @ m.wrench))
            out.append(self.displacement(m, compliance) - paper)
        return np.concatenate(out) if out else np.zeros(0)
