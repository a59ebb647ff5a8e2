"""The virtual experiment end to end: scenario -> dataset -> identification -> truth."""

import copy
import csv
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from vtestbed import cli, ply
from vtestbed.campaigns.montecarlo import prepare, trial
from vtestbed.dataset import read_tests
from vtestbed.errors import DatasetError, ScanError
from vtestbed.experiment import identify_dataset, run, simulate
from vtestbed.scenario import load_scenario, parse_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def small_scenario(n_tests=8, n_val=2, seed=7):
    data = tomllib.loads((SCENARIOS / "kr60_paper.toml").read_text())
    data = copy.deepcopy(data)
    data["name"] = "small"
    data["seed"] = seed
    data["poses"]["angles_deg"] = data["poses"]["angles_deg"][:n_tests]
    for key in ("hook", "anchor"):
        data["load"][key] = data["load"][key][:n_tests]
    if n_val == 0:
        del data["validation"]
        return parse_scenario(data, "small.toml")
    data["validation"]["angles_deg"] = data["validation"]["angles_deg"][:n_val]
    for key in ("hook", "anchor"):
        data["validation"][key] = data["validation"][key][:n_val]
    return parse_scenario(data, "small.toml")


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return out, run(small_scenario(), out, figures=False)


def test_ideal_sensors_recover_the_truth_within_half_a_percent(tmp_path):
    summary = run(load_scenario(SCENARIOS / "kr60_ideal.toml"), tmp_path, figures=False)
    bias = {j["name"]: round(j["rel_err"] * 100, 4) for j in summary["joints"]}
    print(f"\nremaining bias with perfect sensors [%]: {bias}")
    for j in summary["joints"]:
        assert abs(j["rel_err"]) < 0.005, j
    # with perfect sensors the model error is all that is left: validation within 0.5 %
    for v in summary["validation"]:
        assert v["rel_err_translation"] < 0.005 and v["rel_err_rotation"] < 0.005


def test_result_json_has_the_documented_fields(small_run):
    out, summary = small_run
    data = json.loads((out / "result.json").read_text())
    assert [j["name"] for j in data["joints"]] == [f"joint{i}" for i in range(1, 7)]
    for j in data["joints"]:
        assert set(j) == {"name", "k_true", "k_est", "k_std", "rel_err"}
        assert j["rel_err"] == pytest.approx(j["k_est"] / j["k_true"] - 1, rel=1e-12)
        # the estimate is within 5 standard deviations of the truth
        assert abs(j["k_est"] - j["k_true"]) < 5 * j["k_std"]
    assert len(data["convergence"]["n"]) == 8


def test_identify_on_the_dataset_gives_the_same_numbers_as_run(small_run, capsys):
    out, summary = small_run
    assert cli.main(["identify", str(out / "dataset"), "--json", "--quiet"]) == 0
    ident = json.loads(capsys.readouterr().out)
    np.testing.assert_array_equal(ident["stiffness"], [j["k_est"] for j in summary["joints"]])


def test_same_seed_same_result_and_monte_carlo_reproduces_the_dataset(small_run, tmp_path):
    out, summary = small_run
    again = run(small_scenario(), tmp_path, figures=False)
    assert again["joints"] == summary["joints"]
    other = run(small_scenario(seed=8), tmp_path / "other", figures=False)
    assert other["joints"] != summary["joints"]
    # a trial on prepared (cast-once) physics with the same seed is the same experiment
    prepared = prepare(small_scenario())
    res = trial(prepared, seed=7)
    np.testing.assert_array_equal(res.stiffness, [j["k_est"] for j in summary["joints"]])


def test_interrupted_simulation_resumes_without_loss_or_duplicates(small_run, tmp_path):
    out, _ = small_run
    reference = (out / "dataset" / "tests.csv").read_text()
    scenario = small_scenario()
    simulate(scenario, tmp_path)
    lines = (tmp_path / "tests.csv").read_text().splitlines(keepends=True)
    (tmp_path / "tests.csv").write_text("".join(lines[:4]))  # as if killed after 3 tests
    (tmp_path / "clouds" / "T004_unloaded.ply").write_bytes(b"partial")  # a half-written file
    simulate(scenario, tmp_path)
    assert (tmp_path / "tests.csv").read_text() == reference.replace(str(out / "dataset"), str(tmp_path))
    ids = [r.test_id for r in read_tests(tmp_path)]
    assert len(ids) == len(set(ids)) == 10


def test_a_folder_of_another_scenario_is_refused_or_replaced(tmp_path):
    simulate(small_scenario(n_tests=2, n_val=0), tmp_path)
    other = small_scenario(n_tests=2, n_val=0, seed=99)
    with pytest.raises(DatasetError, match="holds a dataset of another scenario"):
        simulate(other, tmp_path)
    simulate(other, tmp_path, replace_stale=True)
    assert json.loads((tmp_path / "truth.json").read_text())["seed"] == 99
    assert len(read_tests(tmp_path)) == 2


def test_relative_output_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scenario = small_scenario(n_tests=2, n_val=0)
    simulate(scenario, Path("runs") / "rel")
    rows = (tmp_path / "runs" / "rel" / "tests.csv").read_text().splitlines()
    assert rows[1].endswith("clouds/T001_unloaded.ply,clouds/T001_loaded.ply")
    _, measurements, _ = identify_dataset(Path("runs") / "rel")
    assert len(measurements) == 2


def _copy_dataset(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def _edit_csv(path: Path, edit) -> None:
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
        fields = list(rows[0])
    edit(rows)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fields)
        writer.writeheader()
        writer.writerows(rows)


def test_broken_datasets_get_clear_errors(small_run, tmp_path):
    src = small_run[0] / "dataset"
    d = _copy_dataset(src, tmp_path / "missing_cloud")
    (d / "clouds" / "T003_loaded.ply").unlink()
    with pytest.raises(
        DatasetError, match=r"test 'T003'.*T003_loaded.ply is missing \(10 tests need 20 clouds, 19 found"
    ):
        identify_dataset(d)

    d = _copy_dataset(src, tmp_path / "no_block")
    far = np.random.default_rng(0).uniform(-0.1, 0.1, (5000, 3)) + [3.0, 0.0, 2.0]
    ply.write_ply(d / "clouds" / "T002_unloaded.ply", far)
    with pytest.raises(ScanError, match=r"test T002, unloaded cloud"):
        identify_dataset(d)

    d = _copy_dataset(src, tmp_path / "overload")
    _edit_csv(d / "tests.csv", lambda rows: rows[4].update({"loaded_Tz_Nm": "45.0"}))
    with pytest.raises(
        DatasetError,
        match=r"test 'T005'.*loaded wrench: Tz = 45.00 N\*m is outside the measuring range \[-30, 30\]",
    ):
        identify_dataset(d)

    d = _copy_dataset(src, tmp_path / "slack")

    def slack(rows):
        for c in ("Fx_N", "Fy_N", "Fz_N", "Tx_Nm", "Ty_Nm", "Tz_Nm"):
            rows[1][f"loaded_{c}"] = rows[1][f"unloaded_{c}"]

    _edit_csv(d / "tests.csv", slack)
    with pytest.raises(Exception, match=r"tests T002 have a force change below 1 N: the wire was slack"):
        identify_dataset(d)

    d = _copy_dataset(src, tmp_path / "no_setup")
    (d / "setup.json").unlink()
    with pytest.raises(DatasetError, match="setup file .* is missing"):
        identify_dataset(d)
    assert cli.main(["identify", str(d), "--quiet"]) == 2  # a clear error, no traceback
