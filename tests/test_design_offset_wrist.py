"""The arm-wrist criterion for an offset (UR-type) wrist, against independent references: the
least-squares wrist point against scipy.optimize.minimize on the same objective, the blocks
against Pinocchio's Jacobian at that point, the UR10's closed forms (distances d_5/2, 0, d_5/2,
||J12||_F = d_5/sqrt(2)), and the KR60's frame-5 origin (every existing number unchanged)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

from vtestbed.design import kappa, regions
from vtestbed.design import optimal as design
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.robots import load_robot

# the UR10's rated-torque stiffness (docs/robots.md) as the design's prior [N*m/rad]
UR10_PRIOR = np.array([1.32e5, 1.32e5, 6.0e4, 2.16e4, 2.16e4, 2.16e4])


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10")


@pytest.fixture(scope="module")
def ur10_optimum(ur10):
    return kappa.optimize(ur10, seed=0)


def _wrist_axes(kin, q):
    """Directions and points (each (3, 3), rows = axes 4, 5, 6) from Pinocchio's joint frames."""
    frames = kin.joint_poses(q)[3:6]
    return np.array([f[:3, 2] for f in frames]), np.array([f[:3, 3] for f in frames])


def _summed_squared_distance(x, z, p):
    return sum(np.sum(np.cross(z[i], x - p[i]) ** 2) for i in range(3))  # |u x r| = distance, |u| = 1


def test_kr60_wrist_point_is_the_frame5_origin(robot, rng):
    kin = ArmKinematics(robot)
    q = rng.uniform(robot.lower, robot.upper, (50, 6))
    point, dist = kappa.wrist_point(robot, q)
    rot, pos = kappa.dh_frames(robot, q)
    np.testing.assert_array_equal(point, pos[:, 4])  # the spherical path: bit for bit as before
    assert not dist.any()
    general, general_dist = kappa.least_squares_wrist_point(rot[:, 3:6, :, 2], pos[:, 3:6])
    for k in range(len(q)):  # the general formula lands on Pinocchio's frame-5 origin as well
        np.testing.assert_allclose(general[k], kin.joint_poses(q[k])[4][:3, 3], rtol=0, atol=1e-12)
    assert general_dist.max() < 1e-12


def test_ur10_least_squares_point_minimises_the_summed_squared_distances(ur10, rng):
    kin = ArmKinematics(ur10)
    q = rng.uniform(ur10.lower, ur10.upper, (8, 6))
    point, dist = kappa.wrist_point(ur10, q)
    for k in range(len(q)):
        z, p = _wrist_axes(kin, q[k])
        start = p[1] + np.array([0.1, -0.05, 0.2])
        found = minimize(_summed_squared_distance, start, args=(z, p), method="BFGS", options={"gtol": 1e-13})
        np.testing.assert_allclose(point[k], found.x, rtol=0, atol=1e-8)
        own = [np.linalg.norm(np.cross(z[i], point[k] - p[i])) for i in range(3)]
        np.testing.assert_allclose(dist[k], own, rtol=0, atol=1e-12)
    # closed form: axes 4-5 and 5-6 meet d_5 apart on axis 5; the optimum is halfway between
    d5 = ur10.joints[4].d
    np.testing.assert_allclose(dist, np.tile([d5 / 2, 0.0, d5 / 2], (len(q), 1)), rtol=0, atol=1e-12)


def test_ur10_criterion_matches_pinocchio_at_the_same_point(ur10, rng):
    kin = ArmKinematics(ur10)
    d5 = ur10.joints[4].d
    for q in rng.uniform(ur10.lower, ur10.upper, (6, 6)):
        value = kappa.criterion(ur10, q)
        z, p = _wrist_axes(kin, q)
        x = minimize(_summed_squared_distance, p[1], args=(z, p), method="BFGS", options={"gtol": 1e-13}).x
        at_point = np.eye(4)
        at_point[:3, 3] = x
        jac = kin.jacobian(q, tool_in_flange=np.linalg.inv(kin.flange_pose(q)) @ at_point)
        j11, j12, j22 = jac[:3, :3], jac[:3, 3:], jac[3:, 3:]
        expected = 9.0 / (np.linalg.cond(j11, "fro") * np.linalg.cond(j22, "fro"))
        assert value.inv_kappa == pytest.approx(expected, rel=1e-7)
        s2 = np.sin(q[4]) ** 2  # z4 . z6 = cos(theta_5), z5 perpendicular to both: the KR60's closed form
        assert value.inv_kappa_wrist == pytest.approx(np.sqrt(3 * s2 / (s2 + 2)), rel=1e-12)
        assert value.coupling == pytest.approx(np.linalg.norm(j12) / np.linalg.norm(j11), rel=1e-7)
        assert np.linalg.norm(j12) == pytest.approx(d5 / np.sqrt(2), rel=1e-7)
        assert abs(np.linalg.det(jac) - value.det_j11 * value.det_j22) > 1e-6 * abs(np.linalg.det(jac))


