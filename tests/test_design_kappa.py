"""The arm-wrist criterion and its optimum against independent references: Pinocchio Jacobians,
closed forms of the two factors, brute-force grids and the paper's tables."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from vtestbed.design import kappa
from vtestbed.errors import JointLimitError, UnknownNameError
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.robots import RobotDescription


def _random_poses(robot, rng, count):
    return rng.uniform(robot.lower, robot.upper, (count, robot.dof))


def _closed_form(robot, q):
    """Both factors from geometry alone (theta_1 = 0 not needed: kappa_F ignores rotations).

    Wrist: 1/kappa_F(J22) = sqrt(3 s^2 / (s^2 + 2)), s = sin(theta_5).
    Arm: J11 columns are r e_perp (r = distance of W from axis 1), z2 x a and z2 x b with
    a = W - p2, b = W - p3 in the arm plane, so its Gram matrix is diag(r^2) + [[a.a, a.b], [a.b, b.b]].
    """
    kin = ArmKinematics(robot)
    frames = kin.joint_poses(q)
    w, p2, p3 = frames[4][:3, 3], frames[1][:3, 3], frames[2][:3, 3]
    r2 = w[0] ** 2 + w[1] ** 2
    a, b = w - p2, w - p3
    cross2 = np.dot(np.cross(a, b), np.cross(a, b))
    arm = 3.0 / np.sqrt((r2 + a @ a + b @ b) * (1.0 / r2 + (a @ a + b @ b) / cross2))
    s2 = np.sin(q[4]) ** 2
    return arm, np.sqrt(3 * s2 / (s2 + 2))


def test_vectorised_blocks_match_pinocchio(robot, lab, rng):
    kin = ArmKinematics(robot)
    q = _random_poses(robot, rng, 20)
    for point, offset in (("flange", np.eye(4)), ("block", lab.block_in_flange)):
        j11, j22, p = kappa.arm_wrist_blocks(robot, q, point)
        for k in range(len(q)):
            jac = kin.jacobian(q[k], tool_in_flange=offset)
            np.testing.assert_allclose(j11[k], jac[:3, :3], atol=1e-13)
            np.testing.assert_allclose(j22[k], jac[3:, 3:], atol=1e-13)
            np.testing.assert_allclose(p[k], kin.tool_pose(q[k], offset)[:3, 3], atol=1e-13)
    j11, _, _ = kappa.arm_wrist_blocks(robot, q, "wrist")
    for k in range(len(q)):
        wrist_in_flange = np.linalg.inv(kin.flange_pose(q[k])) @ kin.joint_poses(q[k])[4]
        jac = kin.jacobian(q[k], tool_in_flange=wrist_in_flange)
        np.testing.assert_allclose(j11[k], jac[:3, :3], atol=1e-13)
        assert np.abs(jac[:3, 3:]).max() < 1e-13  # J12 = 0 at the wrist centre


def test_adjugate_form_equals_the_inverse_form(rng):
    m = rng.normal(size=(200, 3, 3))
    direct = 3.0 / (np.linalg.norm(m, axis=(1, 2)) * np.linalg.norm(np.linalg.inv(m), axis=(1, 2)))
    np.testing.assert_allclose(kappa.inv_kappa_frobenius(m), direct, rtol=1e-11)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    assert kappa.inv_kappa_frobenius(7.3 * rot) == pytest.approx(1.0, abs=1e-14)


def test_both_factors_match_their_closed_forms(robot, rng):
    for q in _random_poses(robot, rng, 50):
        value = kappa.criterion(robot, q)
        arm, wrist = _closed_form(robot, q)
        assert value.inv_kappa_arm == pytest.approx(arm, rel=1e-11)
        assert value.inv_kappa_wrist == pytest.approx(wrist, rel=1e-12)
        assert 0.0 < value.inv_kappa <= 1.0


def test_elbow_singularity_is_derived_from_a3_and_d4(robot):
    stretched, folded = kappa.elbow_singular_theta3(robot)
    assert np.degrees(stretched) == pytest.approx(-np.degrees(np.arctan(0.820 / 0.145)), abs=1e-12)  # -79.97
    assert np.degrees(folded) == pytest.approx(180.0 - np.degrees(np.arctan(0.820 / 0.145)), abs=1e-12)


def _shoulder_singular(robot, theta3, others):
    kin = ArmKinematics(robot)

    def wrist_x(t2):  # signed distance of W from axis 1, in the arm plane
        w = kin.joint_poses(np.r_[others[0], t2, theta3, others[1:]])[4][:3, 3]
        return w[0] * np.cos(others[0]) + w[1] * np.sin(others[0])

    grid = np.linspace(robot.lower[1], robot.upper[1], 200)
    x = np.array([wrist_x(t) for t in grid])
    k = int(np.flatnonzero(np.sign(x[:-1]) != np.sign(x[1:]))[0])
    return np.r_[others[0], brentq(wrist_x, grid[k], grid[k + 1], xtol=1e-15), theta3, others[1:]]


def test_criterion_is_zero_at_each_kind_of_singularity(robot, rng):
    stretched, folded = kappa.elbow_singular_theta3(robot)
    for _ in range(5):
        q = _random_poses(robot, rng, 1)[0]
        wrist, elbow, folded_q = q.copy(), q.copy(), q.copy()
        wrist[4] = 0.0
        elbow[2], folded_q[2] = stretched, folded
        shoulder = _shoulder_singular(robot, rng.uniform(-150, -30) * np.pi / 180, q[[0, 3, 4, 5]])
        values = [
            kappa.criterion(robot, wrist).inv_kappa,
            kappa.criterion(robot, elbow).inv_kappa,
            kappa.criterion(robot, folded_q, check_limits=False).inv_kappa,  # beyond the joint 3 limits
            kappa.criterion(robot, shoulder).inv_kappa,
        ]
        assert max(values) < 1e-12, values
        for point in ("flange", "block"):  # off the wrist centre only z4 // z6 stays structural
            assert kappa.criterion(robot, wrist, point).inv_kappa < 1e-12


def test_criterion_is_positive_away_from_singularities(robot, rng):
    stretched, _ = kappa.elbow_singular_theta3(robot)
    q = _random_poses(robot, rng, 20000)
    _, _, w = kappa.arm_wrist_blocks(robot, q)
    away = (np.abs(np.sin(q[:, 4])) > 0.1) & (np.abs(np.sin(q[:, 2] - stretched)) > 0.1)
    away &= np.hypot(w[:, 0], w[:, 1]) > 0.1
    values = kappa.inv_kappa_batch(robot, q[away])
    assert away.sum() > 10000 and values.min() > 1e-3


def _scaled(robot: RobotDescription, factor: float) -> RobotDescription:
    joints = tuple(replace(j, a_prev=j.a_prev * factor, d=j.d * factor) for j in robot.joints)
    return replace(robot, joints=joints)


def test_criterion_is_free_of_the_length_unit(robot, lab, rng):
    in_mm = _scaled(robot, 1000.0)
    q = _random_poses(robot, rng, 200)
    for point_m, point_mm in (("wrist", "wrist"), ("flange", "flange"), ((0, 0.1, 0.3), (0, 100.0, 300.0))):
        np.testing.assert_allclose(
            kappa.inv_kappa_batch(in_mm, q, point_mm), kappa.inv_kappa_batch(robot, q, point_m), rtol=1e-11
        )


def test_bad_input_is_refused_with_a_clear_error(robot):
    q = np.radians([0, -30, -20, 40, 60, 45])
    with pytest.raises(JointLimitError, match=r"joint5 = 150.000 deg .*\[-119.0, 119.0\]"):
        kappa.criterion(robot, np.r_[q[:4], np.radians(150), q[5]])
    bad = robot.joints[
        5
    ]  # axes 5 and 6 parallel: det J22 = 0 at every pose (offset wrists: test_design_offset_wrist)
    joints = robot.joints[:5] + (replace(bad, alpha_prev=np.pi),)
    with pytest.raises(
        kappa.NotSphericalWristError, match=r"joint6.alpha_prev = 180 deg .* must not be 0 or 180"
    ):
        kappa.criterion(replace(robot, joints=joints), q)
    with pytest.raises(kappa.NotSphericalWristError, match="6 revolute joints, got 5"):
        kappa.optimize(replace(robot, joints=robot.joints[:5]))
    with pytest.raises(UnknownNameError, match="valid names: block, flange, wrist"):
        kappa.criterion(robot, q, point="elbow")


def test_optimum_is_reproducible_and_a_local_maximum_inside_the_limits(robot, optimum):
    again = kappa.optimize(robot, seed=3)
    np.testing.assert_array_equal(again.q, optimum.q)
    assert np.all(optimum.q >= robot.lower) and np.all(optimum.q <= robot.upper) and not any(optimum.at_limit)
    assert np.abs(optimum.gradient).max() < 1e-4  # 1/rad
    assert optimum.curvature[[0, 1, 3]].max() < -0.3  # joints 2, 3, 5
    assert abs(optimum.curvature[2]) < 1e-8  # joint 4 cannot act at the wrist centre
    assert abs(np.degrees(optimum.q[4])) == pytest.approx(90.0, abs=1e-3)  # the closed-form wrist optimum
    flange = kappa.optimize(robot, point="flange", seed=3)
    assert np.abs(flange.gradient).max() < 1e-4 and flange.curvature.max() < -0.01


def test_optimum_beats_a_brute_force_grid(robot, optimum):
    t2 = np.radians(np.arange(-135, 35.01, 0.5))
    t3 = np.radians(np.arange(-210, 68.01, 0.5))
    g2, g3 = np.meshgrid(t2, t3, indexing="ij")
    q = np.zeros((g2.size, 6))
    q[:, 1], q[:, 2], q[:, 4] = g2.ravel(), g3.ravel(), np.pi / 2
    best = kappa.inv_kappa_batch(robot, q).max()
    assert best - 1e-12 <= optimum.inv_kappa < best + 1e-4
    assert optimum.inv_kappa == pytest.approx(0.934786, abs=1e-6)


def test_paper_pose_is_high_only_as_controller_angles_and_is_not_an_optimum(robot, optimum):
    as_ctrl = kappa.criterion(robot, kappa.paper_optimum(robot, as_controller=True))
    as_dh = kappa.criterion(robot, kappa.paper_optimum(robot, as_controller=False))
    assert as_ctrl.inv_kappa == pytest.approx(0.7837, abs=1e-4) and as_dh.inv_kappa < 0.2
    q = kappa.paper_optimum(robot)
    grad, _ = kappa.finite_difference(
        lambda x: kappa.inv_kappa_batch(robot, np.r_[q[0], x, q[5]][None])[0], q[1:5]
    )
    assert abs(grad[3]) > 0.1  # theta_5 = 59.4 deg is not stationary: the wrist factor peaks at 90 deg
