"""Estimates against the truth: relative errors, the paper's Table 5 columns and layout, and the
truth file of a simulated dataset."""

import json
import re

import numpy as np
import pytest

from vtestbed.comparison import PAPER_FIRST_N, compare, error_ranges, read_truth, table5, true_stiffness
from vtestbed.errors import DatasetError
from vtestbed.researcher.identify import IdentificationResult

# Gao et al. 2023, Table 5 [N*mm/rad], typed from the paper.
TABLE5_NMM = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7])
K_TRUE = TABLE5_NMM / 1000.0  # N*m/rad
NAMES = tuple(f"joint{i + 1}" for i in range(6))


def _result(stiffness, std) -> IdentificationResult:
    c = 1.0 / np.asarray(stiffness)
    return IdentificationResult(
        joint_names=NAMES, method="fgls", n_tests=20, compliance=c, compliance_cov=np.diag((std * c**2) ** 2),
        stiffness=np.asarray(stiffness), stiffness_std=np.asarray(std), residuals=np.zeros(120),
        component_std=np.zeros(6), condition_number=10.0, chi2_reduced=1.0,
    )  # fmt: skip


@pytest.fixture
def estimate():
    rng = np.random.default_rng(3)
    k_est = K_TRUE * (1 + rng.normal(0, 0.02, 6))
    return k_est, 0.01 * k_est


def test_compare_gives_the_relative_error_of_each_joint(estimate):
    k_est, k_std = estimate
    rows = compare(_result(k_est, k_std), {"stiffness_true_Nm_per_rad": K_TRUE.tolist()})
    assert [r["name"] for r in rows] == list(NAMES)
    for j, row in enumerate(rows):
        assert row["k_true"] == K_TRUE[j] and row["k_est"] == k_est[j] and row["k_std"] == k_std[j]
        assert row["rel_err"] == pytest.approx(k_est[j] / K_TRUE[j] - 1.0, rel=1e-12, abs=1e-16)
        assert row["rel_err"] == pytest.approx((k_est[j] - K_TRUE[j]) / K_TRUE[j], rel=1e-9)


def test_error_ranges_are_min_max_mean_from_the_sixth_estimate_on():
    rng = np.random.default_rng(4)
    est = K_TRUE * (1 + rng.normal(0, 0.05, (12, 6)))
    ranges = error_ranges({"n": list(range(1, 13)), "stiffness": est.tolist()}, K_TRUE)
    assert PAPER_FIRST_N == 6  # the paper's Table 5: n = 6..20
    rel = est[5:] / K_TRUE - 1.0  # rows n = 6..12, by hand
    np.testing.assert_allclose(ranges["min"], np.min(rel, axis=0), rtol=1e-15)
    np.testing.assert_allclose(ranges["max"], np.max(rel, axis=0), rtol=1e-15)
    np.testing.assert_allclose(ranges["mean"], np.sum(rel, axis=0) / 7, rtol=1e-13)
    # n outside 1..N order does not matter: the rows are picked by their n
    shuffled = error_ranges({"n": list(range(12, 0, -1)), "stiffness": est[::-1].tolist()}, K_TRUE)
    np.testing.assert_allclose(shuffled["min"], ranges["min"], rtol=1e-15)
    # fewer tests than first_n: the last estimate alone
    few = error_ranges({"n": [1, 2, 3], "stiffness": est[:3].tolist()}, K_TRUE)
    np.testing.assert_allclose(few["mean"], est[2] / K_TRUE - 1, rtol=1e-15)
    np.testing.assert_allclose(few["min"], few["max"], rtol=0)


def test_table5_prints_the_truth_in_n_mm_per_rad_and_errors_in_percent(estimate):
    k_est, k_std = estimate
    joints = compare(_result(k_est, k_std), {"stiffness_true_Nm_per_rad": K_TRUE.tolist()})
    ranges = {"min": [-0.01] * 6, "max": [0.0234] * 6, "mean": [0.005] * 6}
    text = table5(joints, ranges, n_tests=20)
    lines = text.splitlines()
    assert len(lines) == 7 and "n=6..20" in lines[0]
    for j, line in enumerate(lines[1:]):
        cells = line.split()
        assert cells[0] == NAMES[j]
        assert float(cells[1]) == pytest.approx(TABLE5_NMM[j], rel=1e-12)  # the paper's printed value
        assert float(cells[2]) == pytest.approx(k_est[j] * 1e3, rel=5e-5)  # 5 significant digits
        assert float(cells[4]) == pytest.approx((k_est[j] / K_TRUE[j] - 1) * 100, abs=5e-4)
        assert re.search(r"-1\.00 ~ 2\.34\s+0\.500$", line), line


def test_truth_file_is_optional_and_checked(tmp_path):
    assert read_truth(tmp_path) is None  # a lab's dataset: no comparison
    (tmp_path / "truth.json").write_text(json.dumps({"stiffness_true_Nm_per_rad": K_TRUE.tolist()}))
    np.testing.assert_array_equal(true_stiffness(read_truth(tmp_path), 6), K_TRUE)
    (tmp_path / "truth.json").write_text("[1, 2]")
    with pytest.raises(DatasetError, match=r"truth\.json: the truth file must hold a JSON dict, got list"):
        read_truth(tmp_path)


@pytest.mark.parametrize(
    "values",
    [None, K_TRUE[:5].tolist(), [*K_TRUE[:5], -1.0], [*K_TRUE[:5], float("nan")], "stiff", [[1.0] * 6],
     [1e-300] * 6, (K_TRUE * 1e3).tolist()],  # a denormal-size number, N*mm/rad for N*m/rad
)  # fmt: skip
def test_a_bad_true_stiffness_names_the_field_its_size_and_range(values):
    with pytest.raises(DatasetError) as exc:
        true_stiffness({"stiffness_true_Nm_per_rad": values}, 6)
    assert str(exc.value) == (
        "truth.json: stiffness_true_Nm_per_rad must be 6 numbers (one per joint), each in [10, 1e+09] "
        f"N*m/rad, got {values!r}"
    )


@pytest.mark.parametrize(
    "truth, message",
    [
        ({"joint_names": [f"joint{i}" for i in range(1, 7)], "stiffness_true_Nm_per_rad": K_TRUE[:5].tolist()},
         "{path}: stiffness_true_Nm_per_rad must be 6 numbers (one per joint), each in [10, 1e+09] N*m/rad, got "
         "[2197700.0, 899390.0, 1111800.0, 64449.0, 25362.0]"),
        ({"joint_names": ["joint1", "joint2"], "tests": {}},
         "{path}: key 'stiffness_true_Nm_per_rad' is missing; it must hold 2 numbers (one per joint), each in "
         "[10, 1e+09] N*m/rad"),
        ({"tests": {}},
         "{path}: key 'stiffness_true_Nm_per_rad' is missing; it must hold numbers (one per joint), each in "
         "[10, 1e+09] N*m/rad"),
        ({"stiffness_true_Nm_per_rad": [1e-300] * 6}, "{path}: stiffness_true_Nm_per_rad must be 6 numbers (one per "
         "joint), each in [10, 1e+09] N*m/rad, got [1e-300, 1e-300, 1e-300, 1e-300, 1e-300, 1e-300]"),
    ],
)  # fmt: skip
def test_a_bad_truth_file_is_named_with_its_folder(tmp_path, truth, message):
    (tmp_path / "truth.json").write_text(json.dumps(truth))
    with pytest.raises(DatasetError) as exc:
        read_truth(tmp_path)
    assert str(exc.value) == message.format(path=tmp_path / "truth.json")
