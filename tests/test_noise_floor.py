"""The model-free noise floor from repeat scans, checked against independent references."""

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import POSE_DEG, paper_scenario_data

from vtestbed import dataset, dataset_repeats
from vtestbed.campaigns.montecarlo import prepare
from vtestbed.dataset import DatasetSetup
from vtestbed.errors import OutOfRangeError, ScanError
from vtestbed.experiment import simulate
from vtestbed.ply import read_ply, write_ply
from vtestbed.researcher import cloud
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.noise_floor import NoiseFloor, noise_floor_from_frames, scan_deviations
from vtestbed.researcher.repeat_scans import estimate_noise_floor, scan_frames
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import displacement_in_block_frame, homogeneous, invert, matrix_from_rotation_vector
from vtestbed.world import physics
from vtestbed.world.physics import draw_readings
from vtestbed.world.repeats import draw_repeat_scans, repeat_rng
from vtestbed.world.scan_noise import ScanNoise

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
# per-point noise only: no drift, outliers or dropouts
POINT_NOISE = ScanNoise(range_std_m=10e-6, dropout_start_deg=90.0, dropout_full_deg=90.0,
                        outlier_fraction=0.0, drift_translation_std_m=0.0, drift_rotation_std_rad=0.0)  # fmt: skip


def small(n_tests=2, n_val=1, **scanner):
    return parse_scenario(paper_scenario_data(n_tests, n_val, "floor", 3, **scanner), "floor.toml")


