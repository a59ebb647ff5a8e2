"""Displacements against the mean unloaded scan (researcher/scan_mean.py), checked against the
closed-form covariance ``S (1 + 1 / m)`` on synthetic frames and on the ray-cast scanner."""

import dataclasses

import numpy as np
import pytest
from conftest import paper_scenario_data
from scan_mean_helpers import Reduced, perturbed

from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames
from vtestbed.errors import DatasetError, OutOfRangeError
from vtestbed.experiment import simulate
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.noise_floor import noise_floor_from_frames
from vtestbed.researcher.repeat_scans import repeat_scan_frames
from vtestbed.researcher.scan_mean import against_scan_mean, common_scan_count, load_with_floor, mean_frame
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import displacement_in_block_frame, homogeneous, matrix_from_rotation_vector


def test_mean_frame_is_the_mean_deviation_and_the_floor_scales_by_the_closed_form():
    rng = np.random.default_rng(11)
    base = homogeneous(matrix_from_rotation_vector([0.4, -0.9, 0.2]), [0.15, -0.2, 0.7])
    # mean_frame: the frames' deviations from their mean sum to zero (to second order: 1e-11 of them)
    frames = [perturbed(base, rng.normal(0, [5e-6] * 3 + [8e-6] * 3)) for _ in range(5)]
    centre = mean_frame(frames)
    dev = np.array([displacement_in_block_frame(centre, f) for f in frames])
    assert np.abs(dev.mean(axis=0)).max() < 1e-15
    assert mean_frame(frames[:1]) == pytest.approx(frames[0], abs=1e-15)
    # 2000 tests x 4 unloaded scans, iid per-scan noise S, and one loaded scan moved by a known xi
    a = rng.standard_normal((6, 6))
    std = np.array([3e-6, 3.5e-6, 4e-6, 6e-6, 5e-6, 7e-6])
    corr = (m := a @ a.T + 3 * np.eye(6)) / np.sqrt(np.outer(np.diag(m), np.diag(m)))
    scan_cov = corr * np.outer(std, std)
    chol = np.linalg.cholesky(scan_cov)
    frames_by_test, errors_single, errors_mean, tests = {}, [], [], []
    for t in range(2000):
        xi = np.array([1e-4, -2e-4, 5e-5, 3e-4, 1e-4, -2e-4])
        scans = [perturbed(base, chol @ rng.standard_normal(6)) for _ in range(4)]
        loaded = perturbed(perturbed(base, xi), chol @ rng.standard_normal(6))
        frames_by_test[f"T{t}"] = scans
        tests.append(Reduced(f"T{t}", scans[0], loaded, np.zeros(6)))
        errors_single.append(displacement_in_block_frame(scans[0], loaded) - xi)
        errors_mean.append(displacement_in_block_frame(mean_frame(scans), loaded) - xi)
    floor = noise_floor_from_frames(frames_by_test)
    averaged = floor.for_scan_mean(4)
    np.testing.assert_allclose(averaged.covariance, floor.covariance * 0.625, rtol=1e-15)
    assert (averaged.reference_scans, averaged.n_samples) == (4, 6000)
    # each std to about 1/sqrt(2 * 2000) = 1.6 %; 6 % is 3.8 sigma. The single-scan floor is
    # sqrt(1.6) = 1.26 x the averaged displacements' std: far outside.
    for errors, ref in ((errors_mean, scan_cov * 1.25), (errors_single, 2 * scan_cov)):
        np.testing.assert_allclose(np.std(errors, axis=0), np.sqrt(np.diag(ref)), rtol=0.06)
    np.testing.assert_allclose(np.std(errors_mean, axis=0), averaged.component_std, rtol=0.06)
    # the mean of all four scans: against_scan_mean's displacements are exactly these
    ms = tests[:20]
    out, scaled = against_scan_mean(ms, frames_by_test, floor)
    assert scaled.reference_scans == 4
    for m_out, t in zip(out, tests):
        ref = displacement_in_block_frame(mean_frame(frames_by_test[t.test_id]), t.frame_loaded)
        np.testing.assert_allclose(m_out.displacement, ref, rtol=0, atol=1e-18)
    # one test without repeats: every test is measured as the paper does
    lone = {**frames_by_test, "T0": frames_by_test["T0"][:1]}
    assert common_scan_count(ms, lone) == 1
    same, unscaled = against_scan_mean(ms, lone, floor)
    assert unscaled is floor and all(a is b for a, b in zip(same, ms))
    with pytest.raises(OutOfRangeError, match="already for a mean of 4 unloaded and 1 loaded scans"):
        averaged.for_scan_mean(4)
    with pytest.raises(OutOfRangeError, match="must be an integer >= 1"):
        floor.for_scan_mean(0)


