"""``vtestbed identify --reference mean`` and ``montecarlo.trial(reference="mean")``: the
displacements against the mean unloaded scan, checked against an average computed with scipy's
rotation mean and against the closed-form scaling of the floor's covariance."""

import json

import numpy as np
import pytest
from conftest import paper_scenario_data
from scan_mean_helpers import scipy_mean_frame

from vtestbed.campaigns.montecarlo import prepare, trial
from vtestbed.cli.main import main
from vtestbed.dataset_identification import identify_dataset_with_floor
from vtestbed.errors import DatasetError, ScenarioError, UnknownNameError
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.researcher.identify import stack
from vtestbed.researcher.measure import load_measurements
from vtestbed.researcher.repeat_scans import repeat_scan_frames
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import displacement_in_block_frame


@pytest.fixture(scope="module")
def repeat_dataset(tmp_path_factory):
    """5 identification and 1 validation test of the paper, 2 repeat scans each (12 floor samples)."""
    sc = parse_scenario(paper_scenario_data(5, 1, "reference", 11, repeats=2), "reference.toml")
    return simulate(sc, tmp_path_factory.mktemp("reference"))


def test_identify_reference_mean_solves_with_the_displacements_against_the_mean_scan(repeat_dataset, capsys):
    assert (
        main(["identify", str(repeat_dataset), "--reference", "mean", "--method", "ols", "--json", "--quiet"])
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["reference"] == "mean" and out["noise_floor"]["reference_scans"] == 3
    _, single = load_measurements(repeat_dataset)
    frames = repeat_scan_frames(repeat_dataset, single)
    tests = [m for m in single if m.group == "identification"]
    d = np.concatenate(
        [displacement_in_block_frame(scipy_mean_frame(frames[m.test_id]), m.frame_loaded) for m in tests]
    )
    a = stack([m.jacobian for m in tests], [m.wrench for m in tests])
    expected = np.linalg.lstsq(a, d, rcond=None)[0]
    np.testing.assert_allclose(out["compliance"], expected, rtol=1e-6)
    d_single = np.concatenate([m.displacement for m in tests])
    assert np.max(np.abs(np.linalg.lstsq(a, d_single, rcond=None)[0] / expected - 1)) > 1e-4  # it moved


def test_gls_floor_against_the_mean_scan_has_the_floor_scaled_by_the_closed_form(repeat_dataset):
    """gls_floor's compliance covariance is (A^T W A)^-1 with W the inverse of the floor (times its
    sampling inflation nu / (nu - 7), nu = 12) plus the F/T readings' part: against the mean of
    m = 3 scans the scans' part is (1 + 1/m) / 2 = 2/3 of the single-scan one; the readings' part
    does not average."""
    _, _, scan, scan_floor = identify_dataset_with_floor(repeat_dataset, "gls_floor", reference="scan")
    _, tests, mean, mean_floor = identify_dataset_with_floor(repeat_dataset, "gls_floor", reference="mean")
    np.testing.assert_allclose(mean_floor.covariance, scan_floor.covariance * 2 / 3, rtol=1e-12)
    assert mean_floor.reading_covariance is not None
    tests = [m for m in tests if m.group == "identification"]
    a = stack([m.jacobian for m in tests], [m.wrench for m in tests])
    weight = np.linalg.inv((mean_floor.covariance + mean_floor.reading_covariance) * 12 / 5)
    np.testing.assert_allclose(
        mean.compliance_cov, np.linalg.inv(a.T @ np.kron(np.eye(len(tests)), weight) @ a), rtol=1e-9
    )
    assert np.max(np.abs(mean.compliance / scan.compliance - 1)) > 1e-4  # other displacements


def test_reference_mean_needs_repeat_scans_and_a_known_name(tmp_path, capsys):
    plain = simulate(parse_scenario(paper_scenario_data(2, 1, "plain", 7), "p.toml"), tmp_path / "plain")
    assert main(["identify", str(plain), "--reference", "mean", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no repeat scans (repeats.csv)" in err and "reference 'scan'" in err and str(plain) in err
    with pytest.raises(DatasetError, match="no repeat scans"):
        identify_dataset(plain, "fgls", reference="mean")
    with pytest.raises(UnknownNameError, match="valid names: mean, scan"):
        identify_dataset(plain, "fgls", reference="median")
    assert main(["identify", str(plain), "--reference", "scan", "--model", str(tmp_path / "m.json")]) == 2
    assert "--reference scan cannot be combined with --model" in capsys.readouterr().err


def test_reference_choices_of_the_command_and_the_scenario_are_the_library_s():
    from vtestbed.cli.experiment import REFERENCES as CLI
    from vtestbed.researcher.scan_mean import REFERENCES
    from vtestbed.scenario import DEFAULT_REFERENCE
    from vtestbed.scenario import REFERENCES as SCENARIO

    assert CLI == SCENARIO == REFERENCES and DEFAULT_REFERENCE == "scan"


def test_a_scenario_asking_for_the_mean_without_repeats_is_refused_before_it_runs():
    data = paper_scenario_data(2, 1, "plain", 7) | {"identification": {"reference": "mean"}}
    with pytest.raises(ScenarioError, match=r"identification\.reference: 'mean' .* repeats >= 1 \(got 0\)"):
        parse_scenario(data, "x.toml")
    data["identification"]["reference"] = "median"
    with pytest.raises(ScenarioError, match=r"identification\.reference.*'median'.*scan, mean"):
        parse_scenario(data, "x.toml")


def test_campaign_trial_against_the_mean_scan_matches_the_dataset_reading(repeat_dataset):
    """montecarlo.trial(reference="mean") draws the same noise as simulate (the same clouds and
    repeat scans): with ols (no floor in the weights; the dataset's floor also holds the validation
    test's repeats) it reproduces the dataset's identification."""
    data = paper_scenario_data(5, 1, "reference", 11, repeats=2) | {
        "identification": {"method": "ols", "reference": "mean"}
    }
    sc = parse_scenario(data, "reference.toml")
    assert sc.reference == "mean"
    result = trial(prepare(sc, include_validation=False), sc.seed)  # the scenario's method and reference
    _, _, dataset = identify_dataset(repeat_dataset, "ols", reference="mean")
    np.testing.assert_allclose(result.compliance, dataset.compliance, rtol=1e-10)
    _, _, single = identify_dataset(repeat_dataset, "ols")
    assert np.max(np.abs(single.compliance / dataset.compliance - 1)) > 1e-4
