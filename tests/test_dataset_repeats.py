"""Repeat scans in the dataset protocol: scenario key, world stream, repeats.csv, simulate and resume."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed import cli, ply
from vtestbed.campaigns.montecarlo import prepare
from vtestbed.dataset import read_tests
from vtestbed.dataset_repeats import REPEATS_FILE, RepeatRecord, RepeatWriter, read_repeats
from vtestbed.errors import DatasetError, ScenarioError
from vtestbed.experiment import simulate
from vtestbed.scenario import load_scenario, parse_scenario
from vtestbed.world import physics
from vtestbed.world.repeats import draw_repeat_scans, repeat_rng
from vtestbed.world.scan_noise import ScanNoise

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def scenario_data(n_tests=3, n_val=1, seed=11, **scanner):
    """The paper scenario cut to ``n_tests`` identification and ``n_val`` validation tests."""
    return paper_scenario_data(n_tests, n_val, "repeats", seed, **scanner)


def scenario(**kwargs):
    return parse_scenario(scenario_data(**kwargs), "repeats.toml")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """The same scenario simulated with 2 repeats and without: (with, without) folders."""
    root = tmp_path_factory.mktemp("repeats")
    return simulate(scenario(repeats=2), root / "r2"), simulate(scenario(), root / "r0")


# ---------------------------------------------------------------------- scenario
def test_repeats_key_is_validated_and_defaults_to_none():
    assert scenario().scanner.repeats == 0
    assert scenario(repeats=20).scanner.repeats == 20
    for bad in (-1, 21, 2.5, True, "3"):
        with pytest.raises(
            ScenarioError, match=r"repeats.toml: scanner.repeats: must be an integer in \[0, 20\]"
        ):
            scenario(repeats=bad)


def test_fingerprint_of_a_file_without_the_key_is_unchanged():
    # the value before repeats existed (commit fd16f5e hashes the same raw TOML mapping)
    assert (
        load_scenario(SCENARIOS.parent / "tests" / "data" / "kr60_paper_unclear.toml").fingerprint
        == "451b9fe93240999f"
    )
    assert scenario(repeats=2).fingerprint != scenario().fingerprint


# ---------------------------------------------------------------------- world
def test_repeat_stream_is_separate_and_repeat_k_does_not_depend_on_r(scene):
    *_, hits = scene
    noise = ScanNoise()
    assert not np.array_equal(
        repeat_rng(5, "identification", 0).random(4), physics.test_rng(5, "identification", 0).random(4)
    )
    assert not np.array_equal(
        repeat_rng(5, "validation", 0).random(4), repeat_rng(5, "identification", 0).random(4)
    )
    three = draw_repeat_scans(hits, noise, repeat_rng(5, "identification", 2), 3)
    two = draw_repeat_scans(hits, noise, repeat_rng(5, "identification", 2), 2)
    for a, b in zip(two, three):
        np.testing.assert_array_equal(a, b)
    # each repeat is exactly one noise.apply on the unloaded hits, in order (own drift each)
    rng = repeat_rng(5, "identification", 2)
    for scan in three:
        np.testing.assert_array_equal(scan, noise.apply(hits, rng))
    assert not np.array_equal(three[0][:100], three[1][:100])


def test_a_perfect_scanner_repeats_copies_and_draws_nothing(scene):
    *_, hits = scene
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    scans = draw_repeat_scans(hits, None, rng, 2)
    assert rng.bit_generator.state == state
    for scan in scans:
        np.testing.assert_array_equal(scan, hits.points_m)
        assert scan is not hits.points_m
    assert draw_repeat_scans(hits, ScanNoise(), rng, 0) == []


# ---------------------------------------------------------------------- simulate
def test_repeats_change_nothing_else_in_the_dataset(datasets):
    with_r, without = datasets
    for name in ("setup.json", "tests.csv"):
        assert (with_r / name).read_bytes() == (without / name).read_bytes(), name
    for tid in ("T001", "T002", "T003", "V001"):
        for kind in ("unloaded", "loaded"):
            name = f"clouds/{tid}_{kind}.ply"
            assert (with_r / name).read_bytes() == (without / name).read_bytes(), name
    assert not (without / REPEATS_FILE).exists()
    truth_r, truth_0 = (json.loads((d / "truth.json").read_text()) for d in datasets)
    assert (truth_r.pop("repeats"), truth_0.pop("repeats")) == (2, 0)
    assert truth_r.pop("scenario_fingerprint") != truth_0.pop("scenario_fingerprint")
    assert truth_r == truth_0


def test_repeats_csv_lists_the_repeat_draws_of_every_test(datasets):
    root, _ = datasets
    lines = (root / REPEATS_FILE).read_text().splitlines()
    assert lines[:3] == [
        "test_id,repeat,cloud",
        "T001,1,clouds/T001_repeat1.ply",
        "T001,2,clouds/T001_repeat2.ply",
    ]
    records = read_repeats(root)
    assert [(r.test_id, r.repeat) for r in records] == [
        (t, k) for t in ("T001", "T002", "T003", "V001") for k in (1, 2)
    ]
    # the clouds are the world's repeat draws on the test's unloaded geometry (V001 too)
    sc = scenario(repeats=2)
    prepared = prepare(sc, include_validation=True)
    for t in (prepared.tests[1], prepared.tests[3]):
        expected = draw_repeat_scans(
            t.hits_unloaded, sc.scanner.noise_model, repeat_rng(11, t.group, t.index), 2
        )
        for k in (1, 2):
            np.testing.assert_array_equal(
                ply.read_ply(root / f"clouds/{t.test_id}_repeat{k}.ply"), expected[k - 1]
            )


def test_resume_redoes_only_the_missing_repeats(datasets, tmp_path):
    ref, _ = datasets
    sc = scenario(repeats=2)
    reference = {n: (ref / n).read_text() for n in ("tests.csv", REPEATS_FILE)}
    simulate(sc, tmp_path)
    # killed after T003's first repeat: its second repeat half written, its tests.csv row missing
    tests = (tmp_path / "tests.csv").read_text().splitlines(keepends=True)
    (tmp_path / "tests.csv").write_text("".join(tests[:3]))
    reps = (tmp_path / REPEATS_FILE).read_text().splitlines(keepends=True)
    (tmp_path / REPEATS_FILE).write_text("".join(reps[:6]))
    (tmp_path / "clouds" / "T003_repeat2.ply").write_bytes(b"partial")
    (tmp_path / "clouds" / "V001_repeat1.ply").unlink()
    keep = (tmp_path / "clouds" / "T003_repeat1.ply").stat().st_mtime_ns
    simulate(sc, tmp_path)
    assert {n: (tmp_path / n).read_text() for n in reference} == reference
    assert (tmp_path / "clouds" / "T003_repeat1.ply").stat().st_mtime_ns == keep  # not redone
    read_repeats(tmp_path)  # every cloud there, no duplicate
    # killed after all of T003's repeats, before its tests.csv row: no repeat written twice
    (tmp_path / "tests.csv").write_text("".join(tests[:3]))
    simulate(sc, tmp_path)
    assert {n: (tmp_path / n).read_text() for n in reference} == reference
    # a finished test whose repeats were lost gets them back, its own row and clouds untouched
    (tmp_path / REPEATS_FILE).write_text("".join(reps[:3]))
    simulate(sc, tmp_path)
    assert {n: (tmp_path / n).read_text() for n in reference} == reference
    for a, b in zip(read_repeats(tmp_path), read_repeats(ref)):
        assert (a.test_id, a.repeat) == (b.test_id, b.repeat)
        assert a.cloud.read_bytes() == b.cloud.read_bytes()


def test_replacing_a_stale_dataset_removes_its_repeats(datasets, tmp_path):
    shutil.copytree(datasets[0], tmp_path / "d")
    simulate(scenario(seed=12), tmp_path / "d", replace_stale=True)
    assert not (tmp_path / "d" / REPEATS_FILE).exists()
    assert len(read_tests(tmp_path / "d")) == 4


# ---------------------------------------------------------------------- repeats.csv by hand
def _with_repeats(datasets, tmp_path, text: str) -> Path:
    d = tmp_path / "d"
    shutil.copytree(datasets[1], d)
    for name in ("extra.ply", "extra2.ply"):
        ply.write_ply(d / "clouds" / name, np.zeros((3, 3)))
    (d / REPEATS_FILE).write_text(text)
    return d


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ("T001,1,clouds/extra.ply\nT009,1,clouds/extra.ply\n",
         r"repeats.csv line 3 \(test 'T009'\): test_id 'T009' is not a test of .*tests.csv"),
        ("T001,1.5,clouds/extra.ply\n", r"repeats.csv line 2 \(test 'T001'\): repeat must be an integer >= 1 .*'1.5'"),
        ("T001,0,clouds/extra.ply\n", r"line 2 .*repeat must be an integer >= 1"),
        ("T001,1,clouds/extra.ply\nT002,1,clouds/extra2.ply\nT001,1,clouds/extra.ply\n",
         r"repeats.csv line 4 \(test 'T001'\): repeat 1 of test 'T001' is listed twice \(first on line 2\)"),
        ("T001,1,clouds/extra.ply\nT001,2,clouds/extra2.ply\nT001,3,clouds/extra.ply\n",
         r"repeats.csv line 4 \(test 'T001'\): cloud 'clouds/extra.ply' is already repeat 1 of test 'T001' "
         r"\(line 2\); every repeat must be its own scan of the unloaded block, in its own file "
         r"\(e.g. clouds/T001_repeat3.ply\)$"),
        ("T001,1,clouds/extra.ply\nT002,1,clouds/../clouds/extra.ply\n",
         r"repeats.csv line 3 \(test 'T002'\): cloud 'clouds/../clouds/extra.ply' is already repeat 1 of "
         r"test 'T001' \(line 2\)"),
        ("T001,1,../r0/clouds/T001_unloaded.ply\n",
         r"line 2 .*cloud '../r0/clouds/T001_unloaded.ply' must be a path inside the dataset folder"),
        ("T001,1,\n", r"line 2 .*cloud '' must be a path inside the dataset folder"),
        ("T001,1,clouds/T001_repeat1.ply\n", r"repeats.csv line 2 \(test 'T001'\): cloud: point cloud .*T001_repeat1.ply is missing"),
        ("T001,1,clouds/extra.ply\nT001,2,clouds/T001_loaded.ply\n",
         r"repeats.csv line 3 \(test 'T001'\): cloud 'clouds/T001_loaded.ply' is the test's own loaded scan "
         r"\(cloud_loaded in .*/d/tests.csv\); a repeat must be another scan of the unloaded block, in its own "
         r"file \(e.g. clouds/T001_repeat2.ply\)$"),
        ("T002,1,clouds/../clouds/T002_unloaded.ply\n",
         r"repeats.csv line 2 \(test 'T002'\): cloud 'clouds/../clouds/T002_unloaded.ply' is the test's own "
         r"unloaded scan \(cloud_unloaded in "),
        ("T001,1,clouds/T002_unloaded.ply\n",
         r"repeats.csv line 2 \(test 'T001'\): cloud 'clouds/T002_unloaded.ply' is the unloaded scan of test "
         r"'T002' \(cloud_unloaded in .*tests.csv\); a repeat must be another scan of its own test's unloaded "
         r"block"),
        ("T001,1,clouds/extra.ply\n", None),  # its own scan: accepted
    ],
)  # fmt: skip
def test_bad_repeats_csv_names_file_line_and_field(datasets, tmp_path, rows, message):
    d = _with_repeats(datasets, tmp_path, "test_id,repeat,cloud\n" + rows)
    if message is None:
        assert [r.repeat for r in read_repeats(d)] == [1]
        return
    with pytest.raises(DatasetError, match=message):
        read_repeats(d)


def test_a_repeat_hard_linked_to_the_tests_own_scan_is_refused(datasets, tmp_path):
    d = _with_repeats(datasets, tmp_path, "test_id,repeat,cloud\nT003,1,clouds/copy.ply\n")
    (d / "clouds" / "copy.ply").hardlink_to(d / "clouds" / "T003_loaded.ply")
    with pytest.raises(DatasetError, match=r"cloud 'clouds/copy.ply' is the test's own loaded scan"):
        read_repeats(d)


def test_a_repeat_hard_linked_to_another_repeat_is_refused(datasets, tmp_path):
    """Two repeats of one scan would enter the noise floor as an exact zero (a floor too small)."""
    d = _with_repeats(
        datasets, tmp_path, "test_id,repeat,cloud\nT003,1,clouds/extra.ply\nT003,2,clouds/b.ply\n"
    )
    (d / "clouds" / "b.ply").hardlink_to(d / "clouds" / "extra.ply")
    with pytest.raises(DatasetError, match=r"line 3 .*'clouds/b.ply' is already repeat 1 of test 'T003'"):
        read_repeats(d)
    (d / "clouds" / "b.ply").unlink()
    ply.write_ply(d / "clouds" / "b.ply", np.ones((3, 3)))  # its own scan: accepted
    assert [r.repeat for r in read_repeats(d)] == [1, 2]


def test_hand_written_repeats_csv_reads_and_missing_columns_are_named(datasets, tmp_path):
    assert read_repeats(datasets[1]) == []  # no file: no repeats
    d = _with_repeats(datasets, tmp_path, "test_id,repeat,cloud\nV001, 3 ,clouds/extra.ply\n")
    assert read_repeats(d) == [RepeatRecord("V001", 3, d / "clouds" / "extra.ply")]
    (d / REPEATS_FILE).write_text("test_id,repeat\nT001,1\n")
    with pytest.raises(DatasetError, match=r"repeats.csv: columns missing: cloud"):
        read_repeats(d)
    (d / REPEATS_FILE).write_text("test_id,repeat,cloud\nT001,1,clouds/nothere.ply\n")
    assert read_repeats(d, check_files=False)[0].cloud == d / "clouds" / "nothere.ply"


def test_repeat_writer_appends_and_knows_what_is_done(tmp_path):
    (tmp_path / "clouds").mkdir()
    with RepeatWriter(tmp_path) as w:
        w.append(RepeatRecord("T001", 1, tmp_path / "clouds" / "a.ply"))
    with RepeatWriter(tmp_path) as w:
        assert w.done == {("T001", 1)}
        w.append(RepeatRecord("T001", 2, tmp_path / "clouds" / "b.ply"))
    assert (tmp_path / REPEATS_FILE).read_text().splitlines() == [
        "test_id,repeat,cloud", "T001,1,clouds/a.ply", "T001,2,clouds/b.ply"
    ]  # fmt: skip


def test_identify_prints_the_floor_only_with_repeats(datasets, capsys):
    with_r, without = datasets
    assert cli.main(["identify", str(with_r), "--quiet", "--no-truth"]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("noise floor")]
    assert len(line) == 1 and "um" in line[0] and "urad" in line[0] and "(8 samples from 4 tests" in line[0]
    assert cli.main(["identify", str(without), "--quiet", "--no-truth", "--json"]) == 0
    assert "noise_floor" not in json.loads(capsys.readouterr().out)


def test_extra_columns_may_repeat_and_a_bad_loaded_row_is_left_to_its_own_read(datasets, tmp_path):
    """A spreadsheet's trailing empty columns (a header ",,") are extra columns, read as before;
    only the columns vtestbed reads must be unique. A NUL byte in loaded_repeats.csv does not
    break the read of repeats.csv (its own read refuses it, naming the line)."""
    d = _with_repeats(datasets, tmp_path, "test_id,repeat,cloud,,\nT003,1,clouds/extra.ply,,\n")
    assert [(r.test_id, r.repeat) for r in read_repeats(d)] == [("T003", 1)]
    (d / "loaded_repeats.csv").write_text("test_id,repeat,cloud\nT003,1,clouds/a\0b.ply\n")
    assert [(r.test_id, r.repeat) for r in read_repeats(d)] == [("T003", 1)]
    with pytest.raises(
        DatasetError, match=r"loaded_repeats.csv line 2 \(test 'T003'\): cloud .* must be a path inside"
    ):
        read_repeats(d, state="loaded")
