"""Clearance of candidate tests on the nominal model (no MuJoCo): the design's physical filter.

The same pairs and margins as the truth world (:mod:`vtestbed.clearance`, docs/clearance.md), on
the commanded pose's nominal kinematics (Pinocchio) and the lab's nominal layout: the link shells
from the DH frame origins, the sensor, stem and block on the flange (a mesh target: its convex
hull, :mod:`vtestbed.target_geometry`), the table top and the floor,
the wire from the hook to the ring, and the scanner where the operator places it (0.6 m from the
block centre along the block's (1, 1, 1) by default). The truth world sags under the load by
well under a millimetre at the block, so a nominal pass within the margins is a truth pass.
"""

from __future__ import annotations

import numpy as np

from ..clearance import (
    ClearanceReport,
    arm_shapes,
    base_shape,
    face_points,
    pose_clearances,
    scanner_position,
    sight_clearances,
    table_shape,
    tool_shapes,
    wire_clearances_many,
)
from ..convex_shapes import Capsule, Plane
from ..errors import OutOfRangeError
from ..lab import DEFAULT_SCANNER_DISTANCE_M, PAPER_LAB, LabSetup
from ..researcher.kinematics import ArmKinematics
from ..robots import RobotDescription


class NominalClearance:
    """Clearance checks of (pose, hook, ring) tests on the nominal model.

    Parameters
    ----------
    robot : RobotDescription
        The nominal robot (DH, limits).
    lab : LabSetup
        Sensor, block, table and wire.
    distance_m : float
        Scanner stand-off [m] (optical centre to block centre), within the datasheet's working distance.
    view_direction_block : (3,) array
        Direction from the block centre to the scanner, in the block frame (as ``Scanner.place``).
    """

    def __init__(
        self,
        robot: RobotDescription,
        lab: LabSetup = PAPER_LAB,
        distance_m: float = DEFAULT_SCANNER_DISTANCE_M,
        view_direction_block=(1.0, 1.0, 1.0),
    ):
        low, high = lab.scanner.working_distance_m
        if not low <= distance_m <= high:
            raise OutOfRangeError(
                f"distance_m (scanner stand-off) = {distance_m!r} m is outside the valid range "
                f"[{low:g}, {high:g}] m (the {lab.scanner.name}'s working distance)"
            )
        self.robot, self.lab, self.distance_m = robot, lab, float(distance_m)
        self.view = np.asarray(view_direction_block, dtype=float)
        self.kin = ArmKinematics(robot, lab.block_in_flange)
        self.table, self.floor = table_shape(lab), Plane("floor", 0.0)
        self._pose_key: bytes | None = None
        self.refused = 0  # tests refused by candidate_tests through this checker (a count for reports)

    def _at(self, q) -> None:
        """Shapes and pose-only clearances at DH pose ``q`` [rad] (cached for the last pose)."""
        q = np.asarray(q, dtype=float)
        if self._pose_key == q.tobytes():
            return
        frames = self.kin.joint_poses(q)
        self.links = arm_shapes([f[:3, 3] for f in frames])
        self.tool = tool_shapes(frames[-1], self.lab)
        self.block_pose = frames[-1] @ self.lab.block_in_flange
        self.block = self.tool[-1]
        self.scanner = scanner_position(self.block_pose, self.lab.block.edge, self.distance_m, self.view)
        self.targets = face_points(self.block_pose, self.lab.block.edge)
        self.pose_entries = pose_clearances(self.links, self.tool, self.table, self.floor)
        self.pose_entries += sight_clearances(self.scanner, self.targets, self.links + self.tool[:3])
        self._pose_key = q.tobytes()

    def check(self, q, hook: str, anchor: str) -> ClearanceReport:
        """Every clearance pair of the test (pose ``q`` [rad] DH, block ``hook``, table ring ``anchor``)."""
        return self.check_many(q, hook, [anchor])[0]

    def check_many(self, q, hook: str, anchors) -> list[ClearanceReport]:
        """:meth:`check` for one pose and hook and several rings (one vectorised pass)."""
        q = self.robot.check_pose(q, field="pose")
        self._at(q)
        hook_w = self.block_pose[:3, :3] @ self.lab.block.hook(hook) + self.block_pose[:3, 3]
        rings = np.array([self.lab.table.anchor(a) for a in anchors]).reshape(-1, 3)
        radius = self.lab.wire.diameter / 2
        obstacles = [base_shape()] + self.links + self.tool[:3]
        wires = wire_clearances_many(hook_w, rings, obstacles, self.block, radius)
        return [
            ClearanceReport(tuple(self.pose_entries + entries + sight_clearances(
                self.scanner, self.targets, [Capsule("wire", hook_w, ring, radius)])))
            for ring, entries in zip(rings, wires)
        ]  # fmt: skip

    def pose_report(self, q) -> ClearanceReport:
        """The pairs that do not depend on the wire (links on the table and floor, the scanner's view)."""
        self._at(self.robot.check_pose(q, field="pose"))
        return ClearanceReport(tuple(self.pose_entries))