def perturbed(pose: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``pose`` moved by ``xi`` = (translation [m], rotation vector [rad]) in its own axes."""
    return pose @ homogeneous(matrix_from_rotation_vector(xi[3:]), xi[:3])


def synthetic_scan_cov(rng) -> np.ndarray:
    """A per-scan frame covariance of realistic size (um, urad) with correlations."""
    a = rng.standard_normal((6, 6))
    m = a @ a.T + 3 * np.eye(6)
    corr = m / np.sqrt(np.outer(np.diag(m), np.diag(m)))
    std = np.array([3e-6, 3.5e-6, 4e-6, 6e-6, 5e-6, 7e-6])
    return corr * np.outer(std, std)


# ---------------------------------------------------------------------- the estimator's algebra
def test_all_pairs_are_the_pooled_within_test_covariance_of_the_scans():
    rng = np.random.default_rng(4)
    base = homogeneous(matrix_from_rotation_vector([0.3, -1.0, 0.5]), [0.2, -0.1, 0.6])
    chol = np.linalg.cholesky(synthetic_scan_cov(rng))
    frames = {
        f"T{n}": [perturbed(base, chol @ rng.standard_normal(6)) for _ in range(n)] for n in (1, 2, 3, 6, 21)
    }
    floor = noise_floor_from_frames(frames)
    # reference: twice the pooled within-test sample covariance (np.cov), tests weighted by n - 1
    pooled = sum((len(f) - 1) * np.cov(scan_deviations(f).T) for f in frames.values() if len(f) > 1)
    np.testing.assert_allclose(floor.covariance, 2 * pooled / (1 + 2 + 5 + 20), rtol=1e-10)
    assert (floor.n_samples, floor.n_tests, floor.test_ids) == (28, 4, ("T2", "T3", "T6", "T21"))
    # the same, to second order, from each pair's own displacement in the first scan's block frame
    direct, dof = np.zeros((6, 6)), 0
    for f in frames.values():
        pairs = [displacement_in_block_frame(f[j], f[k]) for j in range(len(f)) for k in range(j + 1, len(f))]
        direct += (2 / len(f)) * sum(np.outer(d, d) for d in pairs)
        dof += len(f) - 1
    np.testing.assert_allclose(floor.covariance, direct / dof, rtol=1e-4, atol=1e-18)


def test_floor_is_unbiased_for_the_displacement_noise_and_chi2_uses_it():
    rng = np.random.default_rng(5)
    scan_cov = synthetic_scan_cov(rng)
    chol = np.linalg.cholesky(scan_cov)
    base = homogeneous(matrix_from_rotation_vector([1.0, 0.2, -0.4]), [0.1, 0.3, 0.55])
    frames = {i: [perturbed(base, chol @ rng.standard_normal(6)) for _ in range(4)] for i in range(1000)}
    floor = noise_floor_from_frames(frames)
    assert floor.n_samples == 3000
    # a displacement is a difference of two scans: its covariance is twice a scan's
    truth = 2 * scan_cov
    # each std to 1/sqrt(2 * 3000) = 1.3 % (one sigma): 5 % is 3.9 sigma
    np.testing.assert_allclose(floor.component_std, np.sqrt(np.diag(truth)), rtol=0.05)
    true_corr = truth / np.sqrt(np.outer(np.diag(truth), np.diag(truth)))
    np.testing.assert_allclose(floor.correlation, true_corr, atol=0.07)  # 1/sqrt(3000) = 0.018
    # chi^2 of displacement residuals with exactly the true covariance: the explicit quadratic form
    residuals = rng.multivariate_normal(np.zeros(6), truth, size=2000)
    explicit = sum(r @ np.linalg.solve(floor.covariance, r) for r in residuals)
    assert floor.chi2(residuals.ravel()) == pytest.approx(explicit, rel=1e-9)
    # ... whose reduced value is 1 within sqrt(2 / 12000) = 1.3 % (+ the floor's own 1.3 % per std)
    assert floor.reduced_chi2(residuals, n_parameters=6) == pytest.approx(1.0, abs=0.08)
    with pytest.raises(OutOfRangeError, match="6 components per test"):
        floor.chi2(np.zeros(7))
    with pytest.raises(OutOfRangeError, match="leaves no degree of freedom"):
        floor.reduced_chi2(np.zeros(6), n_parameters=6)


def test_no_repeat_at_all_is_refused():
    with pytest.raises(OutOfRangeError, match="no test has a repeat scan"):
        noise_floor_from_frames({"T001": [np.eye(4)]})


# ---------------------------------------------------------------------- datasets
def test_perfect_scanner_gives_exactly_zero(tmp_path):
    root = simulate(small(noise=False, repeats=2), tmp_path)
    floor = estimate_noise_floor(root)
    assert np.array_equal(floor.covariance, np.zeros((6, 6)))
    assert (floor.n_samples, floor.n_tests) == (6, 3)
    np.testing.assert_array_equal(floor.correlation, np.eye(6))
    with pytest.raises(OutOfRangeError, match="the noise floor is singular"):
        floor.chi2(np.ones(12))


def test_dataset_floor_is_the_in_memory_reduction_of_the_world_draws(tmp_path):
    sc = small(repeats=3)
    root = simulate(sc, tmp_path)
    assert estimate_noise_floor(simulate(small(), tmp_path / "none")) is None
    floor = estimate_noise_floor(root)
    assert (floor.n_samples, floor.n_tests, floor.test_ids) == (9, 3, ("T001", "T002", "V001"))
    # the unloaded frames of load_measurements are reused: the same numbers, bit for bit
    _, measurements = load_measurements(root)
    reused = estimate_noise_floor(root, measurements)
    np.testing.assert_array_equal(reused.covariance, floor.covariance)
    # the same tests on prepared (cast-once) physics, drawn and reduced in memory
    prepared = prepare(sc, include_validation=True)
    noise = sc.scanner.noise_model
    frames = {}
    for t in prepared.tests:
        cloud0 = draw_readings(t.hits_unloaded, t.hits_loaded, t.wrench_unloaded, t.wrench_loaded, noise,
                               prepared.sensor, physics.test_rng(3, t.group, t.index))[0]  # fmt: skip
        repeats = draw_repeat_scans(t.hits_unloaded, noise, repeat_rng(3, t.group, t.index), 3)
        frames[t.test_id] = scan_frames(t.record(), cloud0, repeats, prepared.setup, prepared.kinematics)
    np.testing.assert_array_equal(noise_floor_from_frames(frames).covariance, floor.covariance)
    assert np.all(floor.component_std > 0)
    assert floor.summary().startswith("noise floor from repeat scans: std x y z ")
    # a repeat scan in which the block cannot be found (moved 0.3 m) names its test, number and file
    rep = dataset_repeats.read_repeats(root)[4]
    write_ply(rep.cloud, read_ply(rep.cloud) + [0.3, 0.0, 0.0])
    with pytest.raises(
        ScanError, match=rf"^test {rep.test_id}, repeat {rep.repeat} cloud {re.escape(str(rep.cloud))}: "
    ):
        estimate_noise_floor(root)


# ---------------------------------------------------------------------- against a Monte Carlo
def _point_noise_comparison(scene, robot, groups, repeats, pairs, seed):
    """Estimated std (``groups`` x ``repeats`` repeat scans through the noise-floor code) and an
    independent Monte Carlo std (``pairs`` pairs of scans through open3d's fit directly)."""
    rig, state, scanner, hits = scene
    hits = hits.take(slice(None, None, 4))  # a quarter of the points: faster fits, same pipeline
    lab = rig.lab
    setup = DatasetSetup(robot.name, "dh", lab.block_in_flange, lab.sensor_in_flange, lab.block.edge,
                         lab.sensor.name, lab.sensor.wrench_range)  # fmt: skip
    kin = ArmKinematics(robot, lab.block_in_flange)
    record = dataset.TestRecord("T001", "identification", np.array(POSE_DEG), np.zeros(6), np.zeros(6),
                        scanner.pose_world, Path(), Path())  # fmt: skip
    rng = np.random.default_rng(seed)
    frames = {}
    for g in range(groups):
        cloud0 = POINT_NOISE.apply(hits, rng)
        frames[g] = scan_frames(
            record, cloud0, draw_repeat_scans(hits, POINT_NOISE, rng, repeats), setup, kin
        )
    estimate = noise_floor_from_frames(frames).component_std
    true_pose = invert(scanner.pose_world) @ state.block_pose
    params = cloud.FitParams(edge_m=lab.block.edge)
    d = []
    for _ in range(pairs):
        f0 = cloud.fit_block_frame(POINT_NOISE.apply(hits, rng), true_pose, params).pose
        f1 = cloud.fit_block_frame(POINT_NOISE.apply(hits, rng), true_pose, params).pose
        d.append(displacement_in_block_frame(f0, f1))
    return estimate, np.std(d, axis=0, ddof=1)


def test_point_noise_floor_matches_an_independent_monte_carlo(scene, robot):
    # 10 x 7 = 70 degrees of freedom (a std to 8.5 %) against 80 pairs (7.9 %): the ratio of the
    # two stds scatters by 11.6 % per component, so 40 % is 3.4 sigma; their mean over the six
    # components (correlated) by about 7 %, so 20 %. A floor off by the factor 2 between one scan
    # and a displacement (std x 0.71 or x 1.41) fails.
    estimate, reference = _point_noise_comparison(scene, robot, groups=10, repeats=7, pairs=80, seed=8)
    ratio = estimate / reference
    print(f"\nper-point noise: floor std / Monte Carlo std = {np.round(ratio, 3)}")
    assert np.all(np.abs(ratio - 1) < 0.40), ratio
    assert abs(ratio.mean() - 1) < 0.15, ratio
    assert np.all(reference[:3] > 0.3e-6) and np.all(reference[3:] > 3e-6)  # a floor well above zero


@pytest.mark.slow
def test_point_noise_floor_matches_an_independent_monte_carlo_closely(scene, robot):
    # 40 x 9 = 360 degrees of freedom (3.7 %) against 400 pairs (3.5 %): ratio scatter 5.1 %
    estimate, reference = _point_noise_comparison(scene, robot, groups=40, repeats=9, pairs=400, seed=9)
    ratio = estimate / reference
    print(f"\nper-point noise: floor std / Monte Carlo std = {np.round(ratio, 3)}")
    assert np.all(np.abs(ratio - 1) < 0.20), ratio
    assert abs(ratio.mean() - 1) < 0.08, ratio


def test_noise_floor_record_helpers():
    cov = np.diag([4e-12, 9e-12, 1e-12, 1e-10, 0.0, 4e-10])
    cov[0, 1] = cov[1, 0] = 3e-12
    floor = NoiseFloor(cov, n_samples=50, n_tests=5)
    np.testing.assert_allclose(floor.component_std, [2e-6, 3e-6, 1e-6, 1e-5, 0.0, 2e-5])
    assert floor.correlation[0, 1] == pytest.approx(0.5) and floor.correlation[4, 4] == 1.0
    assert floor.correlation[4, 3] == 0.0
    assert floor.relative_std_uncertainty == pytest.approx(0.1)
    assert floor.as_dict()["n_samples"] == 50
    assert (
        "x y z 2.00 3.00 1.00 um, rx ry rz 10.00 0.00 20.00 urad (50 samples from 5 tests" in floor.summary()
    )


def test_a_scan_copied_as_a_repeat_is_refused_unless_every_scan_repeats_itself():
    """Two scans of a real block never give the same frame to the last bit; a copied file does, and
    enters the floor as an exact zero (a floor too small). A perfect scanner repeats itself in every
    test: that floor is zero, and allowed (test above)."""
    from vtestbed.errors import DatasetError
    from vtestbed.researcher.noise_floor import noise_floor_from_frames

    rng = np.random.default_rng(3)

    def frame():
        f = np.eye(4)
        f[:3, 3] = rng.normal(0.0, 5e-6, 3)
        return f

    a = frame()
    noisy = {"T001": [a, a.copy(), frame()], "T002": [frame(), frame()]}
    with pytest.raises(DatasetError, match=r"^ds/repeats.csv: test T001: its own scan and a repeat of the unloaded block give "
                       r"bitwise the same frame while the other scans differ \(1 such pair\)"):  # fmt: skip
        noise_floor_from_frames(noisy, "ds/repeats.csv")
    perfect = {"T001": [np.eye(4)] * 3, "T002": [np.eye(4)] * 2}
    assert not np.any(noise_floor_from_frames(perfect).covariance)
    noisy["T001"][1] = frame()  # a new scan: accepted, 3 samples
    assert noise_floor_from_frames(noisy).n_samples == 3
