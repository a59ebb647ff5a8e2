"""Importing a URDF's 6R chain (``vtestbed robot import``), checked against Pinocchio's own URDF
model (``pin.buildModelFromUrdf``): FK, geometric Jacobian and inertias of the imported
description, in vtestbed's Pinocchio model and in the generated MuJoCo world."""

import importlib.metadata
import re
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from vtestbed import robots
from vtestbed.cli.main import main
from vtestbed.design import kappa
from vtestbed.errors import DescriptionError, UnknownNameError
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.robot_import import import_urdf
from vtestbed.urdf import read_urdf
from vtestbed.world import mjcf
from vtestbed.world.truth import load_truth

# How models/ur10 was made (its README says so); the drift test repeats it.
UR10_SOURCE = (
    "the UR10 of the example-robot-data 6.0.0 wheel (PyPI), robots/ur_description/urdf/ur10_robot.urdf"
)
TOL = 1e-9


def _ur10_urdf():
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed (pip install -e '.[test]')")
    return next(f.locate() for f in files if str(f).endswith("ur_description/urdf/ur10_robot.urdf"))


@pytest.fixture(scope="module")
def ur10_urdf():
    return _ur10_urdf()


def _random_6r_urdf(path, seed=7):
    """A 6R chain with arbitrary joint placements, skew axes and rotated inertials (not DH-shaped)."""
    rng = np.random.default_rng(seed)

    def vec(scale):
        return " ".join(f"{v:.17g}" for v in rng.uniform(-scale, scale, 3))

    def inertial():
        return (
            f'<inertial><origin xyz="{vec(0.1)}" rpy="{vec(3.0)}"/><mass value="{rng.uniform(1, 10):.17g}"/>'
            f'<inertia ixx="{rng.uniform(0.1, 0.2):.17g}" ixy="0.01" ixz="-0.02" iyy="{rng.uniform(0.1, 0.2):.17g}"'
            f' iyz="0.015" izz="{rng.uniform(0.1, 0.2):.17g}"/></inertial>'
        )

    parts = [f'<robot name="skew6"><link name="l0">{inertial()}</link>']
    for i in range(1, 7):
        kind = "continuous" if i == 4 else "revolute"
        limit = (
            '<limit effort="100" velocity="1"/>'
            if i == 4
            else '<limit lower="-2" upper="2.5" effort="100" velocity="1"/>'
        )
        parts.append(
            f'<joint name="j{i}" type="{kind}"><parent link="l{i - 1}"/><child link="l{i}"/>'
            f'<origin xyz="{vec(0.3)}" rpy="{vec(3.0)}"/><axis xyz="{vec(1.0)}"/>{limit}</joint>'
            f'<link name="l{i}">{inertial()}</link>'
        )
    parts.append(
        f'<joint name="bolt" type="fixed"><parent link="l6"/><child link="tool"/><origin xyz="{vec(0.1)}" '
        f'rpy="{vec(3.0)}"/></joint><link name="tool">{inertial()}</link><link name="frame_only"/>'
        '<joint name="marker" type="fixed"><parent link="l3"/><child link="frame_only"/></joint></robot>'
    )
    path.write_text("".join(parts))
    return path


@pytest.fixture(scope="module")
def skew_robot(tmp_path_factory):
    """The random chain imported through the CLI into a scratch models folder: (robot, urdf path)."""
    tmp = tmp_path_factory.mktemp("models")
    urdf = _random_6r_urdf(tmp / "skew6.urdf")
    mp = pytest.MonkeyPatch()
    mp.setattr(robots, "MODELS_DIR", tmp)
    try:  # the loaders cache what they read: the scratch folder is needed only while importing
        assert main(["robot", "import", str(urdf), "--name", "skew6_test", "--tip", "tool"]) == 0
        loaded = robots.load_robot("skew6_test"), load_truth("skew6_test"), urdf
    finally:
        mp.undo()
    return loaded


