"""From a recorded test to what the identification needs: the wrench moved to the block by hand,
the displacement against MuJoCo's true block motion, the Jacobian against MuJoCo's, and the
model's prediction J K^-1 J^T F written out."""

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vtestbed.dataset import DatasetSetup, write_setup
from vtestbed.dataset import TestRecord as Record  # under their own names pytest would try to
from vtestbed.dataset import TestWriter as Writer  # collect them as test classes
from vtestbed.errors import DatasetError, JointLimitError, ScanError
from vtestbed.ply import read_ply, write_ply
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import TestMeasurement as Measurement  # not a test class
from vtestbed.researcher.measure import (
    commanded_pose,
    identify_measurements,
    load_measurements,
    measure_arrays,
    measure_test,
    motionless_tests,
    predict_displacement,
    wrench_at_block,
)
from vtestbed.transforms import invert
from vtestbed.world import mjcf
from vtestbed.world.physics import run_test_physics
from vtestbed.world.rig import Rig

# Gao et al. 2023, Table 5 [N*mm/rad], typed from the paper.
K_TABLE5 = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7]) / 1000.0  # N*m/rad
POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)


def _setup(lab, block_in_flange=None, convention="dh") -> DatasetSetup:
    return DatasetSetup("kuka_kr60_3", convention, lab.block_in_flange if block_in_flange is None else block_in_flange,
                        lab.sensor_in_flange, lab.block.edge, lab.sensor.name, lab.sensor.wrench_range)  # fmt: skip


