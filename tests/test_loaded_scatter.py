"""The loaded repeats' creep check (vtestbed.researcher.loaded_scatter).

References: numpy's pooled within-test variances of the known frame perturbations (the ratio);
the F distribution's level, by Monte Carlo under the hypothesis (same noise at both ends); a creep
ramp of known size (the power); a simulated dataset with loaded repeats (the wiring into
``load_with_floor`` and the diagnosis report).
"""

import numpy as np
import pytest
from test_loaded_repeats import loaded_dataset  # noqa: F401  (the module's fixture)

from vtestbed.researcher.loaded_scatter import LoadedScatter, loaded_scatter
from vtestbed.researcher.scan_mean import load_with_floor
from vtestbed.transforms import homogeneous, matrix_from_rotation_vector

SIGMA = np.array([3.0e-6, 3.0e-6, 3.0e-6, 5.0e-6, 5.0e-6, 5.0e-6])  # m, rad: one scan's frame noise
BASE = homogeneous(matrix_from_rotation_vector(np.array([0.3, -0.2, 1.1])), np.array([0.4, 0.1, 0.9]))


def frames(perturbations: np.ndarray) -> list[np.ndarray]:
    """Frames moved from BASE by each (6,) perturbation, in the block's own axes."""
    return [BASE @ homogeneous(matrix_from_rotation_vector(p[3:]), p[:3]) for p in perturbations]


def draw(rng, n_tests: int, scans: int, scale=1.0, ramp=0.0):
    """Per test, ``scans`` perturbations: noise (SIGMA * scale) plus ``ramp`` (6,) times the scan index."""
    return {
        f"T{t:03d}": rng.normal(0.0, SIGMA * scale, (scans, 6)) + np.arange(scans)[:, None] * ramp
        for t in range(n_tests)
    }


def pooled_variance(perturbations: dict) -> np.ndarray:
    """(6,) within-test variance pooled over the tests (numpy, from the perturbations themselves)."""
    dev = [p - p.mean(axis=0) for p in perturbations.values()]
    dof = sum(len(p) - 1 for p in perturbations.values())
    return sum(np.sum(d**2, axis=0) for d in dev) / dof


def test_the_ratio_is_the_pooled_variance_ratio_of_the_perturbations():
    rng = np.random.default_rng(21)
    unloaded, loaded = draw(rng, 20, 4), draw(rng, 20, 3, scale=np.array([1, 1, 2, 1, 1, 1.0]))
    check = loaded_scatter(
        {k: frames(v) for k, v in unloaded.items()}, {k: frames(v) for k, v in loaded.items()}
    )
    expected = pooled_variance(loaded) / pooled_variance(unloaded)
    np.testing.assert_allclose(check.ratio, expected, rtol=1e-4)  # the frames' algebra is linear to ~1e-5
    assert (check.dof_loaded, check.dof_unloaded) == (40, 60)
    assert check.moved(0.01) and "most in z" in check.sentence(0.01)  # z's variance is 4 times the floor's
    back = LoadedScatter.from_dict(check.to_dict())  # as a report.json carries it
    assert np.array_equal(back.ratio, check.ratio) and back.p_value == check.p_value
    assert (back.dof_loaded, back.dof_unloaded) == (check.dof_loaded, check.dof_unloaded)


def test_same_noise_rejects_at_most_the_stated_level():
    """600 datasets (10 tests, 3 scans at each end) under the hypothesis: the one-sided Bonferroni
    test over 6 components rejects at most alpha (the independent components: 1 - (1 - alpha/6)^6,
    4.9 % at alpha = 5 %); a binomial 99 % band around it is 2.7-7.4 %."""
    rng = np.random.default_rng(22)
    p_values = []
    for _ in range(600):
        unloaded, loaded = draw(rng, 10, 3), draw(rng, 10, 3)
        check = loaded_scatter(
            {k: frames(v) for k, v in unloaded.items()}, {k: frames(v) for k, v in loaded.items()}
        )
        p_values.append(check.p_value)
    p_values = np.array(p_values)
    assert 0.027 <= np.mean(p_values < 0.05) <= 0.074
    assert 0.3 < np.median(p_values) <= 1.0  # not piled up at small values


def test_a_creeping_block_is_caught_and_named():
    """The loaded block drifts 2 sigma in y per scan (creep under the wire): caught, y named."""
    rng = np.random.default_rng(23)
    ramp = np.array([0.0, 2.0 * SIGMA[1], 0.0, 0.0, 0.0, 0.0])
    unloaded, loaded = draw(rng, 10, 4), draw(rng, 10, 4, ramp=ramp)
    check = loaded_scatter(
        {k: frames(v) for k, v in unloaded.items()}, {k: frames(v) for k, v in loaded.items()}
    )
    assert check.p_value < 1e-6 and int(np.argmax(check.ratio)) == 1
    assert "moved between its scans" in check.sentence(0.01) and "most in y" in check.sentence(0.01)
    # one side without repeats: nothing to compare
    single = {k: frames(v[:1]) for k, v in loaded.items()}
    assert loaded_scatter({k: frames(v) for k, v in unloaded.items()}, single) is None
    assert loaded_scatter(None, {k: frames(v) for k, v in loaded.items()}) is None


def test_a_simulated_dataset_carries_the_check_to_its_floor(loaded_dataset):  # noqa: F811
    """No creep in the truth world: the check passes, its ratios those of the two floors."""
    from vtestbed.researcher.measure import load_measurements
    from vtestbed.researcher.noise_floor import noise_floor_from_frames
    from vtestbed.researcher.repeat_scans import repeat_scan_frames
    from vtestbed.researcher.scan_mean import loaded_scan_frames

    _, root = loaded_dataset
    _, measurements, floor = load_with_floor(root)
    check = floor.loaded_scatter
    assert (check.dof_loaded, check.dof_unloaded) == (8, 8) and not check.moved(0.01)
    _, single = load_measurements(root)
    unloaded = noise_floor_from_frames(repeat_scan_frames(root, single)).covariance
    loaded = noise_floor_from_frames(loaded_scan_frames(root, single)).covariance
    np.testing.assert_allclose(check.ratio, np.diag(loaded) / np.diag(unloaded), rtol=1e-12)


def test_the_diagnosis_reports_the_check(loaded_dataset, tmp_path):  # noqa: F811
    """report.json carries it; report.md and report.html say it in words."""
    import json

    from vtestbed import cli

    _, root = loaded_dataset
    out = tmp_path / "d"
    assert cli.main(["diagnose", str(root), "--candidates", "none", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    expected = load_with_floor(root)[2].loaded_scatter.to_dict()
    carried = report["noise_floor"]["loaded_scatter"]
    assert carried["ratio"] == pytest.approx(expected["ratio"], rel=1e-12)
    assert [carried[k] for k in ("dof_loaded", "dof_unloaded")] == [
        expected[k] for k in ("dof_loaded", "dof_unloaded")
    ]
    assert carried["p_value"] == pytest.approx(expected["p_value"], rel=1e-9)
    sentence = LoadedScatter.from_dict(expected).sentence(report["alpha"])
    assert "no sign that the loaded block moved" in sentence
    assert sentence in (out / "report.md").read_text()
    assert "no sign that the loaded block moved between its scans" in (out / "report.html").read_text()
