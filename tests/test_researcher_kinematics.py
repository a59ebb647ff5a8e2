import mujoco
import numpy as np
import pytest
from dh_reference import flange_pose as dh_flange_pose
from scipy.spatial.transform import Rotation

from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.world import mjcf


@pytest.fixture(scope="module")
def world(robot, truth, lab):
    model = mjcf.build_scene_spec(robot, truth, lab).compile()
    return model, mujoco.MjData(model)


def test_flange_mujoco_and_pinocchio_match_explicit_dh(robot, world):
    model, data = world
    kin = ArmKinematics(robot)
    site = model.site(mjcf.FLANGE_SITE).id
    rng = np.random.default_rng(1)
    worst_pos = worst_rot = 0.0
    for _ in range(100):
        q = robot.random_pose(rng)
        ref = dh_flange_pose(q)
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mj_pose = np.eye(4)
        mj_pose[:3, :3] = data.site_xmat[site].reshape(3, 3)
        mj_pose[:3, 3] = data.site_xpos[site]
        for pose in (mj_pose, kin.flange_pose(q)):
            worst_pos = max(worst_pos, np.abs(pose[:3, 3] - ref[:3, 3]).max())
            rot_err = Rotation.from_matrix(pose[:3, :3] @ ref[:3, :3].T).magnitude()
            worst_rot = max(worst_rot, rot_err)
    assert worst_pos < 1e-9
    assert worst_rot < 1e-9


def _fd_jacobian(q, offset, h=1e-6):
    """Central differences of the explicit DH product at a point fixed to the flange."""
    jac = np.zeros((6, 6))
    for k in range(6):
        dq = np.zeros(6)
        dq[k] = h
        plus, minus = dh_flange_pose(q + dq) @ offset, dh_flange_pose(q - dq) @ offset
        jac[:3, k] = (plus[:3, 3] - minus[:3, 3]) / (2 * h)
        jac[3:, k] = Rotation.from_matrix(plus[:3, :3] @ minus[:3, :3].T).as_rotvec() / (2 * h)
    return jac


def test_block_jacobian_matches_mujoco_and_finite_differences(robot, lab, world):
    model, data = world
    kin = ArmKinematics(robot, lab.block_in_flange)
    site = model.site(mjcf.BLOCK_SITE).id
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = robot.random_pose(rng)
        jac = kin.jacobian(q)
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jp, jr, site)
        np.testing.assert_allclose(jac, np.vstack([jp, jr]), atol=1e-12)
        np.testing.assert_allclose(jac, _fd_jacobian(q, lab.block_in_flange), atol=1e-8)


def test_jacobian_in_tool_frame_is_the_rotated_base_jacobian(robot, lab):
    kin = ArmKinematics(robot, lab.block_in_flange)
    q = np.radians([10, -50, -30, 40, 60, -20])
    rot = kin.tool_pose(q)[:3, :3]
    base, tool = kin.jacobian(q, frame="base"), kin.jacobian(q, frame="tool")
    np.testing.assert_allclose(tool[:3], rot.T @ base[:3], atol=1e-13)
    np.testing.assert_allclose(tool[3:], rot.T @ base[3:], atol=1e-13)


def test_unknown_jacobian_frame_lists_valid_names(robot):
    with pytest.raises(KeyError, match="base, tool"):
        ArmKinematics(robot).jacobian(np.zeros(6), frame="world")


def test_base_and_flange_transforms_are_honoured_everywhere(robot, truth, lab):
    """The KR60 between an arbitrary base and flange transform: Pinocchio, MuJoCo, the
    description's own frames and the design's DH frames all equal base @ explicit DH @ flange."""
    from dataclasses import replace

    from vtestbed.design import kappa

    rng = np.random.default_rng(4)

    def rigid():
        out = np.eye(4)
        out[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        out[:3, 3] = rng.uniform(-0.3, 0.3, 3)
        return tuple(tuple(float(x) for x in row) for row in out)

    moved = replace(robot, dh0_in_base=rigid(), flange_in_dh=rigid())
    base, flange = moved.base_transform, moved.flange_transform
    kin = ArmKinematics(moved, lab.block_in_flange)
    model = mjcf.build_scene_spec(moved, truth, lab).compile()
    data = mujoco.MjData(model)
    site = model.site(mjcf.BLOCK_SITE).id
    for _ in range(20):
        q = moved.random_pose(rng)
        expected = base @ dh_flange_pose(q) @ flange @ lab.block_in_flange
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mj_pose = np.eye(4)
        mj_pose[:3, :3], mj_pose[:3, 3] = data.site_xmat[site].reshape(3, 3), data.site_xpos[site]
        for pose in (kin.tool_pose(q), mj_pose, moved.frame_poses(q)[-1] @ lab.block_in_flange):
            np.testing.assert_allclose(pose, expected, atol=1e-12)
        rot, pos = kappa.dh_frames(moved, q[None])
        dh6 = base @ dh_flange_pose(q)
        np.testing.assert_allclose(rot[0, 5], dh6[:3, :3], atol=1e-12)
        np.testing.assert_allclose(pos[0, 5], dh6[:3, 3], atol=1e-12)
        jac = kin.jacobian(q)
        np.testing.assert_allclose(
            jac[:3], base[:3, :3] @ _fd_jacobian(q, flange @ lab.block_in_flange)[:3], atol=1e-8
        )