def test_wrench_at_block_is_the_sensor_wrench_moved_by_hand(lab):
    block = lab.block_in_flange.copy()
    block[:3, :3] = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    sensor = lab.sensor_in_flange.copy()
    sensor[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    sensor[:3, 3] += [0.01, -0.02, 0.0]
    setup = _setup(lab, block)
    setup = DatasetSetup(**{**setup.__dict__, "sensor_in_flange": sensor})
    w = np.array([120.0, -45.0, 80.0, 3.0, -1.5, 0.7])
    # by hand, in flange axes: F, and the torque about the block origin tau_s + (o_s - o_b) x F
    r_b, o_b, r_s, o_s = block[:3, :3], block[:3, 3], sensor[:3, :3], sensor[:3, 3]
    f_flange = r_s @ w[:3]
    tau_flange = r_s @ w[3:] + np.cross(o_s - o_b, f_flange)
    expected = np.r_[r_b.T @ f_flange, r_b.T @ tau_flange]
    np.testing.assert_allclose(wrench_at_block(w, setup), expected, rtol=0, atol=1e-12)
    # the paper's lab: axes parallel, so only the lever arm of 100 mm along z acts
    e = lab.block.edge
    lever = np.array([-e / 2, -e / 2, -(lab.block.standoff + e)])  # sensor origin seen from B
    np.testing.assert_allclose(
        wrench_at_block(w, _setup(lab)), np.r_[w[:3], w[3:] + np.cross(lever, w[:3])], rtol=0, atol=1e-12
    )


def test_controller_angles_become_dh_angles(robot, lab):
    a = np.array([10.0, -80.0, 120.0, 30.0, 45.0, -60.0])
    record = Record("T001", "identification", a, np.zeros(6), np.zeros(6), np.eye(4), Path(), Path())
    # KR60-3: theta = A except theta_3 = A_3 - 90 deg (decoded in the robot's README)
    np.testing.assert_allclose(
        np.degrees(commanded_pose(record, _setup(lab, convention="controller"), robot)),
        a - [0, 0, 90, 0, 0, 0],
        atol=1e-12,
    )
    np.testing.assert_array_equal(commanded_pose(record, _setup(lab), robot), np.radians(a))


def _synthetic(robot, lab, count, group="identification", seed=0):
    """Noise-free measurements d = J K^-1 J^T F at Table 5, Jacobians from Pinocchio."""
    kin = ArmKinematics(robot, lab.block_in_flange)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        q = np.radians([0, -60, -20, 30, 50, 45]) + rng.uniform(-0.4, 0.4, 6)
        jac = kin.jacobian(q, frame="tool")
        wrench = np.r_[rng.normal(0, 120, 3), rng.normal(0, 8, 3)]
        d = jac @ np.diag(1.0 / K_TABLE5) @ jac.T @ wrench
        out.append(Measurement(f"T{i}", group, q, wrench, d, jac, np.eye(4), np.eye(4)))
    return out


def test_prediction_is_j_k_inverse_jt_f(robot, lab):
    m = _synthetic(robot, lab, 1)[0]
    k = K_TABLE5 * np.array([1.1, 0.9, 1.0, 1.2, 0.8, 1.05])
    np.testing.assert_allclose(
        predict_displacement(m, k),
        m.jacobian @ np.linalg.inv(np.diag(k)) @ m.jacobian.T @ m.wrench,
        rtol=1e-12,
    )


def test_identification_uses_the_identification_group_only(robot, lab):
    tests = _synthetic(robot, lab, 6)
    junk = [Measurement(**{**m.__dict__, "displacement": m.displacement * 3}) for m in _synthetic(robot, lab, 3, "validation", 1)]  # fmt: skip
    res = identify_measurements(tests[:3] + junk + tests[3:], joint_names=robot.joint_names)
    np.testing.assert_allclose(res.stiffness, K_TABLE5, rtol=1e-9)
    assert res.n_tests == 6 and res.joint_names == robot.joint_names
    with pytest.raises(DatasetError, match="^the dataset has no test in group 'identification'"):
        identify_measurements(junk)
    with pytest.raises(DatasetError) as err:  # a dataset's: the file and the column
        identify_measurements(junk, source="lab/ds")
    assert str(err.value) == (
        "lab/ds/tests.csv: the dataset has no test in group 'identification' (column group: "
        "identification or validation; its 3 tests are all validation): at least one identification "
        "test is needed"
    )


@pytest.fixture(scope="module")
def measured(robot, lab):
    """One test in a gravity-free world (the wrench change is the wire alone), noise-free clouds."""
    rig = Rig(robot, lab, gravity=False)
    q = np.radians(POSE_DEG)
    phys = run_test_physics(rig, q, "hook_edge", "ring_4", 300.0, 0.6)
    record = Record("T007", "identification", np.degrees(q), phys.unloaded.sensor_wrench,
                    phys.loaded.sensor_wrench, phys.scanner.pose_world, Path(), Path())  # fmt: skip
    kin = ArmKinematics(robot, lab.block_in_flange)
    m = measure_arrays(record, phys.hits_unloaded.points_m, phys.hits_loaded.points_m, _setup(lab), kin)
    return rig, phys, m


def test_displacement_is_mujocos_block_motion_in_the_block_frame(measured):
    _, phys, m = measured
    p0, p1 = phys.unloaded.block_pose, phys.loaded.block_pose
    r0 = p0[:3, :3]
    truth = np.r_[r0.T @ (p1[:3, 3] - p0[:3, 3]), Rotation.from_matrix(r0.T @ p1[:3, :3]).as_rotvec()]
    np.testing.assert_allclose(m.displacement, truth, rtol=0, atol=1e-9)
    assert np.linalg.norm(truth[:3]) > 1e-4  # a real displacement (0.1 mm and more)
    assert m.fit_methods == ("fast", "fast")  # the nominal kinematics place the block well enough


def test_a_miscalibrated_scanner_pose_falls_back_to_ransac_for_the_unloaded_scan(measured, robot, lab):
    """A recorded scanner pose 25 deg off about the block: the unloaded fit falls back (and is
    right), the loaded one starts from it and takes the fast path; the same displacement."""
    _, phys, m = measured
    corner = invert(phys.scanner.pose_world) @ phys.unloaded.block_pose  # B in the scanner frame
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_rotvec(np.radians(25.0) * np.array([0.6, 0.0, 0.8])).as_matrix()
    about = corner @ turn @ invert(corner)  # a rotation about B's origin, scanner frame
    wrong = phys.scanner.pose_world @ invert(about)  # so the nominal block is turned by 25 deg
    record = Record("T008", "identification", np.degrees(phys.unloaded.q_cmd), phys.unloaded.sensor_wrench,
                    phys.loaded.sensor_wrench, wrong, Path(), Path())  # fmt: skip
    kin = ArmKinematics(robot, lab.block_in_flange)
    off = measure_arrays(record, phys.hits_unloaded.points_m, phys.hits_loaded.points_m, _setup(lab), kin)
    assert off.fit_methods == ("ransac", "fast")
    np.testing.assert_allclose(off.frame_unloaded, m.frame_unloaded, rtol=0, atol=1e-12)
    np.testing.assert_allclose(off.displacement, m.displacement, rtol=0, atol=1e-12)


def test_wrench_is_the_wire_force_at_the_block_in_its_axes(measured):
    _, phys, m = measured
    s1 = phys.loaded
    force = s1.wire_tension * s1.wire_direction  # world axes
    torque = np.cross(s1.hook_position - s1.block_pose[:3, 3], force)  # about B's origin
    rot = s1.block_pose[:3, :3]
    np.testing.assert_allclose(m.wrench, np.r_[rot.T @ force, rot.T @ torque], rtol=0, atol=1e-6)
    assert np.linalg.norm(m.wrench[:3]) == pytest.approx(300.0, abs=1e-3)


def test_jacobian_is_mujocos_at_the_commanded_pose_in_block_axes(measured):
    rig, phys, m = measured
    model = rig.model
    data = mujoco.MjData(model)
    data.qpos[:] = phys.unloaded.q_cmd
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    site = model.site(mjcf.BLOCK_SITE).id
    jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jp, jr, site)
    rot = data.site_xmat[site].reshape(3, 3)
    np.testing.assert_allclose(m.jacobian, np.vstack([rot.T @ jp, rot.T @ jr]), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.q, phys.unloaded.q_cmd)


