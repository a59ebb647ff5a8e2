"""The force/torque sensor model: reading = true + bias + N(0, noise_std^2), range-checked."""

import numpy as np
import pytest

from vtestbed.errors import SensorOverloadError
from vtestbed.lab import ForceSensorSpec
from vtestbed.world.sensors import DEFAULT_NOISE_STD, ForceTorqueSensor

TRUE = np.array([120.0, -80.0, 300.0, 12.0, -7.5, 3.25])  # N, N*m, inside the SI-330-30's range
BIAS = (1.5, -0.8, 2.0, 0.05, -0.03, 0.02)
STD = (0.5, 0.25, 1.0, 0.01, 0.02, 0.004)


def test_default_noise_is_the_sensors_resolution():
    # ATI SI-330-30: 1/16 N and 1/528 N*m
    np.testing.assert_allclose(DEFAULT_NOISE_STD, [1 / 16] * 3 + [1 / 528] * 3, rtol=0.004)


def test_without_a_generator_the_reading_is_true_plus_bias():
    sensor = ForceTorqueSensor(noise_std=STD, bias=BIAS)
    np.testing.assert_allclose(sensor.read(TRUE, None), TRUE + np.array(BIAS), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(ForceTorqueSensor(noise_std=STD).read(TRUE, None), TRUE)


def test_mean_and_std_over_many_readings_are_bias_and_noise_std():
    sensor = ForceTorqueSensor(noise_std=STD, bias=BIAS)
    rng = np.random.default_rng(8)
    n = 10_000
    readings = np.array([sensor.read(TRUE, rng) for _ in range(n)])
    err = readings - TRUE
    # the sample mean has std sigma/sqrt(n); the sample std has relative std 1/sqrt(2(n-1))
    np.testing.assert_array_less(np.abs(err.mean(axis=0) - BIAS), 4.5 * np.array(STD) / np.sqrt(n))
    np.testing.assert_array_less(np.abs(err.std(axis=0, ddof=1) / STD - 1), 4.5 / np.sqrt(2 * (n - 1)))
    # the six axes are drawn independently
    corr = np.corrcoef(err.T)[np.triu_indices(6, 1)]
    assert np.abs(corr).max() < 4.5 / np.sqrt(n)


def test_a_true_wrench_outside_the_range_raises_naming_the_axis():
    sensor = ForceTorqueSensor()
    wrench = TRUE.copy()
    wrench[1] = -331.0
    with pytest.raises(
        SensorOverloadError,
        match=r"true wrench at the sensor: Fy = -331\.00 N is outside the measuring range \[-330, 330\] N",
    ):
        sensor.read(wrench, np.random.default_rng(0))


def test_a_bias_that_pushes_the_reading_out_of_range_raises_on_the_reading():
    sensor = ForceTorqueSensor(noise_std=(0.0,) * 6, bias=(0, 0, 0, 0, 0, 0.5))
    wrench = TRUE.copy()
    wrench[5] = 29.75  # in range; the bias takes the reading to 30.25 N*m
    with pytest.raises(
        SensorOverloadError,
        match=r"force sensor reading: Tz = 30\.25 N\*m is outside the measuring range \[-30, 30\] N\*m",
    ):
        sensor.read(wrench, None)
    narrow = ForceTorqueSensor(ForceSensorSpec(wrench_range=(200, 200, 100, 20, 20, 20)))
    with pytest.raises(SensorOverloadError, match=r"Fz = 300\.00 N .* \[-100, 100\] N"):
        narrow.read(TRUE, None)
