"""Joint influence on the criterion against closed forms of the wrist factor, a known Fourier
series and the paper's Table 2."""

import numpy as np
import pytest

from vtestbed.design import influence, kappa
from vtestbed.researcher.kinematics import ArmKinematics


def test_joint5_curvature_matches_the_closed_form(robot, optimum):
    inf = influence.joint_influence(robot, optimum.q, joints=(4, 5))
    # f = arm * sqrt(3 s^2 / (s^2 + 2)); at theta_5 = 90 deg d2f/dtheta^2 = -2/3 arm per rad^2
    expected = -2.0 / 3.0 * kappa.criterion(robot, optimum.q).inv_kappa_arm * influence.DEG2
    assert inf.curvature_per_deg2[1] == pytest.approx(expected, rel=1e-4)
    assert abs(inf.curvature_per_deg2[0]) < 1e-12


def test_fourier_fit_recovers_a_trigonometric_polynomial():
    x = np.linspace(-170, 130, 601)
    w = 2 * np.pi / 300 * 0.7
    y = 0.3 + 0.2 * np.cos(w * x) - 0.1 * np.sin(3 * w * x) + 0.05 * np.cos(8 * w * x)
    fit = influence.fourier_fit(x, y, order=8, fit_frequency=True)
    d2 = -0.2 * w**2 * np.cos(w * 10) + 0.9 * w**2 * np.sin(3 * w * 10) - 3.2 * w**2 * np.cos(8 * w * 10)
    assert fit.w == pytest.approx(w, rel=1e-6) and fit.second_derivative(10.0) == pytest.approx(d2, rel=1e-5)


@pytest.mark.parametrize("point", ["wrist", "flange", "block"])
def test_curvature_magnitudes_against_paper_table2(robot, point):
    opt = kappa.optimize(robot, point=point, seed=0)
    curv = influence.joint_influence(robot, opt.q, point=point).curvature_per_deg2
    paper = np.abs(kappa.PAPER_TABLE2_PER_DEG2)
    assert abs(curv[0]) / paper[0] == pytest.approx(1.1, abs=0.1)  # joint 2 agrees
    assert 1.0 < abs(curv[3]) / paper[3] < 2.0  # joint 5 within a factor 2
    assert 3.0 < abs(curv[1]) / paper[1] < 5.0  # joint 3 does not: 4x the paper's
    if point == "block":  # a point off the wrist gives joint 4 the paper's small influence
        assert abs(curv[2]) / paper[2] == pytest.approx(1.0, abs=0.1)


def _wrist_curvature_closed_form(robot, q):
    """d2/dtheta5^2 of the criterion at the wrist centre [1/deg^2], from Pinocchio and calculus.

    At W the arm factor 1/kappa_F(J11) does not depend on theta_5, and the wrist factor is
    g = sqrt(h), h = 3u/(u + 2), u = sin^2(theta_5), so with h_t = h_u u', h_tt = h_uu u'^2 + h_u u'':
    g'' = h_tt / (2 sqrt h) - h_t^2 / (4 h^1.5).
    """
    kin = ArmKinematics(robot)
    wrist_in_flange = np.linalg.inv(kin.flange_pose(q)) @ kin.joint_poses(q)[4]
    j11 = kin.jacobian(q, tool_in_flange=wrist_in_flange)[:3, :3]
    arm = 3.0 / (np.linalg.norm(j11) * np.linalg.norm(np.linalg.inv(j11)))
    t = q[4]
    u, du, ddu = np.sin(t) ** 2, np.sin(2 * t), 2 * np.cos(2 * t)
    h, dh_du, d2h_du2 = 3 * u / (u + 2), 6 / (u + 2) ** 2, -12 / (u + 2) ** 3
    h_t, h_tt = dh_du * du, d2h_du2 * du**2 + dh_du * ddu
    g_tt = h_tt / (2 * np.sqrt(h)) - h_t**2 / (4 * h**1.5)
    return arm * g_tt * np.radians(1.0) ** 2


@pytest.mark.parametrize("theta5_deg", [30.0, 60.0, 90.0, -75.0])
def test_joint5_curvature_at_any_wrist_angle_matches_calculus(robot, theta5_deg):
    q = np.radians([0.0, -40.0, -30.0, 25.0, theta5_deg, 45.0])
    inf = influence.joint_influence(robot, q, joints=(4, 5))
    expected = _wrist_curvature_closed_form(robot, q)
    assert inf.curvature_per_deg2[1] == pytest.approx(expected, rel=1e-5)
    assert abs(inf.curvature_per_deg2[0]) < 1e-12  # joint 4 cannot act at the wrist centre
    assert inf.ranking == (5, 4)


def test_the_swept_curve_is_the_closed_form_wrist_factor(robot):
    q = np.radians([0.0, -40.0, -30.0, 25.0, 60.0, 45.0])
    curve = influence.joint_influence(robot, q, joints=(5,), samples=241).curves[0]
    np.testing.assert_allclose(np.degrees(curve.angles), np.linspace(-119.0, 119.0, 241), rtol=0, atol=1e-12)
    assert curve.at == q[4]
    # along joint 5 only the wrist factor changes: arm * sqrt(3 s^2 / (s^2 + 2)), s = sin(theta_5)
    kin = ArmKinematics(robot)
    wrist_in_flange = np.linalg.inv(kin.flange_pose(q)) @ kin.joint_poses(q)[4]
    j11 = kin.jacobian(q, tool_in_flange=wrist_in_flange)[:3, :3]
    arm = 3.0 / (np.linalg.norm(j11) * np.linalg.norm(np.linalg.inv(j11)))
    s2 = np.sin(curve.angles) ** 2
    np.testing.assert_allclose(curve.values, arm * np.sqrt(3 * s2 / (s2 + 2)), rtol=1e-11)


def test_paper_comparison_uses_table2(robot, optimum):
    inf = influence.joint_influence(robot, optimum.q)
    cmp = influence.compare_with_paper(inf)
    table2 = [1.4172e-4, -1.0774e-4, -3.6893e-5, -1.5070e-4]  # paper Table 2, joints 2..5 [1/deg^2]
    assert cmp["paper_curvature_per_deg2"] == table2 and cmp["paper_ranking"] == [5, 2, 3, 4]
    ratio = np.abs(inf.curvature_per_deg2) / np.abs(table2)
    np.testing.assert_allclose(cmp["ratio_to_paper"], ratio, rtol=1e-12)
    assert cmp["log10_ratio_rms"] == pytest.approx(np.sqrt(np.mean(np.log10(np.maximum(ratio, 1e-300)) ** 2)))


def test_bad_influence_requests_are_refused(robot, optimum):
    with pytest.raises(
        influence.UnknownNameError, match="unknown influence method 'spline'; valid names: fd, fourier"
    ):
        influence.joint_influence(robot, optimum.q, method="spline")
    with pytest.raises(influence.OutOfRangeError, match=r"joint = 7 is outside the valid range \[1, 6\]"):
        influence.joint_influence(robot, optimum.q, joints=(7,))
    with pytest.raises(
        influence.OutOfRangeError, match="fourier order = 8 needs >= 1 and at least 18 samples"
    ):
        influence.fourier_fit(np.arange(10.0), np.zeros(10))
