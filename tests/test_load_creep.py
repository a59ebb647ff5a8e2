"""Load creep (``load_creep``): the loaded block moves on between its scans, seen by loaded repeats.

References: the closed form (loaded repeat k's frame is the loaded scan's moved by
``k * rate * d``, d the test's elastic displacement) on a noise-free dataset; the clean world's
files (without loaded repeats the effect changes nothing); the campaign trial against the
dataset; the creep check's F test (researcher/loaded_scatter.py) on noisy datasets.
"""

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed.campaigns.montecarlo import prepare, trial
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.scan_mean import load_with_floor, loaded_scan_frames
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