def test_ur10_optimum_is_a_local_maximum_inside_the_limits(ur10, ur10_optimum, rng):
    opt = ur10_optimum
    assert np.all(opt.q >= ur10.lower) and np.all(opt.q <= ur10.upper) and not any(opt.at_limit)
    assert np.isfinite(opt.inv_kappa) and np.abs(opt.gradient).max() < 1e-4
    assert opt.curvature.max() < -0.01  # joint 4 now acts too: the wrist point moves with it
    q = rng.uniform(ur10.lower, ur10.upper, (50000, 6))
    q[:, 0], q[:, 5] = 0.0, np.radians(45.0)
    best = kappa.inv_kappa_batch(ur10, q).max()
    assert best - 1e-12 <= opt.inv_kappa <= 1.0
    assert opt.inv_kappa == pytest.approx(0.943283, abs=1e-5)


def test_ur10_regions_and_design_return_poses_inside_the_limits(ur10, ur10_optimum):
    pmap = regions.joint_plane_map(ur10, ur10_optimum.q, step_deg=2.0)
    box = regions.PoseConstraints(min_height=0.5, box_min=(0.3, -1, 0), box_max=(2.3, 1, 2.2))
    found = regions.restrict(regions.find_regions(pmap), pmap, ur10, box)
    assert any(r.excluded is None for r in found)
    draw = regions.sample_poses(ur10, pmap, found, 12, np.random.default_rng(4), constraints=box,
                                wrist_jitter_deg=20, threshold=0.7)  # fmt: skip
    assert np.all((draw.q >= ur10.lower) & (draw.q <= ur10.upper)) and np.all(box.ok(ur10, draw.q))
    np.testing.assert_allclose(draw.inv_kappa, kappa.inv_kappa_batch(ur10, draw.q), rtol=1e-12)
    assert np.all(np.isfinite(draw.inv_kappa)) and draw.inv_kappa.min() >= 0.7
    report = regions.wrist_report(ur10, draw.q)
    assert not report["spherical"] and report["wrist_axis_distances_m_max"][0] == pytest.approx(
        0.05785, abs=1e-12
    )
    # the clearance check's link shells are the KR60's: on the UR10 they reach below the floor
    cands = design.candidate_tests(ur10, draw.q, clearance=False)
    sel = design.select_tests(cands, 6, UR10_PRIOR)
    std = np.asarray(sel.to_dict()["relative_std_percent"])
    assert len(cands) > 6 and std.shape == (6,) and np.all(np.isfinite(std) & (std > 0))


def test_only_an_undefined_criterion_is_refused(robot):
    q = np.radians([0, -30, -20, 40, 60, 45])
    offset = robot.joints[:4] + (replace(robot.joints[4], a_prev=0.01),) + robot.joints[5:]
    value = kappa.criterion(replace(robot, joints=offset), q)  # an offset KR60 wrist is accepted
    assert 0 < value.inv_kappa <= 1 and value.wrist_axis_distances.max() > 1e-3 and value.coupling > 0
    parallel = robot.joints[:4] + (replace(robot.joints[4], alpha_prev=0.0),) + robot.joints[5:]
    with pytest.raises(kappa.NotSphericalWristError, match=r"joint5.alpha_prev = 0 deg .* not be 0 or 180"):
        kappa.optimize(replace(robot, joints=parallel))
    with pytest.raises(kappa.NotSphericalWristError, match="6 revolute joints, got 5"):
        regions.joint_plane_map(replace(robot, joints=robot.joints[:5]), q)
