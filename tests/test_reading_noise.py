"""The F/T readings' noise in the model's prediction (vtestbed.researcher.reading_noise), against
Monte Carlo draws of the world's own sensor (vtestbed.world.sensors.ForceTorqueSensor)."""

import dataclasses

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed.experiment import simulate
from vtestbed.researcher.measure import load_measurements, wrench_at_block
from vtestbed.researcher.model_fit import Whitener
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.researcher.reading_noise import reading_covariance, with_reading_noise
from vtestbed.scenario import parse_scenario
from vtestbed.world.sensors import ForceTorqueSensor

DRAWS = 20_000


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, truth):
    """A small simulated dataset (2 identification tests, 1 validation test), its scenario,
    setup and measurements, and the true compliances."""
    scenario = parse_scenario(paper_scenario_data(2, 1, "reading", 3), "reading.toml")
    root = simulate(scenario, tmp_path_factory.mktemp("reading"))
    setup, measurements = load_measurements(root)
    return scenario, setup, measurements, 1.0 / np.asarray(truth.stiffness_true)


def _drawn_wrench_changes(scenario, setup, measurement, rng) -> np.ndarray:
    """(DRAWS, 6) wrench changes at the block, each from two readings of the world's sensor."""
    sensor = ForceTorqueSensor(scenario.lab.sensor, scenario.force_sensor.noise_std)
    unloaded, loaded = measurement.readings
    return np.array(
        [wrench_at_block(sensor.read(loaded, rng) - sensor.read(unloaded, rng), setup) for _ in range(DRAWS)]
    )


def test_simulate_writes_the_world_sensors_noise(dataset):
    scenario, setup, _, _ = dataset
    assert setup.sensor_noise_std == tuple(scenario.force_sensor.noise_std)
    # the default: the ATI SI-330-30's resolution, 1/16 N and about 1/528 N*m (sensors.DEFAULT_NOISE_STD)
    assert setup.sensor_noise_std == (0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019)


def test_the_covariance_is_the_sample_covariance_of_the_sensors_draws(dataset):
    scenario, setup, measurements, compliance = dataset
    ident = [m for m in measurements if m.group == "identification"]
    rng = np.random.default_rng(7)
    sampled = np.zeros((6, 6))
    for m in ident:
        g = m.jacobian @ np.diag(compliance) @ m.jacobian.T  # the paper's model: d = J C J^T w
        predicted = _drawn_wrench_changes(scenario, setup, m, rng) @ g.T
        sampled += np.cov(predicted, rowvar=False) / len(ident)
    closed = reading_covariance(ident, setup, compliance)
    # 20000 draws: a variance's relative error is about sqrt(2 / 20000) = 1 %
    np.testing.assert_allclose(np.diag(closed), np.diag(sampled), rtol=0.04)
    assert np.linalg.norm(closed - sampled) < 0.04 * np.linalg.norm(sampled)


def test_with_the_readings_the_chi2_of_the_true_model_has_its_mean(dataset):
    """Residuals of the true compliances from scans of covariance F and the sensor's readings:
    their chi^2 over the tests has mean 6 T against F + the mean reading covariance (the identity
    of reading_noise's docstring), and overshoots by the readings' share against F alone."""
    scenario, setup, measurements, compliance = dataset
    ident = [m for m in measurements if m.group == "identification"]
    reading = reading_covariance(ident, setup, compliance)
    scans = 0.5 * np.diag(np.diag(reading)) + 0.1 * reading  # the readings about 60 % of the sum
    big = 10**9  # samples: the floor as good as known, no inflation to divide out
    with_readings = Whitener(NoiseFloor(scans, big, 2, reading_covariance=reading))
    scans_only = Whitener(NoiseFloor(scans, big, 2))
    rng = np.random.default_rng(11)
    residuals = []
    for m in ident:
        g = m.jacobian @ np.diag(compliance) @ m.jacobian.T
        scan_noise = rng.multivariate_normal(np.zeros(6), scans, DRAWS)
        reading_noise = _drawn_wrench_changes(scenario, setup, m, rng) - m.wrench
        residuals.append(scan_noise - reading_noise @ g.T)  # measured - predicted
    stacked = np.stack(residuals, axis=1).reshape(DRAWS, -1)  # (draws, 6 T)
    chi2_with = np.sum(with_readings(stacked.T) ** 2, axis=0)
    chi2_without = np.sum(scans_only(stacked.T) ** 2, axis=0)
    dof = 6 * len(ident)
    # the mean of 20000 chi^2(12)-like draws: relative std 0.3 %
    assert np.mean(chi2_with) == pytest.approx(dof, rel=0.02)
    expected_without = sum(
        np.trace(np.linalg.solve(scans, scans + m_cov)) for m_cov in _per_test(ident, setup, compliance)
    )
    assert np.mean(chi2_without) == pytest.approx(expected_without, rel=0.02)
    assert expected_without > 1.5 * dof


def _per_test(ident, setup, compliance):
    return [reading_covariance([m], setup, compliance) for m in ident]


def test_the_floor_carries_it_and_the_whitener_uses_the_sum(dataset):
    _, setup, measurements, compliance = dataset
    scans = np.diag([2e-6, 2e-6, 2e-6, 3e-6, 3e-6, 3e-6]) ** 2
    floor = NoiseFloor(scans, 75, 25)
    added = with_reading_noise(floor, measurements, setup)
    ident = [m for m in measurements if m.group == "identification"]
    # at the fitted compliances, not the true ones: 2 tests determine them to a few %, so the
    # covariance's size in the floor's metric (quadratic in them) is within about 10 %
    share = lambda cov: np.trace(np.linalg.solve(scans, cov))  # noqa: E731
    assert share(added.reading_covariance) == pytest.approx(
        share(reading_covariance(ident, setup, compliance)), rel=0.1
    )
    np.testing.assert_array_equal(added.covariance, scans)  # the scans' estimate stays as it was
    white = Whitener(added)
    np.testing.assert_allclose(
        white.inv_chol @ (scans + added.reading_covariance) @ white.inv_chol.T,
        np.eye(6) / white.inflation,
        atol=1e-12,
    )
    assert added.as_dict()["reading_std"] == pytest.approx(
        np.sqrt(np.diag(added.reading_covariance)).tolist()
    )
    # not known (a dataset from before 2026-12-02, or a lab's without the field): nothing added
    assert with_reading_noise(floor, measurements, dataclasses.replace(setup, sensor_noise_std=None)) is floor
    assert "reading_std" not in floor.as_dict()
