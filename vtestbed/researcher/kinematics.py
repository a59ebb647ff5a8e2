"""The researcher's kinematic model (Pinocchio), built from the same robot description.

This is the model side: it knows the nominal geometry (DH table, the block's pose on the
flange) but nothing of the world's true stiffness or hidden effects.

Jacobians are geometric, ordered ``[v; omega]`` as in the paper (J = [J_P; J_O]): ``v`` is the
velocity of the chosen point, ``omega`` the angular velocity.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..robots import RobotDescription, load_robot
from ..transforms import homogeneous, rot_x


def build_pinocchio_model(robot: RobotDescription) -> pin.Model:
    """A Pinocchio model with one ``JointModelRZ`` per DH joint and the robot's inertias.

    Joint placement i is Rx(alpha_{i-1}) Tx(a_{i-1}) Tz(d_i): Rz(theta_i) and Tz(d_i) commute,
    so the modified-DH product is reproduced exactly. The first placement is preceded by the
    description's ``dh0_in_base``; the ``flange`` frame sits at ``flange_in_dh`` in the last joint.
    """
    model = pin.Model()
    model.name = robot.name
    parent = 0
    base = pin.SE3(robot.base_transform)
    for joint in robot.joints:
        placement = pin.SE3(
            rot_x(joint.alpha_prev),
            np.array([joint.a_prev, 0.0, 0.0]) + rot_x(joint.alpha_prev) @ [0, 0, joint.d],
        )
        if parent == 0:
            placement = base * placement
        jid = model.addJoint(
            parent,
            pin.JointModelRZ(),
            placement,
            joint.name,
            np.full(1, np.inf),
            np.full(1, np.inf),
            np.array([joint.lower]),
            np.array([joint.upper]),
        )
        inertia = pin.Inertia(joint.mass, np.array(joint.com), joint.inertia)
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        parent = jid
    flange = pin.SE3(robot.flange_transform)
    model.addFrame(pin.Frame("flange", parent, flange, pin.FrameType.OP_FRAME))
    return model


class ArmKinematics:
    """Forward kinematics and Jacobians at points fixed to the flange (e.g. the block).

    Parameters
    ----------
    robot : RobotDescription
    tool_in_flange : (4, 4) array, optional
        Default tool frame (e.g. the block frame B) in the flange frame.
    flange_mass : float
        Mass [kg] that the flange carries and the F/T sensor does not read (the sensor's mounting
        plate and upper half), added to the last link's inertia at ``flange_com`` (3,) [m] in the
        flange frame, so that the weight in the statics is the arm's plus that (0: the robot's own).
    """

    def __init__(
        self,
        robot: RobotDescription,
        tool_in_flange: np.ndarray | None = None,
        flange_mass: float = 0.0,
        flange_com=(0.0, 0.0, 0.0),
    ):
        self.robot = robot
        self.model = build_pinocchio_model(robot)
        if flange_mass > 0:  # a point mass: the statics need its weight, not its rotational inertia
            com = robot.flange_transform @ np.append(np.asarray(flange_com, dtype=float), 1.0)
            point = pin.Inertia(flange_mass, com[:3], np.zeros((3, 3)))
            self.model.appendBodyToJoint(self.model.njoints - 1, point, pin.SE3.Identity())
        self.data = self.model.createData()
        self.tool_in_flange = np.eye(4) if tool_in_flange is None else np.asarray(tool_in_flange, dtype=float)
        self._last_joint = self.model.njoints - 1
        self._flange = robot.flange_transform  # the flange in the last DH frame

    @classmethod
    def for_setup(cls, setup, robot: RobotDescription | None = None) -> ArmKinematics:
        """The model of a dataset's setup (a :class:`vtestbed.dataset.DatasetSetup`): its block
        frame as the tool, and the weight its flange carries above the sensor's measurement
        (``setup.sensor_mount_mass``) among the masses; ``robot`` defaults to ``setup.robot``'s."""
        robot = load_robot(setup.robot) if robot is None else robot
        return cls(robot, setup.block_in_flange, setup.sensor_mount_mass, setup.sensor_mount_com)

    def _update(self, q) -> None:
        q = np.asarray(q, dtype=float)
        pin.forwardKinematics(self.model, self.data, q)
        pin.computeJointJacobians(self.model, self.data, q)

    def flange_pose(self, q) -> np.ndarray:
        """(4, 4) pose of the flange (``flange_in_dh`` in DH frame 6) in the base frame at DH angles ``q`` [rad]."""
        self._update(q)
        return self.data.oMi[self._last_joint].homogeneous @ self._flange

    def joint_poses(self, q) -> list[np.ndarray]:
        """Poses of DH frames 1..n in the base frame, each (4, 4)."""
        self._update(q)
        return [self.data.oMi[i].homogeneous.copy() for i in range(1, self.model.njoints)]

    def tool_pose(self, q, tool_in_flange: np.ndarray | None = None) -> np.ndarray:
        """(4, 4) pose of a frame fixed to the flange (default: the tool frame)."""
        offset = self.tool_in_flange if tool_in_flange is None else tool_in_flange
        return self.flange_pose(q) @ offset

    def jacobian(self, q, tool_in_flange: np.ndarray | None = None, frame: str = "base") -> np.ndarray:
        """Geometric Jacobian (6, n) of a frame fixed to the flange, ``[v; omega]``.

        Parameters
        ----------
        q : (n,) DH angles [rad]
        tool_in_flange : (4, 4), optional
            The point (its origin) and the frame (its axes); default: the tool frame.
        frame : {"base", "tool"}
            ``"base"``: v and omega in base axes (velocity of the tool origin).
            ``"tool"``: the same vectors in the tool frame's axes.
        """
        if frame not in ("base", "tool"):
            from ..errors import UnknownNameError

            raise UnknownNameError("Jacobian frame", frame, ("base", "tool"))
        offset = self.tool_in_flange if tool_in_flange is None else np.asarray(tool_in_flange)
        offset = self._flange @ offset  # the tool in the last DH frame, the joint Pinocchio knows
        self._update(q)
        j_flange_local = pin.getJointJacobian(
            self.model, self.data, self._last_joint, pin.ReferenceFrame.LOCAL
        )
        tool = pin.SE3(offset[:3, :3], offset[:3, 3])
        j_tool_local = tool.inverse().action @ j_flange_local  # [v; w] of the tool in tool axes
        if frame == "tool":
            return j_tool_local
        rot = self.data.oMi[self._last_joint].rotation @ offset[:3, :3]
        out = np.empty_like(j_tool_local)
        out[:3] = rot @ j_tool_local[:3]
        out[3:] = rot @ j_tool_local[3:]
        return out


def tool_frame(rotation=None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Convenience (4, 4) frame in the flange frame."""
    return homogeneous(np.eye(3) if rotation is None else np.asarray(rotation), translation)