def _reference(urdf, tip):
    model = pin.buildModelFromUrdf(str(urdf))
    return model, model.createData(), model.getFrameId(tip)


def _random_q(ref_model, rng):
    """Random URDF joint positions [rad] inside the URDF's limits (a continuous joint: +-pi)."""
    out = []
    for joint in ref_model.joints[1:]:
        if joint.nq == 2:
            out.append(rng.uniform(-np.pi, np.pi))
        else:
            i = joint.idx_q
            out.append(rng.uniform(ref_model.lowerPositionLimit[i], ref_model.upperPositionLimit[i]))
    return np.array(out)


def _q_pin(ref_model, q):
    """URDF joint positions -> Pinocchio's configuration (a continuous joint is (cos, sin))."""
    out, k = [], 0
    for joint in ref_model.joints[1:]:
        out += [np.cos(q[k]), np.sin(q[k])] if joint.nq == 2 else [q[k]]
        k += 1
    return np.array(out)


def _compare_chain(robot, truth, urdf, tip, lab, n_poses=100):
    """Worst |pose error| and |Jacobian error| of vtestbed's Pinocchio model and the MuJoCo world
    against Pinocchio's URDF model, at the flange and at the block, over random poses."""
    ref, data, fid = _reference(urdf, tip)
    block = ref.addFrame(
        pin.Frame(
            "block",
            ref.frames[fid].parentJoint,
            ref.frames[fid].placement * pin.SE3(lab.block_in_flange),
            pin.FrameType.OP_FRAME,
        )
    )
    data = ref.createData()
    kin = ArmKinematics(robot, lab.block_in_flange)
    model = mjcf.build_scene_spec(robot, truth, lab).compile()
    mj = mujoco.MjData(model)
    sites = {fid: model.site(mjcf.FLANGE_SITE).id, block: model.site(mjcf.BLOCK_SITE).id}
    rng = np.random.default_rng(3)
    worst_pose = worst_jac = 0.0
    for _ in range(n_poses):
        q = _random_q(ref, rng)
        theta = robot.controller_to_dh(q)
        pin.framesForwardKinematics(ref, data, _q_pin(ref, q))
        pin.computeJointJacobians(ref, data)
        mj.qpos[:] = theta
        mujoco.mj_kinematics(model, mj)
        mujoco.mj_comPos(model, mj)
        for frame, tool in ((fid, np.eye(4)), (block, lab.block_in_flange)):
            expected = data.oMf[frame].homogeneous
            jac_ref = pin.getFrameJacobian(ref, data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            site = sites[frame]
            mj_pose = np.eye(4)
            mj_pose[:3, :3], mj_pose[:3, 3] = mj.site_xmat[site].reshape(3, 3), mj.site_xpos[site]
            jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            mujoco.mj_jacSite(model, mj, jp, jr, site)
            for pose in (kin.flange_pose(theta) @ tool, mj_pose):
                worst_pose = max(worst_pose, np.abs(pose - expected).max())
            for jac in (kin.jacobian(theta, tool), np.vstack([jp, jr])):
                worst_jac = max(worst_jac, np.abs(jac - jac_ref).max())
    return worst_pose, worst_jac


def test_ur10_fk_and_jacobian_match_pinocchio_urdf_model(ur10_urdf, lab):
    robot = robots.load_robot("ur10")
    worst_pose, worst_jac = _compare_chain(robot, load_truth("ur10"), ur10_urdf, "tool0", lab)
    assert worst_pose < TOL and worst_jac < TOL, (worst_pose, worst_jac)


def test_any_6r_chain_matches_pinocchio_urdf_model(skew_robot, lab):
    robot, truth, urdf = skew_robot
    assert np.abs(robot.base_transform - np.eye(4)).max() > 0.1  # the chain needs both transforms
    assert np.abs(robot.flange_transform - np.eye(4)).max() > 0.1
    worst_pose, worst_jac = _compare_chain(robot, truth, urdf, "tool", lab)
    assert worst_pose < TOL and worst_jac < TOL, (worst_pose, worst_jac)


def test_inertias_match_pinocchio_and_mujoco(skew_robot, lab):
    """Each link's mass, com and full inertia (fixed children lumped) equal Pinocchio's URDF
    inertias moved into the DH frame; MuJoCo's principal axes rebuild the same tensor."""
    robot, truth, urdf = skew_robot
    ref, data, _ = _reference(urdf, "tool")
    q0 = np.zeros(6)
    pin.forwardKinematics(ref, data, _q_pin(ref, q0))
    dh_frames = robots.RobotDescription.frame_poses(robot, robot.controller_to_dh(q0))
    model = mjcf.build_robot_spec(robot, truth).compile()
    for i, joint in enumerate(robot.joints):
        dh_in_link = pin.SE3(data.oMi[i + 1].homogeneous).inverse() * pin.SE3(dh_frames[i])
        expected = dh_in_link.inverse().act(ref.inertias[i + 1])  # the URDF body, in DH axes
        assert abs(joint.mass - expected.mass) < 1e-12
        np.testing.assert_allclose(joint.com, expected.lever, atol=1e-12)
        np.testing.assert_allclose(joint.inertia, expected.inertia, atol=1e-12)
        body = model.body(f"link{i + 1}")
        rot = Rotation.from_quat(body.iquat, scalar_first=True).as_matrix()
        np.testing.assert_allclose(rot @ np.diag(body.inertia) @ rot.T, joint.inertia, atol=1e-12)
    assert abs(robot.total_mass - sum(i.mass for i in ref.inertias)) < 1e-12


def test_conditioning_and_kappa_frames_honour_base_and_flange(skew_robot, lab):
    """robots.jacobian_conditioning and kappa.dh_frames against Pinocchio's URDF model."""
    robot, _, urdf = skew_robot
    ref, data, fid = _reference(urdf, "tool")
    rng = np.random.default_rng(5)
    point = lab.block_in_flange[:3, 3]
    for _ in range(20):
        q = _random_q(ref, rng)
        theta = robot.controller_to_dh(q)
        pin.framesForwardKinematics(ref, data, _q_pin(ref, q))
        pin.computeJointJacobians(ref, data)
        jac = pin.getFrameJacobian(ref, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        tool = data.oMf[fid]
        jac[:3] -= np.cross(tool.rotation @ point, jac[3:], axis=0)  # move the point to the block
        s = np.linalg.svd(jac, compute_uv=False)
        assert abs(robot.jacobian_conditioning(theta, point) - s[-1] / s[0]) < 1e-9
        rot, pos = kappa.dh_frames(robot, theta[None])
        for k in range(6):  # DH frame k: z along the URDF axis (the Jacobian's column), origin on it
            axis = jac[3:, k]
            np.testing.assert_allclose(rot[0, k][:, 2], axis, atol=1e-9)
            gap = pos[0, k] - data.oMi[k + 1].translation
            assert np.linalg.norm(gap - (gap @ axis) * axis) < 1e-9
        _, _, p = kappa.arm_wrist_blocks(robot, theta[None], point="flange")
        np.testing.assert_allclose(p[0], tool.translation, atol=1e-9)


def test_committed_ur10_files_are_what_the_importer_produces(ur10_urdf):
    imported = import_urdf(
        read_urdf(ur10_urdf), "ur10", tip="tool0", source_note=UR10_SOURCE, rated_payload_kg=10.0
    )
    directory = robots.robot_dir("ur10")
    for name, text in (
        ("robot.toml", imported.robot_toml),
        ("truth.toml", imported.truth_toml),
        ("README.md", imported.readme),
    ):
        assert (directory / name).read_text() == text, (
            f"models/ur10/{name} drifted: run `vtestbed robot import ... --force`"
        )
    # the UR10's rated torques (330, 330, 150, 54, 54, 54 N*m) over the assumed 2.5 mrad
    np.testing.assert_allclose(imported.stiffness, np.array([330, 330, 150, 54, 54, 54]) / 2.5e-3, rtol=1e-15)


def _edited(urdf, tmp_path, edit):
    tree = ET.parse(urdf)
    edit(tree.getroot())
    out = tmp_path / "edited.urdf"
    tree.write(out)
    return out


def _cli_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vtestbed: error: ") and "Traceback" not in err
    return err


def test_bad_urdfs_get_clear_errors(ur10_urdf, tmp_path, capsys):
    missing = tmp_path / "nope.urdf"
    assert "nope.urdf is missing" in _cli_error(capsys, ["robot", "import", str(missing), "--name", "x"])
    (tmp_path / "junk.urdf").write_text("<robot><link name='a'></robot")
    with pytest.raises(DescriptionError, match=r"junk\.urdf: not valid XML"):
        read_urdf(tmp_path / "junk.urdf")
    urdf = read_urdf(ur10_urdf)
    with pytest.raises(
        UnknownNameError,
        match=r"--tip link of .*ur10_robot\.urdf 'tool9'; valid names: base, base_link, ee_link",
    ):
        import_urdf(urdf, "x", tip="tool9")
    with pytest.raises(UnknownNameError, match=r"--base link .* valid names: .*forearm_link"):
        import_urdf(urdf, "x", base="plinth")
    with pytest.raises(
        DescriptionError,
        match=r"'world' -> 'forearm_link' has 3 revolute joints \(shoulder_pan_joint, shoulder_lift_joint, elbow_joint\); a 6R arm needs exactly 6",
    ):
        import_urdf(urdf, "x", tip="forearm_link")
    with pytest.raises(DescriptionError, match=r"link 'base_link' is not below the base link 'tool0'"):
        import_urdf(urdf, "x", base="tool0", tip="base_link")

    def prismatic(root):
        root.find("joint[@name='elbow_joint']").set("type", "prismatic")

    with pytest.raises(
        DescriptionError, match=r"joint 'elbow_joint' between 'world' and 'tool0' is prismatic"
    ):
        import_urdf(read_urdf(_edited(ur10_urdf, tmp_path, prismatic)), "x", tip="tool0")

    def no_inertial(root):
        link = root.find("link[@name='wrist_2_link']")
        link.remove(link.find("inertial"))

    err = _cli_error(
        capsys, ["robot", "import", str(_edited(ur10_urdf, tmp_path, no_inertial)), "--name", "x"]
    )
    assert re.search(r"link 'wrist_2_link' \(moved by joint 'wrist_2_joint'\) has no <inertial>", err)
    err = _cli_error(
        capsys, ["robot", "import", str(ur10_urdf), "--name", "x", "--stiffness-Nm-per-rad", "1,2,3"]
    )
    assert "--stiffness-Nm-per-rad must be 6 finite numbers > 0" in err
    assert "not a valid robot name" in _cli_error(
        capsys, ["robot", "import", str(ur10_urdf), "--name", "../x"]
    )


def test_description_transforms_are_checked(tmp_path, monkeypatch):
    text = (robots.MODELS_DIR / "ur10" / "robot.toml").read_text()
    (tmp_path / "bent").mkdir()
    bent = text.replace("flange_in_dh = [\n    [1.0, 0.0,", "flange_in_dh = [\n    [2.0, 0.0,")
    (tmp_path / "bent" / "robot.toml").write_text(bent)
    monkeypatch.setattr(robots, "MODELS_DIR", tmp_path)
    with pytest.raises(
        DescriptionError, match=r"bent/robot\.toml: flange_in_dh is not a rigid transform \(valid: 4 rows"
    ):
        robots.load_robot("bent")
