"""``gls_floor``: GLS weighted with the repeat-scan noise floor, on datasets and in campaigns.

References: a dense GLS written out with numpy (block-diagonal Sigma^-1 over the tests, the normal
equations solved directly), the noise floor estimated from the dataset's own repeat scans, and
the campaign path (cast-once physics, noise drawn in memory) against the files ``simulate`` wrote.
"""

import importlib
from pathlib import Path

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed.campaigns import montecarlo
from vtestbed.campaigns.spec import parse_campaign
from vtestbed.errors import DatasetError, ScenarioError
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.researcher.identify import stack
from vtestbed.researcher.measure import stacked
from vtestbed.researcher.reading_noise import with_reading_noise
from vtestbed.researcher.repeat_scans import estimate_noise_floor
from vtestbed.scenario import parse_scenario

cli_main = importlib.import_module("vtestbed.cli.main")
N_TESTS = 8


def _scenario(repeats=3, method="gls_floor"):
    data = paper_scenario_data(N_TESTS, 0, "gls_floor", 5, repeats=repeats)
    data.pop("validation")
    data["identification"] = {"method": method}
    return data


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    sc = parse_scenario(_scenario(), "gls_floor.toml")
    return sc, simulate(sc, tmp_path_factory.mktemp("gls_floor") / "dataset")


def test_gls_floor_is_the_dense_gls_with_the_floor_covariance(dataset):
    _, root = dataset
    setup, measurements, result = identify_dataset(root, "gls_floor")
    floor = estimate_noise_floor(root, measurements)
    assert result.method == "gls_floor" and floor.n_samples == 3 * N_TESTS
    jac, wrench, disp = stacked(measurements)
    a, d = stack(jac, wrench), disp.reshape(-1)
    # the F/T readings' noise (checked against the sensor's own draws in test_reading_noise.py)
    readings = with_reading_noise(floor, measurements, setup).reading_covariance
    assert 1e-4 < np.trace(readings) / np.trace(floor.covariance) < 0.05
    # the floor's covariance times its sampling inflation nu / (nu - 7), nu = 24 repeat samples
    cov = (floor.covariance + readings) * 24 / 17
    w = np.kron(np.eye(N_TESTS), np.linalg.inv(cov))  # dense (6T, 6T) reference
    normal = a.T @ w @ a
    c_ref = np.linalg.solve(normal, a.T @ w @ d)
    std_ref = np.sqrt(np.diag(np.linalg.inv(normal))) / c_ref**2
    np.testing.assert_allclose(result.compliance, c_ref, rtol=1e-9)
    np.testing.assert_allclose(result.stiffness_std, std_ref, rtol=1e-7)
    np.testing.assert_allclose(result.displacement_cov, cov, rtol=1e-15)
    # the floor's correlations change the estimate: not the per-component weights of fgls
    _, _, fgls = identify_dataset(root, "fgls")
    assert np.max(np.abs(fgls.compliance / c_ref - 1)) > 1e-4


def test_a_campaign_trial_gives_the_dataset_numbers(dataset):
    sc, root = dataset
    prepared = montecarlo.prepare(sc)
    trial = montecarlo.trial(prepared, sc.seed, method="gls_floor")
    _, _, from_files = identify_dataset(root, "gls_floor")
    np.testing.assert_allclose(trial.stiffness, from_files.stiffness, rtol=1e-10)
    np.testing.assert_allclose(trial.stiffness_std, from_files.stiffness_std, rtol=1e-8)


def test_without_repeat_scans_every_entry_point_says_what_to_record(tmp_path, capsys):
    with pytest.raises(ScenarioError, match=r"identification\.method: 'gls_floor' .* repeats >= 2 \(got 0\)"):
        parse_scenario(_scenario(repeats=0), "x.toml")
    root = simulate(parse_scenario(_scenario(repeats=0, method="fgls"), "x.toml"), tmp_path / "plain")
    with pytest.raises(DatasetError, match=r"no repeat scans: record 2 or more scans .* 'fgls'"):
        identify_dataset(root, "gls_floor")
    code = cli_main.main(["identify", str(root), "--method", "gls_floor"])
    err = capsys.readouterr().err
    assert code == 2 and "no repeat scans" in err and "Traceback" not in err
    campaign = _scenario(repeats=0, method="fgls") | {
        "campaign": {"seed": 1, "trials": 2, "axes": {"method": ["fgls", "gls_floor"]}}
    }
    with pytest.raises(ScenarioError, match=r"campaign\.axes\.method\[1\]: 'gls_floor' needs repeat scans"):
        parse_campaign(campaign, Path("c.toml"))


def test_identify_estimates_the_floor_once_and_reports_the_one_it_weighted_with(dataset, capsys, monkeypatch):
    import json

    from vtestbed.researcher import repeat_scans

    _, root = dataset
    calls = []
    frames = repeat_scans.repeat_scan_frames
    monkeypatch.setattr(
        repeat_scans, "repeat_scan_frames", lambda *a, **k: calls.append(1) or frames(*a, **k)
    )
    assert cli_main.main(["identify", str(root), "--method", "gls_floor", "--json", "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(calls) == 1  # the repeat scans are fitted once: the weights and the report share them
    # reference: the floor refitted from the dataset's clouds alone (no reduced tests passed in)
    independent = repeat_scans.estimate_noise_floor(root)
    setup, measurements, _ = identify_dataset(root, "fgls")
    readings = with_reading_noise(independent, measurements, setup).reading_covariance
    # it weighted with the scans' and the readings' covariance times the sampling inflation
    # nu / (nu - 7) (nu = 24 samples), and reports the readings' stds
    np.testing.assert_allclose(
        out["displacement_cov"], (independent.covariance + readings) * 24 / 17, rtol=1e-12, atol=1e-30
    )
    np.testing.assert_allclose(out["noise_floor"]["reading_std"], np.sqrt(np.diag(readings)), rtol=1e-12)
    np.testing.assert_allclose(
        out["noise_floor"]["covariance"], independent.covariance, rtol=1e-12, atol=1e-30
    )


def test_too_few_repeat_samples_name_the_dataset_and_how_many_are_needed(dataset, tmp_path, capsys):
    import shutil

    root = shutil.copytree(dataset[1], tmp_path / "one")
    rows = (root / "repeats.csv").read_bytes().splitlines(keepends=True)
    (root / "repeats.csv").write_bytes(b"".join(rows[:2]))  # the header and T001's first repeat
    message = (
        f"{root}: identification method 'gls_floor' weights with the repeat-scan noise floor's 6 x 6 "
        "covariance, which needs at least 8 repeat-scan samples (one per repeat of a test); repeats.csv "
        "gives 1 (from 1 test): record 7 more repeat scans, or use method 'fgls'"
    )
    with pytest.raises(DatasetError) as exc:
        identify_dataset(root, "gls_floor")
    assert str(exc.value) == message
    assert cli_main.main(["identify", str(root), "--method", "gls_floor", "--quiet"]) == 2
    assert capsys.readouterr().err == f"vtestbed: error: {message}\n"
    (root / "repeats.csv").write_bytes(b"".join(rows[:10]))  # T001-T003, 3 repeats each: 9 samples
    _, _, result = identify_dataset(root, "gls_floor")
    assert result.method == "gls_floor" and np.all(result.stiffness > 0)
