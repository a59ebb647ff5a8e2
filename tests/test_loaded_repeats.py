"""Repeat scans of the loaded block (``[scanner] loaded_repeats``, ``loaded_repeats.csv``): both
ends of a displacement averaged. References: the closed form ``S (1 / m + 1 / m')`` on synthetic
frames, scipy's rotation mean for the averages, the campaign trial for the dataset path."""

import dataclasses
import shutil

import numpy as np
import pytest
from conftest import paper_scenario_data
from scan_mean_helpers import Reduced, perturbed, scipy_mean_frame

from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames, trial
from vtestbed.dataset_repeats import LOADED_REPEATS_FILE, REPEATS_FILE, read_repeats
from vtestbed.errors import DatasetError, OutOfRangeError, ScenarioError
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.noise_floor import noise_floor_from_frames
from vtestbed.researcher.repeat_scans import repeat_scan_frames
from vtestbed.researcher.scan_mean import against_scan_mean, load_with_floor, loaded_scan_frames
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import displacement_in_block_frame, homogeneous, matrix_from_rotation_vector


def test_both_ends_averaged_have_the_closed_form_noise():
    """2000 synthetic tests, 3 unloaded and 2 loaded scans each with iid scan noise S: the
    displacement's covariance is S (1/3 + 1/2), the floor (2 S from the unloaded pairs) scaled by
    (1/3 + 1/2) / 2."""
    rng = np.random.default_rng(5)
    base = homogeneous(matrix_from_rotation_vector([0.3, 0.8, -0.4]), [0.2, 0.1, 0.6])
    std = np.array([3e-6, 4e-6, 5e-6, 6e-6, 5e-6, 8e-6])
    xi = np.array([2e-4, -1e-4, 5e-5, -3e-4, 2e-4, 1e-4])
    unloaded, loaded, tests, errors = {}, {}, [], []
    for t in range(2000):
        u = [perturbed(base, std * rng.standard_normal(6)) for _ in range(3)]
        v = [perturbed(perturbed(base, xi), std * rng.standard_normal(6)) for _ in range(2)]
        unloaded[f"T{t}"], loaded[f"T{t}"] = u, v
        tests.append(Reduced(f"T{t}", u[0], v[0], displacement_in_block_frame(u[0], v[0])))
    floor = noise_floor_from_frames(unloaded)
    out, scaled = against_scan_mean(tests, unloaded, floor, loaded)
    errors = np.array([m.displacement - xi for m in out])
    assert (scaled.reference_scans, scaled.loaded_scans) == (3, 2)
    np.testing.assert_allclose(scaled.covariance, floor.covariance * (1 / 3 + 1 / 2) / 2, rtol=1e-15)
    # each std to about 1/sqrt(2 * 2000) = 1.6 %; 6 % is 3.8 sigma. Without the loaded end
    # averaged the std would be sqrt(1.333 / 0.833) = 1.26 x: far outside.
    np.testing.assert_allclose(errors.std(axis=0), std * np.sqrt(1 / 3 + 1 / 2), rtol=0.06)
    np.testing.assert_allclose(errors.std(axis=0), scaled.component_std, rtol=0.06)
    np.testing.assert_allclose(out[0].frame_loaded, scipy_mean_frame(loaded["T0"]), atol=1e-15)
    # the loaded end alone (no unloaded repeats in the mean) is measured from the test's own scan
    alone, half = against_scan_mean(tests[:5], {}, floor, loaded)
    assert (half.reference_scans, half.loaded_scans) == (1, 2)
    np.testing.assert_array_equal(alone[0].frame_unloaded, tests[0].frame_unloaded)
    with pytest.raises(OutOfRangeError, match="already for a mean of 3 unloaded and 2 loaded scans"):
        scaled.for_scan_mean(2)
    with pytest.raises(OutOfRangeError, match="loaded_scans = 0 must be an integer >= 1"):
        floor.for_scan_mean(2, 0)