def test_ray_cast_scans_averaged_have_the_scaled_floor_as_their_covariance():
    """60 trials of two paper tests with the scenario's full scan noise (per-point, drift, outliers,
    dropouts): the averaged displacements' errors against the noise-free pipeline, whitened by
    the floor for a mean of 4 scans, have a mean square of 1 per component (720 samples: 1 +- 0.06
    for iid Gaussian errors); with the single-scan floor it would be 0.625."""
    sc = parse_scenario(paper_scenario_data(2, 1, "scanmean", 5), "scanmean.toml")
    prepared = prepare(sc, include_validation=False)
    tests = prepared.identification_tests()
    truth = {m.test_id: m.displacement for m in measure_trial(prepared, 0, tests, noise=None)}
    noise = sc.scanner.noise_model
    frames, measurements = {}, []
    for seed in range(60):
        ms = measure_trial(prepared, seed, tests)
        for tid, f in repeat_frames(prepared, seed, tests, ms, noise, 3).items():
            frames[f"{seed}:{tid}"] = f
        measurements += [dataclasses.replace(m, test_id=f"{seed}:{m.test_id}") for m in ms]
    floor = noise_floor_from_frames(frames)  # 360 repeat samples
    averaged, scaled = against_scan_mean(measurements, frames, floor)
    errors = np.array([m.displacement - truth[m.test_id.split(":")[1]] for m in averaged])
    chol = np.linalg.cholesky(scaled.covariance)
    mean_square = np.mean(np.linalg.solve(chol, errors.T) ** 2)
    single = np.array([m.displacement - truth[m.test_id.split(":")[1]] for m in measurements])
    single_square = np.mean(np.linalg.solve(chol, single.T) ** 2)
    print(f"mean square: averaged {mean_square:.3f}, single scan {single_square:.3f} (of the averaged floor)")
    assert mean_square == pytest.approx(1.0, abs=0.2)
    assert single_square / mean_square == pytest.approx(1.6, rel=0.2)  # the information gained, 1 / 0.625


def test_dataset_is_measured_against_its_mean_unloaded_scan(tmp_path):
    root = simulate(parse_scenario(paper_scenario_data(3, 1, "scanmean", 7, repeats=2), "s.toml"), tmp_path)
    setup, measurements, floor = load_with_floor(root)
    _, single = load_measurements(root)
    frames = repeat_scan_frames(root, single)
    assert floor.reference_scans == 3 and floor.n_samples == 8
    np.testing.assert_allclose(floor.covariance, noise_floor_from_frames(frames).covariance * (1 + 1 / 3) / 2)
    for m, s in zip(measurements, single):
        ref = displacement_in_block_frame(mean_frame(frames[s.test_id]), s.frame_loaded)
        np.testing.assert_array_equal(m.displacement, ref)
        assert np.abs(m.displacement - s.displacement).max() > 0  # the mean moved the reference
    none = simulate(parse_scenario(paper_scenario_data(3, 1, "plain", 7), "p.toml"), tmp_path / "none")
    with pytest.raises(DatasetError, match="no repeat scans"):
        load_with_floor(none)
