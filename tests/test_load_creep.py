"""Load creep (``load_creep``): the loaded block moves on between its scans, seen by loaded repeats.

References: the closed form (loaded repeat k's frame is the loaded scan's moved by
``k * rate * d``, d the test's elastic displacement) on a noise-free dataset; the clean world's
files (without loaded repeats the effect changes nothing); the campaign trial against the
dataset; the creep check's F test (researcher/loaded_scatter.py) on noisy datasets; what the
workflow does when the check fails (the loaded repeats left out: the test's own loaded scan).
"""

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed.campaigns.montecarlo import prepare, trial
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.scan_mean import against_scan_mean, load_with_floor, loaded_scan_frames
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import displacement_in_block_frame


def scenario(rate: float | None, name: str, n_tests: int = 3, n_val: int = 1, seed: int = 9, **scanner):
    data = paper_scenario_data(n_tests, n_val, name, seed, **scanner)
    if rate is not None:
        data["world"] = {"effects": [{"name": "load_creep", "rate_percent": rate}]}
    return parse_scenario(data, f"{name}.toml")


def test_loaded_repeats_see_the_block_moved_on_by_the_rate(tmp_path):
    """A perfect scanner: loaded repeat k is fitted at the loaded frame moved by k * 5 % of the
    test's displacement (to 1e-3 of that motion); the unloaded repeats do not move."""
    root = simulate(scenario(5.0, "creep", noise=False, repeats=1, loaded_repeats=2), tmp_path / "d")
    _, measurements = load_measurements(root)
    loaded = loaded_scan_frames(root, measurements)
    for m in measurements:
        frames = loaded[m.test_id]
        assert len(frames) == 3
        for k in (1, 2):
            moved = displacement_in_block_frame(frames[0], frames[k])
            expected = 0.05 * k * m.displacement
            assert np.abs(moved - expected).max() < 1e-3 * np.abs(expected).max() + 1e-12
    _, _, floor = load_with_floor(root)
    assert np.all(np.isinf(floor.loaded_scatter.ratio))  # a perfect scanner: only the creep scatters
    assert floor.loaded_scatter.moved(1e-9)


def test_without_loaded_repeats_a_creeping_world_writes_the_clean_dataset(tmp_path):
    clean = simulate(scenario(None, "creep0", repeats=2), tmp_path / "clean")
    crept = simulate(scenario(2.0, "creep0", repeats=2), tmp_path / "crept")
    for name in ("tests.csv", "repeats.csv"):
        assert (clean / name).read_text() == (crept / name).read_text()
    for path in sorted((clean / "clouds").iterdir()):
        assert path.read_bytes() == (crept / "clouds" / path.name).read_bytes(), path.name


def test_the_campaign_trial_draws_the_creep_as_the_dataset_does(tmp_path):
    sc = scenario(3.0, "creeptrial", repeats=2, loaded_repeats=2)
    root = simulate(sc, tmp_path / "d")
    data = paper_scenario_data(3, 1, "creeptrial", 9, repeats=2, loaded_repeats=2)
    data["world"] = {"effects": [{"name": "load_creep", "rate_percent": 3.0}]}
    data["identification"] = {"method": "ols", "reference": "mean"}
    res = trial(prepare(parse_scenario(data, "creeptrial.toml"), include_validation=False), sc.seed)
    _, _, from_files = identify_dataset(root, "ols", reference="mean")
    np.testing.assert_allclose(res.compliance, from_files.compliance, rtol=1e-10)


@pytest.mark.parametrize(("rate", "moved"), [(None, False), (10.0, True)])
def test_the_creep_check_sees_a_creeping_block(rate, moved, tmp_path):
    """6 tests with 3 repeat scans at each end and the scanner's noise: a creep of 10 % per scan
    is caught at 1 %, the clean world is not."""
    root = simulate(scenario(rate, "creepcheck", 6, 1, 4, repeats=3, loaded_repeats=3), tmp_path / "d")
    check = load_with_floor(root)[2].loaded_scatter
    assert check.moved(0.01) is moved, check.to_dict()


def test_a_failed_creep_check_measures_to_the_own_loaded_scan(tmp_path):
    """A perfect scanner and 5 % creep per scan, 2 loaded repeats: the mean of the loaded scans lies
    (0 + 1 + 2) / 3 * 5 % = 5 % of the deflection beyond the test's own loaded scan (closed form).
    The check fails, so the displacements are the own scan's (to 1e-12 m) and the floor is scaled
    for one loaded scan; averaged regardless (``creep_alpha=None``) they carry the 5 %."""
    from vtestbed.researcher.noise_floor import noise_floor_from_frames
    from vtestbed.researcher.repeat_scans import repeat_scan_frames

    root = simulate(scenario(5.0, "creepleft", noise=False, repeats=1, loaded_repeats=2), tmp_path / "d")
    _, own = load_measurements(root)
    _, measured, floor = load_with_floor(root)
    assert floor.loaded_scatter.left_out and (floor.reference_scans, floor.loaded_scans) == (2, 1)
    assert "loaded repeats left out" in floor.summary()  # what `identify --reference mean` prints
    for m, o in zip(measured, own, strict=True):
        np.testing.assert_allclose(m.displacement, o.displacement, rtol=0, atol=1e-12)
    unloaded, loaded = repeat_scan_frames(root, own), loaded_scan_frames(root, own)
    single = noise_floor_from_frames(unloaded)
    averaged, avg_floor = against_scan_mean(own, unloaded, single, loaded, creep_alpha=None)
    assert not avg_floor.loaded_scatter.left_out and avg_floor.loaded_scans == 3
    for m, o in zip(averaged, own, strict=True):
        excess = m.displacement - o.displacement
        np.testing.assert_allclose(
            excess, 0.05 * o.displacement, rtol=0, atol=2e-3 * np.abs(o.displacement).max()
        )


def test_the_diagnosis_says_the_loaded_repeats_were_left_out(tmp_path):
    """With the scanner's noise, 10 % creep per scan on 6 tests: report.json records the check with
    ``left_out`` and one loaded scan per displacement; report.md says why in words. The check runs
    at the diagnosis's alpha."""
    import json

    from vtestbed import cli

    root = simulate(scenario(10.0, "creepreport", 6, 1, 4, repeats=3, loaded_repeats=3), tmp_path / "d")
    out = tmp_path / "diag"
    assert cli.main(["diagnose", str(root), "--candidates", "none", "--out", str(out)]) == 0
    floor = json.loads((out / "report.json").read_text())["noise_floor"]
    assert floor["loaded_scatter"]["left_out"] and floor["loaded_scatter"]["p_value"] < 0.01
    assert (floor["reference_scans"], floor["loaded_scans"]) == (4, 1)
    assert "the loaded repeats are left out" in (out / "report.md").read_text()
    # the check runs at diagnose's own alpha: at 1e-30 (its p is about 3e-25 here) they are kept
    from vtestbed.researcher.discrepancy import diagnose

    kept = diagnose(root, alpha=1e-30, names=())["noise_floor"]
    assert not kept["loaded_scatter"]["left_out"] and kept["loaded_scatter"]["p_value"] > 1e-30
    assert (kept["reference_scans"], kept["loaded_scans"]) == (4, 4)