@pytest.fixture(scope="module")
def loaded_dataset(tmp_path_factory):
    data = paper_scenario_data(3, 1, "loadedrep", 9, repeats=2, loaded_repeats=2)
    sc = parse_scenario(data, "loadedrep.toml")
    return sc, simulate(sc, tmp_path_factory.mktemp("loadedrep"))


def test_a_simulated_dataset_holds_the_loaded_repeats_and_the_workflow_averages_them(loaded_dataset):
    sc, root = loaded_dataset
    records = read_repeats(root, state="loaded")
    assert [(r.test_id, r.repeat) for r in records[:2]] == [("T001", 1), ("T001", 2)] and len(records) == 8
    assert records[0].cloud == root / "clouds" / "T001_loaded_repeat1.ply"
    assert len(read_repeats(root)) == 8  # the unloaded repeats are where they were
    _, single = load_measurements(root)
    unloaded, loaded = repeat_scan_frames(root, single), loaded_scan_frames(root, single)
    _, measurements, floor = load_with_floor(root)
    assert (floor.reference_scans, floor.loaded_scans) == (3, 3)
    np.testing.assert_allclose(floor.covariance, noise_floor_from_frames(unloaded).covariance / 3, rtol=1e-12)
    for m, s in zip(measurements, single):
        expected = displacement_in_block_frame(
            scipy_mean_frame(unloaded[s.test_id]), scipy_mean_frame(loaded[s.test_id])
        )
        np.testing.assert_allclose(m.displacement, expected, rtol=0, atol=1e-11)  # m, rad; noise ~1e-6
        assert np.abs(m.displacement - s.displacement).max() > 1e-8  # both ends moved
    # the campaign trial draws the same loaded repeats: it reproduces the dataset's identification
    data = paper_scenario_data(3, 1, "loadedrep", 9, repeats=2, loaded_repeats=2)
    data["identification"] = {"method": "ols", "reference": "mean"}
    res = trial(prepare(parse_scenario(data, "loadedrep.toml"), include_validation=False), sc.seed)
    _, _, from_files = identify_dataset(root, "ols", reference="mean")
    np.testing.assert_allclose(res.compliance, from_files.compliance, rtol=1e-10)


def test_ray_cast_loaded_repeats_have_the_scaled_floor_as_their_covariance():
    """40 trials of two paper tests with the full scan noise, 3 repeats at each end: whitened by
    the floor for 4 + 4 scans, the displacement errors against the noise-free pipeline have a mean
    square of 1 (480 samples: 1 +- 0.07 for iid Gaussian errors); with the unloaded end alone
    averaged the floor would say 2.5."""
    sc = parse_scenario(paper_scenario_data(2, 1, "loadedrep", 5), "loadedrep.toml")
    prepared = prepare(sc, include_validation=False)
    tests = prepared.identification_tests()
    truth = {m.test_id: m.displacement for m in measure_trial(prepared, 0, tests, noise=None)}
    noise = sc.scanner.noise_model
    unloaded, loaded, measurements = {}, {}, []
    for seed in range(40):
        ms = measure_trial(prepared, seed, tests)
        for tid, f in repeat_frames(prepared, seed, tests, ms, noise, 3).items():
            unloaded[f"{seed}:{tid}"] = f
        for tid, f in repeat_frames(prepared, seed, tests, ms, noise, 3, "loaded").items():
            loaded[f"{seed}:{tid}"] = f
        measurements += [dataclasses.replace(m, test_id=f"{seed}:{m.test_id}") for m in ms]
    averaged, floor = against_scan_mean(measurements, unloaded, noise_floor_from_frames(unloaded), loaded)
    errors = np.array([m.displacement - truth[m.test_id.split(":")[1]] for m in averaged])
    chol = np.linalg.cholesky(floor.covariance)
    mean_square = np.mean(np.linalg.solve(chol, errors.T) ** 2)
    print(f"mean square of the whitened errors {mean_square:.3f}")
    assert floor.loaded_scans == 4 and mean_square == pytest.approx(1.0, abs=0.2)


