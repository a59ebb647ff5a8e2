"""A command resumes only its own kind of folder (simulate, run, sweep, dataset import), and a
finished simulated test whose cloud was lost is redone byte for byte."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from quick_campaign import tiny
from report_fixtures import small_paper

from vtestbed.campaigns.runner import sweep
from vtestbed.campaigns.store import SweepError
from vtestbed.dataset import read_tests
from vtestbed.errors import DatasetError, SensorOverloadError
from vtestbed.experiment import run, simulate
from vtestbed.output_folders import folder_kinds
from vtestbed.scenario import parse_scenario


def _scenario(n_tests: int = 3, seed: int = 4):
    return parse_scenario(small_paper(n_tests, 1) | {"name": "folders", "seed": seed}, "folders.toml")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "ds"
    simulate(_scenario(), out)
    return out


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_simulate_refuses_a_dataset_without_truth_and_changes_nothing(dataset, tmp_path):
    lab = tmp_path / "lab"
    shutil.copytree(dataset, lab)
    (lab / "truth.json").unlink()  # what `dataset import` writes: no truth record
    before = _snapshot(lab)
    with pytest.raises(DatasetError) as exc:
        simulate(_scenario(), lab)
    assert str(exc.value) == (
        f"{lab} holds a dataset without truth.json (vtestbed dataset import, or a lab's files) "
        "(setup.json, tests.csv); 'vtestbed simulate' does not write into it, so as not to mix two "
        "results: choose a new or empty --out folder"
    )
    assert _snapshot(lab) == before


def test_simulate_refuses_rows_that_its_truth_does_not_record(dataset, tmp_path):
    mixed = tmp_path / "mixed"
    shutil.copytree(dataset, mixed)
    rows = (mixed / "tests.csv").read_text().splitlines(keepends=True)
    (mixed / "tests.csv").write_text(
        "".join(rows) + rows[1].replace("T001", "L007")
    )  # a lab's row, its own scans
    before = _snapshot(mixed)
    with pytest.raises(DatasetError) as exc:
        simulate(_scenario(), mixed)
    assert str(exc.value) == (
        f"{mixed / 'tests.csv'} lists tests (L007) that {mixed / 'truth.json'} of scenario 'folders' "
        "does not record: the folder mixes another dataset in; choose a new --out folder"
    )
    assert _snapshot(mixed) == before


def test_an_interrupted_simulation_still_resumes(dataset, tmp_path):
    out = tmp_path / "int"
    shutil.copytree(dataset, out)
    rows = (out / "tests.csv").read_bytes().splitlines(keepends=True)  # csv rows end in \r\n
    (out / "tests.csv").write_bytes(b"".join(rows[:2]))  # killed after the first test
    simulate(_scenario(), out)
    assert _snapshot(out) == _snapshot(dataset)
    # older code wrote setup.json and a header before truth.json: a start with nothing in it resumes
    early = tmp_path / "early"
    early.mkdir()
    shutil.copy(dataset / "setup.json", early)
    (early / "tests.csv").write_bytes(rows[0])
    assert folder_kinds(early) == []
    simulate(_scenario(), early)
    assert [r.test_id for r in read_tests(early)] == ["T001", "T002", "T003", "V001"]


@pytest.mark.parametrize(
    "victims", [["T002_loaded.ply"], ["T003_unloaded.ply", "T003_loaded.ply", "V001_loaded.ply"]]
)
def test_a_lost_cloud_of_a_finished_test_is_redone_byte_for_byte(dataset, tmp_path, victims):
    out = tmp_path / "ds"
    shutil.copytree(dataset, out)
    kept = (out / "clouds" / "T001_loaded.ply").stat().st_mtime_ns
    for name in victims:
        (out / "clouds" / name).unlink()
    simulate(_scenario(), out)
    assert _snapshot(out) == _snapshot(dataset)  # the clouds, tests.csv and truth.json alike
    assert (out / "clouds" / "T001_loaded.ply").stat().st_mtime_ns == kept  # the others untouched


def test_sweep_refuses_a_run_folder_and_keeps_its_report(tmp_path):
    out = tmp_path / "run"
    run(_scenario(n_tests=2), out, figures=False)
    (out / "report.html").write_text("the run's page")
    with pytest.raises(
        SweepError,
        match=r"holds a run's results \(vtestbed run\) \(result\.json, dataset/truth\.json\); 'vtestbed sweep' does not write",
    ):
        sweep(tiny(), out, progress=False)
    assert not (out / "campaign.json").exists() and (out / "report.html").read_text() == "the run's page"
    with pytest.raises(SweepError, match=r"holds a simulated dataset \(vtestbed simulate\) \(truth\.json\)"):
        sweep(tiny(), out / "dataset", progress=False)
    assert not (out / "dataset" / "campaign.json").exists()


def test_sweep_folder_is_refused_by_simulate_run_and_import(tiny_sweep, tmp_path):
    _, ref = tiny_sweep
    folder = tmp_path / "sw"
    shutil.copytree(ref, folder)
    before = _snapshot(folder)
    words = (
        r"holds a campaign's results \(vtestbed sweep\) \(campaign\.json, trials/\); 'vtestbed {}' does not"
    )
    with pytest.raises(DatasetError, match=words.format("simulate")):
        simulate(_scenario(), folder)
    with pytest.raises(DatasetError, match=words.format("run")):
        run(_scenario(), folder, figures=False)
    from vtestbed.output_folders import require_own_kind

    with pytest.raises(DatasetError, match=words.format("dataset import")):
        require_own_kind(folder, (), "vtestbed dataset import", DatasetError)
    assert _snapshot(folder) == before
    manifest = json.loads((folder / "campaign.json").read_text())
    assert manifest["scenario"]  # still the campaign's own folder


def test_a_simulation_refused_at_its_first_test_leaves_a_folder_the_fixed_scenario_can_use(tmp_path):
    """truth.json is written first, so a refused simulation leaves one; it finished nothing, so the
    rerun with the corrected scenario replaces it instead of asking for a new folder."""
    out = tmp_path / "ds"
    overloaded = small_paper(2, 1) | {"name": "folders", "seed": 4}
    overloaded["load"]["tension_N"] = 588.6  # beyond the sensor's Fx range on the first test
    with pytest.raises(SensorOverloadError, match="outside the measuring range"):
        simulate(parse_scenario(overloaded, "overloaded.toml"), out)
    assert json.loads((out / "truth.json").read_text())["tests"] == {}
    fixed = _scenario(n_tests=2)
    simulate(fixed, out)
    again = tmp_path / "again"
    simulate(fixed, again)
    assert _snapshot(out) == _snapshot(again)  # as if the folder had been new