def test_missing_clouds_and_empty_datasets_are_named(tmp_path, lab, robot):
    write_setup(tmp_path, _setup(lab))
    with Writer(tmp_path):
        pass
    with pytest.raises(DatasetError, match=r"tests\.csv holds no tests"):
        load_measurements(tmp_path)
    cloud = write_ply(tmp_path / "clouds" / "u.ply", np.random.default_rng(0).normal(size=(10, 3)))
    record = Record("T003", "identification", np.array(POSE_DEG), np.zeros(6), np.zeros(6), np.eye(4),
                    cloud, tmp_path / "clouds" / "gone.ply")  # fmt: skip
    kin = ArmKinematics(robot, lab.block_in_flange)
    with pytest.raises(ScanError, match=r"test T003, loaded cloud .*gone\.ply: point cloud file not found"):
        measure_test(record, _setup(lab), kin)
    bad_pose = Record("T004", "identification", np.array([0, 40.0, 0, 0, 0, 0]), np.zeros(6), np.zeros(6),
                      np.eye(4), cloud, cloud)  # fmt: skip
    with pytest.raises(
        JointLimitError,
        match=r"test T004 pose \(tests\.csv q1_deg\.\., dh angles\): joint2 = 40\.000 deg .*\[-135\.0, 35\.0\]",
    ):
        measure_test(bad_pose, _setup(lab), kin)


def test_a_cloud_in_mm_and_a_cloud_without_the_block_name_the_file(tmp_path, lab, robot):
    """A lab's scan in mm read as m (the fit alone would say only "block not found"), and a cloud
    that misses the block: both errors name the test, the state and the file."""
    rng = np.random.default_rng(2)
    (tmp_path / "clouds").mkdir()
    mm = write_ply(tmp_path / "clouds" / "T005_loaded.ply", rng.normal([0, 0, 600.0], 40.0, (200, 3)))
    far = write_ply(tmp_path / "clouds" / "T005_unloaded.ply", rng.normal([3.0, 0, 2.0], 0.1, (200, 3)))
    kin = ArmKinematics(robot, lab.block_in_flange)
    record = Record(
        "T005", "identification", np.array(POSE_DEG), np.zeros(6), np.zeros(6), np.eye(4), far, mm
    )
    with pytest.raises(ScanError) as exc:
        measure_test(record, _setup(lab), kin)
    reach = np.abs(read_ply(mm)).max()
    assert 600 < reach < 1000 and str(exc.value) == (
        f"test T005, loaded cloud {mm}: coordinates reach {reach:.4g} m, beyond 50 m: is the file in mm? "
        "A dataset's clouds are in m (vtestbed dataset import --cloud-units mm converts them)"
    )
    with pytest.raises(ScanError) as exc:
        measure_test(replace(record, cloud_loaded=far), _setup(lab), kin)
    assert str(exc.value).startswith(
        f"test T005, unloaded cloud {far}: block not found: only 0 of 200 points"
    )
    assert str(exc.value).endswith(
        "the nominal pose is wrong (the pose's angles and their convention, the scanner's pose)"
    )


