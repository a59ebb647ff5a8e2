"""The two values every candidate term is built from: a :class:`Candidate` (a named model
extension and its columns) and the :class:`ModelContext` of one dataset.

Frames: displacements, Jacobians and wrenches in the unloaded block frame (B axes, B origin), as
:mod:`vtestbed.researcher.measure` builds them; joint frames and the block pose in the robot's
base frame, from the nominal kinematics at the commanded pose. Units: SI (m, rad, N, N*m).
:mod:`vtestbed.researcher.candidates` defines the terms themselves.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..dataset import DatasetSetup
from .kinematics import ArmKinematics
from .measure import TestMeasurement, wrench_at_block
from .statics import sensor_load_torque

__all__ = ["Candidate", "ModelContext"]


@dataclass(frozen=True)
class Candidate:
    """A model extension: ``columns(context, compliance) -> (6 T, p)`` with named parameters."""

    name: str  # the effect it stands for (vtestbed.world.effects names)
    label: str  # this instance, e.g. "joint_coupling(5,6)"
    params: tuple[str, ...]  # parameter names with units
    columns: Callable
    bilinear: bool = False  # columns depend on the compliances (refit after an update)
    absorbed: tuple = ()  # (parameter, note): left out, the stiffnesses explain it (diagnose.identifiable)
    # nonlinear in its own parameters: ``columns(ctx, compliance, params)`` gives the secant through
    # ``params`` (columns @ params = the term's exact contribution there); see :meth:`design`
    secant: bool = False

    def design(self, ctx: ModelContext, compliance, params=None) -> np.ndarray:
        """(6 T, p) columns at ``compliance``; for a ``secant`` term at its estimate ``params``
        (None: the derivative at zero, the first-order term), so that a fitted model predicts the
        term's exact contribution, not its linearisation."""
        if self.secant and params is not None:
            return self.columns(ctx, compliance, np.asarray(params, dtype=float))
        return self.columns(ctx, compliance)


@dataclass
class ModelContext:
    """What the columns need, computed once per dataset from the nominal model (SI)."""

    measurements: list[TestMeasurement]
    setup: DatasetSetup
    kin: ArmKinematics
    statics: object = None  # an ExactStatics: fit the paper's model plus the clean world's statics

    def __post_init__(self):
        self.frames = [self.kin.joint_poses(m.q) for m in self.measurements]
        self.block = [self.kin.tool_pose(m.q, self.setup.block_in_flange) for m in self.measurements]
        eye = np.eye(6)
        self.sensor_to_block = np.column_stack([wrench_at_block(eye[k], self.setup) for k in range(6)])
        self.wrench_sensor = [np.linalg.solve(self.sensor_to_block, m.wrench) for m in self.measurements]

    @property
    def n_tests(self) -> int:
        return len(self.measurements)

    @cached_property
    def payload_torque(self) -> np.ndarray:
        """(T, n) joint torques [N*m] of the unloaded F/T reading (the weight of what the sensor
        carries: plate and block) at the commanded pose; zero where a test has no raw readings."""
        out = np.zeros((self.n_tests, self.kin.robot.dof))
        for t, m in enumerate(self.measurements):
            if m.readings is not None:
                out[t] = sensor_load_torque(self.kin, self.setup, m.q, np.asarray(m.readings[0], dtype=float))
        return out

    def hinge_column(self, t: int, point: np.ndarray, axis: np.ndarray) -> np.ndarray:
        """(6,) displacement per unit compliance of a hinge at world ``point`` about world ``axis``."""
        rot, origin = self.block[t][:3, :3], self.block[t][:3, 3]
        j = np.concatenate([rot.T @ np.cross(axis, origin - point), rot.T @ axis])
        return j * (j @ self.measurements[t].wrench)

    def predicted(self, t: int, compliance: np.ndarray, wrench: np.ndarray | None = None) -> np.ndarray:
        """J C J^T W (6,) at the commanded pose for a block wrench ``wrench`` (default: measured)."""
        m = self.measurements[t]
        w = m.wrench if wrench is None else wrench
        return m.jacobian @ (compliance * (m.jacobian.T @ w))