def test_bad_loaded_repeats_are_named(loaded_dataset, tmp_path):
    _, root = loaded_dataset
    with pytest.raises(ScenarioError, match=r"scanner\.loaded_repeats.*\[0, 20\]"):
        parse_scenario(paper_scenario_data(2, 1, "x", 1, loaded_repeats=21), "x.toml")
    d = tmp_path / "d"
    d.mkdir()
    for name in ("setup.json", "tests.csv"):
        (d / name).write_text((root / name).read_text())
    shutil.copytree(root / "clouds", d / "clouds")  # a symlink would lead outside the folder: refused
    (d / LOADED_REPEATS_FILE).write_text("test_id,repeat,cloud\nT001,1,clouds/T001_loaded.ply\n")
    with pytest.raises(
        DatasetError, match=r"is the test's own loaded scan .* another scan of the loaded block"
    ):
        read_repeats(d, state="loaded")
    (d / LOADED_REPEATS_FILE).write_text("test_id,repeat,cloud\nT009,1,clouds/T001_loaded_repeat1.ply\n")
    with pytest.raises(DatasetError, match=r"loaded_repeats\.csv line 2 .*'T009' is not a test of"):
        read_repeats(d, state="loaded")
    assert not (d / REPEATS_FILE).exists() and read_repeats(d) == []


def test_resume_redoes_only_the_missing_loaded_repeats(loaded_dataset, tmp_path):
    sc, ref = loaded_dataset
    names = ("tests.csv", REPEATS_FILE, LOADED_REPEATS_FILE)
    reference = {n: (ref / n).read_text() for n in names}
    simulate(sc, tmp_path)
    # killed after T003's first loaded repeat: its second missing, its tests.csv row missing
    tests = (tmp_path / "tests.csv").read_text().splitlines(keepends=True)
    (tmp_path / "tests.csv").write_text("".join(tests[:3]))
    reps = (tmp_path / LOADED_REPEATS_FILE).read_text().splitlines(keepends=True)
    (tmp_path / LOADED_REPEATS_FILE).write_text("".join(reps[:6]))
    (tmp_path / "clouds" / "V001_loaded_repeat1.ply").unlink()
    simulate(sc, tmp_path)
    assert {n: (tmp_path / n).read_text() for n in names} == reference
    for a, b in zip(read_repeats(tmp_path, state="loaded"), read_repeats(ref, state="loaded")):
        assert (a.test_id, a.repeat) == (b.test_id, b.repeat) and a.cloud.read_bytes() == b.cloud.read_bytes()


def test_a_discover_round_carries_the_loaded_repeats_as_a_fresh_simulation(loaded_dataset, tmp_path):
    """discover extends the dataset (``discovery._extend_dataset``: every file copied, clouds linked)
    and simulates the combined scenario there. With loaded repeats the result holds the same scans
    as a fresh simulation of the combined scenario: the first tests' from the copy, the added
    test's drawn anew (file order aside: the copy lists the validation test before it)."""
    from vtestbed.discovery import _extend_dataset

    _, root = loaded_dataset
    combined = parse_scenario(
        paper_scenario_data(4, 1, "loadedrep", 9, repeats=2, loaded_repeats=2), "c.toml"
    )
    extended = tmp_path / "extended"
    _extend_dataset(root, extended, combined)
    assert (extended / LOADED_REPEATS_FILE).read_text() == (root / LOADED_REPEATS_FILE).read_text()
    simulate(combined, extended)
    fresh = simulate(combined, tmp_path / "fresh")
    for name in ("tests.csv", REPEATS_FILE, LOADED_REPEATS_FILE):
        lines = [sorted((d / name).read_text().splitlines()) for d in (extended, fresh)]
        assert lines[0] == lines[1], name
    for state in ("unloaded", "loaded"):
        ext, new = read_repeats(extended, state=state), read_repeats(fresh, state=state)
        assert len(ext) == len(new) == 10  # 5 tests, 2 repeats each
        by_key = {(r.test_id, r.repeat): r.cloud for r in new}
        for r in ext:
            assert r.cloud.read_bytes() == by_key[r.test_id, r.repeat].read_bytes()