def _raw_ply(path, pts) -> Path:
    """A binary PLY as a scanner may write it, NaN and inf included (write_ply refuses them)."""
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
    header += "property double x\nproperty double y\nproperty double z\nend_header\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(header.encode() + np.asarray(pts, "<f8").tobytes())
    return path


def test_non_finite_points_name_the_test_and_the_file(tmp_path, lab, robot):
    from vtestbed.researcher.repeat_scans import estimate_noise_floor

    pts = np.random.default_rng(1).normal(size=(50, 3))
    pts[[3, 7], 1], pts[9, 2] = np.nan, np.inf  # 3 points, one coordinate each
    bad = _raw_ply(tmp_path / "clouds" / "T003_loaded.ply", pts)
    good = write_ply(tmp_path / "clouds" / "T003_unloaded.ply", np.nan_to_num(pts, posinf=0.0))
    record = Record(
        "T003", "identification", np.array(POSE_DEG), np.zeros(6), np.zeros(6), np.eye(4), good, bad
    )
    kin = ArmKinematics(robot, lab.block_in_flange)
    with pytest.raises(ScanError) as exc:
        measure_test(record, _setup(lab), kin)
    assert str(exc.value) == (
        f"test T003, loaded cloud {bad}: 3 of its 50 points have a NaN or infinite coordinate; "
        "valid: finite coordinates in m (remove those points, or rescan)"
    )
    # a repeat scan, read for the noise floor, says the same with its repeat number
    write_setup(tmp_path, _setup(lab))
    with Writer(tmp_path) as w:
        w.append(record)
    (tmp_path / "repeats.csv").write_text("test_id,repeat,cloud\nT003,1,clouds/T003_loaded_copy.ply\n")
    _raw_ply(tmp_path / "clouds" / "T003_loaded_copy.ply", pts)
    with pytest.raises(
        ScanError, match=r"^test T003, repeat 1 cloud .*T003_loaded_copy\.ply: 3 of its 50 points"
    ):
        estimate_noise_floor(tmp_path)


def test_a_block_that_did_not_move_under_load_is_flagged_by_test_id(robot, lab):
    tests = _synthetic(robot, lab, 8)  # exact model displacements: k = Table 5
    clean = identify_measurements(tests, joint_names=robot.joint_names)
    assert clean.warnings == ()
    zero = Measurement(**{**tests[2].__dict__, "displacement": np.zeros(6)})  # the same scan twice
    tiny = Measurement(**{**tests[5].__dict__, "displacement": tests[5].displacement * 0.01})
    just = Measurement(
        **{**tests[6].__dict__, "displacement": tests[6].displacement * 0.2}
    )  # small, possible
    with pytest.warns(UserWarning, match=r"tests T2, T5: the block barely moved"):
        res = identify_measurements([*tests[:2], zero, *tests[3:5], tiny, just, tests[7]])
    assert res.warnings[-1].startswith("tests T2, T5: the block barely moved under the load")
    assert "below 5% of the fitted model's" in res.warnings[-1]
    assert motionless_tests(tests, 1.0 / K_TABLE5) == []


def test_the_same_cloud_as_unloaded_and_loaded_is_a_motionless_test(measured, robot, lab):
    rig, phys, m = measured
    record = Record("T009", "identification", np.degrees(phys.unloaded.q_cmd), phys.unloaded.sensor_wrench,
                    phys.loaded.sensor_wrench, phys.scanner.pose_world, Path(), Path())  # fmt: skip
    kin = ArmKinematics(robot, lab.block_in_flange)
    same = measure_arrays(record, phys.hits_unloaded.points_m, phys.hits_unloaded.points_m, _setup(lab), kin)
    assert np.linalg.norm(same.displacement[:3]) < 1e-9 * np.linalg.norm(m.displacement[:3])
    assert motionless_tests([same, m], 1.0 / K_TABLE5) == ["T009"]
