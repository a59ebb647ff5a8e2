"""What a correct model reaches on the validation tests: ``sqrt(1 + mean leverage)``.

References: a Monte Carlo of ordinary least squares in numpy (the closed form's mean square
prediction error), the same design with a duplicated column (rank deficiency changes nothing),
and a Monte Carlo of the researcher's own fit (``fit_model`` + ``validation_gap``) on the paper's
poses with a known Gaussian noise floor.
"""

from pathlib import Path

import numpy as np
import pytest

from vtestbed.experiment import dataset_setup
from vtestbed.researcher.candidates import ModelContext
from vtestbed.researcher.diagnose import Whitener, expected_validation_ratio, fit_model, validation_gap
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import TestMeasurement
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SIGMA = np.array([5.3e-6, 5.3e-6, 5.3e-6, 8.5e-6, 8.5e-6, 8.5e-6])  # m, rad: the scanner's floor


def test_closed_form_matches_least_squares_monte_carlo():
    rng = np.random.default_rng(11)
    x_id, x_val = rng.normal(size=(60, 8)), 2.0 * rng.normal(size=(30, 8))  # validation far out
    expected = expected_validation_ratio(x_id, x_val)
    assert expected > 1.1  # the leverage matters here, so the check below can tell it from 1
    beta = rng.normal(size=8)
    draws = 4000
    y_id = x_id @ beta + rng.normal(size=(draws, 60))
    y_val = x_val @ beta + rng.normal(size=(draws, 30))
    beta_hat = np.linalg.lstsq(x_id, y_id.T, rcond=None)[0]  # (8, draws)
    mean_square = np.mean((y_val.T - x_val @ beta_hat) ** 2)
    assert np.sqrt(mean_square) == pytest.approx(expected, rel=0.02)


def test_a_duplicated_column_changes_nothing():
    rng = np.random.default_rng(12)
    x_id, x_val = rng.normal(size=(40, 5)), rng.normal(size=(12, 5))
    dup_id, dup_val = np.hstack([x_id, x_id[:, :1]]), np.hstack([x_val, x_val[:, :1]])
    assert expected_validation_ratio(dup_id, dup_val) == pytest.approx(
        expected_validation_ratio(x_id, x_val), rel=1e-9
    )


def test_validation_gap_expectation_matches_a_monte_carlo_of_the_fit():
    """The baseline fit on the paper's poses (8 identification tests; 5 validation tests with
    twice the load, so the estimation error shows), a correct model and a known floor: the mean
    squared validation ratio over 600 noise draws is the expected ratio squared."""
    scenario = load_scenario(ROOT / "scenarios" / "kr60_paper.toml")
    setup = dataset_setup(scenario, scenario.lab)
    kin = ArmKinematics.for_setup(setup, scenario.robot)
    rng = np.random.default_rng(13)
    compliance = 1.0 / np.array([5.0e6, 4.0e6, 3.0e6, 6.0e5, 5.0e5, 3.0e5])
    poses = [*scenario.poses[:8], *scenario.poses[15:20]]
    jacobians = [kin.jacobian(q, setup.block_in_flange, frame="tool") for q in poses]
    scale = [1.0] * 8 + [2.0] * 5
    wrenches = [f * np.concatenate([rng.normal(0, 120, 3), rng.normal(0, 40, 3)]) for f in scale]
    eye = np.eye(4)

    def draw(noise_rng):
        return [
            TestMeasurement(f"T{i + 1:03d}", "identification" if i < 8 else "validation", np.asarray(q),
                            w, j @ (compliance * (j.T @ w)) + noise_rng.normal(0, SIGMA), j, eye, eye)
            for i, (q, j, w) in enumerate(zip(poses, jacobians, wrenches))
        ]  # fmt: skip

    # a floor known to high precision: the whitener's inflation nu / (nu - 7) is 1 to 1e-6
    white = Whitener(NoiseFloor(np.diag(SIGMA**2), 10_000_000, 13, ()))
    squares, expected = [], set()
    for _ in range(600):
        ms = draw(rng)
        ident = ModelContext([m for m in ms if m.group == "identification"], setup, kin)
        valid = ModelContext([m for m in ms if m.group == "validation"], setup, kin)
        gap = validation_gap(valid, white, fit_model(ident, white, []), [])
        squares.append(gap["ratio_to_floor"] ** 2)
        expected.add(round(gap["expected_ratio"], 12))  # the design, not the noise, sets it
    assert len(expected) == 1
    (ratio,) = expected
    assert ratio > 1.15  # 6 compliances from 8 tests, twice the load: well above the floor
    # the standard error of the root mean square is about 0.6 %
    assert np.sqrt(np.mean(squares)) == pytest.approx(ratio, rel=0.025)
