"""The researcher's report: convergence rows against identifications on the first n tests and the
paper's Table 5, validation errors against the norm ratio by hand, and the figures' sizes."""

import struct
import warnings

import numpy as np
import pytest

from vtestbed.researcher.identify import identify
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import TestMeasurement as Measurement  # not a test class
from vtestbed.researcher.report import convergence, plot_convergence, plot_validation, validation

# Gao et al. 2023, Table 5 [N*mm/rad], typed from the paper.
K_TABLE5 = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7]) / 1000.0  # N*m/rad
SIGMA = np.array([3e-6, 3e-6, 3e-6, 5e-6, 5e-6, 5e-6])  # m, rad


def _measurements(robot, lab, count, group="identification", noise=True, seed=0):
    """d = J K^-1 J^T F at Table 5 (+ noise), Jacobians from Pinocchio at scattered poses."""
    kin = ArmKinematics(robot, lab.block_in_flange)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        q = np.radians([0, -60, -20, 30, 50, 45]) + rng.uniform(-0.5, 0.5, 6)
        jac = kin.jacobian(q, frame="tool")
        wrench = np.r_[rng.normal(0, 120, 3), rng.normal(0, 8, 3)]
        d = jac @ ((jac.T @ wrench) / K_TABLE5) + (rng.normal(size=6) * SIGMA if noise else 0.0)
        out.append(Measurement(f"{group[0].upper()}{i:03d}", group, q, wrench, d, jac, np.eye(4), np.eye(4)))
    return out


def _identify(tests, method):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(
            np.array([m.jacobian for m in tests]), np.array([m.wrench for m in tests]),
            np.array([m.displacement for m in tests]), method=method,
        )  # fmt: skip


@pytest.mark.parametrize("method", ["fgls", "ols"])
def test_convergence_row_n_is_the_identification_on_the_first_n_tests(robot, lab, method):
    tests = _measurements(robot, lab, 10)
    val = _measurements(robot, lab, 3, "validation", seed=1)
    conv = convergence(tests[:4] + val + tests[4:], method, robot.joint_names)  # validation rows ignored
    assert conv["n"] == list(range(1, 11))
    for n in (2, 7, 10):
        res = _identify(tests[:n], method)
        np.testing.assert_allclose(conv["stiffness"][n - 1], res.stiffness, rtol=1e-12)
        np.testing.assert_allclose(conv["stiffness_std"][n - 1], res.stiffness_std, rtol=1e-12)
    # and the last row is the paper's stiffness to the noise's few per cent
    np.testing.assert_allclose(conv["stiffness"][-1], K_TABLE5, rtol=0.1)


def test_convergence_without_identification_tests_is_empty(robot, lab):
    val = _measurements(robot, lab, 3, "validation")
    assert convergence(val, "fgls", robot.joint_names) == {"n": [], "stiffness": [], "stiffness_std": []}


def test_noise_free_convergence_is_table5_from_the_first_test(robot, lab):
    conv = convergence(_measurements(robot, lab, 5, noise=False), "fgls", robot.joint_names)
    for row in conv["stiffness"]:
        np.testing.assert_allclose(row, K_TABLE5, rtol=1e-9)
    assert np.all(np.isnan(conv["stiffness_std"][0]))  # one test: 6 equations, 6 unknowns, no residual


def test_validation_errors_are_the_norm_ratios_by_hand(robot, lab):
    val = _measurements(robot, lab, 4, "validation", seed=2)
    k = K_TABLE5 * np.array([1.05, 0.97, 1.0, 1.1, 0.9, 1.02])  # an identified model, a few % off
    rows = validation(_measurements(robot, lab, 2) + val, k)
    assert [r["test_id"] for r in rows] == ["V000", "V001", "V002", "V003"]
    for m, row in zip(val, rows):
        pred = m.jacobian @ np.diag(1 / k) @ m.jacobian.T @ m.wrench
        np.testing.assert_allclose(row["predicted"], pred, rtol=1e-12)
        assert row["measured"] == m.displacement.tolist()
        for part, key in ((slice(0, 3), "rel_err_translation"), (slice(3, 6), "rel_err_rotation")):
            diff, meas = pred[part] - m.displacement[part], m.displacement[part]
            assert row[key] == pytest.approx(np.sqrt(diff @ diff / (meas @ meas)), rel=1e-12)
        assert 0.0 < row["rel_err_translation"] < 0.5


def _png_size(path) -> tuple[int, int]:
    """Width and height from the PNG header (IHDR), read by hand."""
    raw = path.read_bytes()[:24]
    assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR"
    return struct.unpack(">II", raw[16:24])


def test_figures_have_the_set_size(robot, lab, tmp_path):
    tests = _measurements(robot, lab, 8)
    conv = convergence(tests, "fgls", robot.joint_names)
    path = plot_convergence(conv, robot.joint_names, tmp_path / "conv.png", reference=K_TABLE5)
    assert _png_size(path) == (12 * 110, round(6.5 * 110))  # figsize [in] x 110 dpi
    assert _png_size(plot_convergence(conv, robot.joint_names, tmp_path / "c2.png")) == (1320, 715)
    rows = validation(_measurements(robot, lab, 3, "validation", seed=3), K_TABLE5)
    assert _png_size(plot_validation(rows, tmp_path / "val.png")) == (12 * 110, round(4.5 * 110))
