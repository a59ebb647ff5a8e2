"""docs/errors.md, dataset and result-folder rows: each bad file made for real (an edit of a small
written dataset, or of a sweep folder's files) and read by the library's one reader per kind."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from errors_table import Ctx, cli, refused, run_row, section_rows
from test_dataset import _edit_setup, _edit_tests, _records, _setup, _write

from vtestbed.comparison import read_truth
from vtestbed.dataset import read_setup, read_tests, write_setup
from vtestbed.dataset_repeats import read_repeats
from vtestbed.errors import DatasetError
from vtestbed.lab import LabSetup

ROWS = section_rows("Dataset files (`DatasetError`, `vtestbed/dataset_checks.py`)", "Result folders")
RANGE = (300.0, 300.0, 900.0, 25.0, 25.0, 25.0)  # the written dataset's force sensor range


def _dataset(ctx: Ctx):
    """A small written dataset (4 tests, empty cloud files): ``ctx.tmp/ds``."""
    root = ctx.tmp / "ds"
    root.mkdir(exist_ok=True)
    write_setup(root, _setup(LabSetup()))
    _write(root, _records(root))
    return root


def setup_error(**changes):
    def case(ctx):
        root = _dataset(ctx)
        _edit_setup(root, **changes)
        return refused(lambda: read_setup(root), DatasetError)

    return case


def setup_text(data: bytes | None):
    def case(ctx):
        root = _dataset(ctx)
        if data is None:
            (root / "setup.json").unlink()
        else:
            (root / "setup.json").write_bytes(data)
        return refused(lambda: read_setup(root), DatasetError)

    return case


def row_error(index, check_files=False, sensor_range=None, **values):
    def case(ctx):
        root = _dataset(ctx)
        _edit_tests(root, lambda rows: rows[index].update(values))
        return refused(lambda: read_tests(root, check_files, sensor_range), DatasetError)

    return case


def csv_lines(edit):
    def case(ctx):
        root = _dataset(ctx)
        path = root / "tests.csv"
        path.write_bytes(edit(path.read_text().splitlines()))
        return refused(lambda: read_tests(root, check_files=False), DatasetError)

    return case


def _cut_last_field(lines):
    return ("\n".join([*lines[:2], lines[2].rsplit(",", 1)[0], *lines[3:]]) + "\n").encode()


def _missing_cloud(ctx):
    root = _dataset(ctx)
    (root / "clouds" / "T1_l.ply").unlink()
    return refused(lambda: read_tests(root), DatasetError)


def _missing_tests(ctx):
    root = _dataset(ctx)
    (root / "tests.csv").unlink()
    return refused(lambda: read_tests(root), DatasetError)


def _column_twice(lines):
    """tests.csv with its loaded_Fz_N column (header and values) appended once more."""
    k = lines[0].split(",").index("loaded_Fz_N")
    return ("\n".join(f"{line},{line.split(',')[k]}" for line in lines) + "\n").encode()


def _tests_edit(edit):
    """A case: read_tests on the small dataset with its tests.csv rows changed by ``edit(rows)``."""

    def case(ctx):
        root = _dataset(ctx)
        _edit_tests(root, edit)
        return refused(lambda: read_tests(root, check_files=False), DatasetError)

    return case


def _copied_row(rows):
    rows.append(dict(rows[0], test_id="T009"))  # the first test again, under a new id


def _other_pose_unloaded(rows):
    rows[1]["cloud_unloaded"] = rows[0]["cloud_unloaded"]  # T001's scan for T002, at another pose


def _repeats(text):
    def case(ctx):
        root = _dataset(ctx)
        (root / "repeats.csv").write_text(text)
        return refused(lambda: read_repeats(root, check_files=False), DatasetError)

    return case


def _loaded_repeats(text):
    def case(ctx):
        root = _dataset(ctx)
        (root / "loaded_repeats.csv").write_text(text)
        return refused(lambda: read_repeats(root, check_files=False, state="loaded"), DatasetError)

    return case


def _both_repeat_files(ctx):
    """One scan listed as an unloaded repeat and as a loaded one."""
    root = _dataset(ctx)
    (root / "clouds" / "T0_r1.ply").write_bytes(b"")
    (root / "loaded_repeats.csv").write_text("test_id,repeat,cloud\nT000,1,clouds/T0_r1.ply\n")
    (root / "repeats.csv").write_text("test_id,repeat,cloud\nT000,1,clouds/T0_r1.ply\n")
    return refused(lambda: read_repeats(root, check_files=False), DatasetError)


def _truth(text):
    def case(ctx):
        (ctx.tmp / "truth.json").write_text(text)
        return refused(lambda: read_truth(ctx.tmp), DatasetError)

    return case


def _gls_floor_on_few_repeats(ctx):
    """``vtestbed identify --method gls_floor`` on a simulated dataset whose repeats.csv holds 2
    repeats of each of 2 tests: 4 samples of the floor's 6 x 6 covariance, which needs 6."""
    from conftest import paper_scenario_data

    from vtestbed.experiment import simulate
    from vtestbed.scenario import parse_scenario

    root = ctx.tmp / "ds"
    data = paper_scenario_data(2, 1, "floor", 3, repeats=2)
    del data["validation"]  # identification tests only
    simulate(parse_scenario(data), root, progress=False)
    return cli(ctx, ["identify", root, "--method", "gls_floor", "--quiet", "--no-truth"])


def _reference_mean_without_repeats(ctx):
    """``vtestbed identify --reference mean`` on a simulated dataset without repeats.csv."""
    from conftest import paper_scenario_data

    from vtestbed.experiment import simulate
    from vtestbed.scenario import parse_scenario

    root = ctx.tmp / "ds"
    simulate(parse_scenario(paper_scenario_data(2, 1, "plain", 3)), root, progress=False)
    return cli(ctx, ["identify", root, "--reference", "mean", "--quiet", "--no-truth"])


def _sweep_folder(ctx, part: bytes | None = None, manifest: str | None = None):
    """A results folder holding a campaign.json and one trials part (no sweep run)."""
    out = ctx.tmp / "sweep"
    (out / "trials").mkdir(parents=True)
    if part is not None:
        (out / "trials" / "part-0000.parquet").write_bytes(part)
    if manifest is not None:
        (out / "campaign.json").write_text(manifest)
    return out


def _parquet_part(ctx):
    from vtestbed.campaigns.store import SweepError, read_results

    good = ctx.tmp / "good.parquet"
    pd.DataFrame({"trial_key": ["a"], "x": [1.0]}).to_parquet(good)
    out = _sweep_folder(ctx, part=good.read_bytes()[:100])  # truncated
    return refused(lambda: read_results(out), SweepError)


def _foreign_part(ctx):
    from vtestbed.campaigns.store import SweepError, read_results

    good = ctx.tmp / "good.parquet"
    pd.DataFrame({"x": [1.0]}).to_parquet(good)
    out = _sweep_folder(ctx, part=good.read_bytes())
    return refused(lambda: read_results(out), SweepError)


def _manifest(text):
    def case(ctx):
        from quick_campaign import tiny

        from vtestbed.campaigns.runner import sweep
        from vtestbed.campaigns.store import SweepError

        out = _sweep_folder(ctx, manifest=text)
        return refused(lambda: sweep(tiny(), out, workers=1, progress=False), SweepError)

    return case


def _report_of_nothing(ctx):
    (ctx.tmp / "empty").mkdir()
    return cli(ctx, ["report", ctx.tmp / "empty"])


DIAGNOSIS = {"dataset": "ds", "alpha": 0.01, "noise_floor": {}, "detect": {}, "named": [], "rounds": [],
             "baseline": {}, "model": {}, "validation": {}, "identification_fit": {}}  # fmt: skip

DISCOVERY = {"scenario": "s", "seed": 1, "alpha": 0.01, "named_before": [], "rounds": []}


def _report_of(name: str, data: dict):
    """``vtestbed report`` on a folder holding only ``name`` with ``data`` (a sweep folder: a trials
    folder too, empty: the manifest is checked first)."""

    def case(ctx):
        folder = ctx.tmp / "result"
        (folder / "trials").mkdir(parents=True)
        (folder / name).write_text(json.dumps(data))
        return cli(ctx, ["report", folder])

    return case


def _identify_not_a_dataset(ctx):
    (ctx.tmp / "empty").mkdir()
    return cli(ctx, ["identify", ctx.tmp / "empty"])


NAN_T = np.eye(4).tolist()
NAN_T[0][3] = float("nan")
FAR_T = np.eye(4).tolist()
FAR_T[2][3] = 5.0
MIRROR = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()
LINES = {"cut": _cut_last_field}

CASES = {
    "setup-number": setup_text(b"5"),
    "setup-not-utf8": setup_text(b'{"robot": "kr\xe960"}'),
    "setup-not-json": setup_text(b"{robot: kr60}"),
    "setup-missing": setup_text(None),
    "setup-key-missing": setup_error(robot=KeyError),
    "setup-sensor-string": setup_error(force_sensor="ati"),
    "setup-sensor-range-nan": setup_error(force_sensor={"range_N_Nm": [330, 330, 990, 30, 30, float("nan")]}),
    "setup-sensor-range-zero": setup_error(force_sensor={"range_N_Nm": [330, 330, 990, 30, 30, 0]}),
    "setup-sensor-mount-mass-negative": setup_error(
        force_sensor={"range_N_Nm": [330, 330, 990, 30, 30, 30], "mount_side_mass_kg": -0.45}
    ),
    "setup-sensor-mount-com-short": setup_error(
        force_sensor={
            "range_N_Nm": [330, 330, 990, 30, 30, 30],
            "mount_side_mass_kg": 0.45,
            "mount_side_com_m": [0, 0.013],
        }
    ),
    "setup-sensor-noise-above-range": setup_error(
        force_sensor={
            "range_N_Nm": [330, 330, 990, 30, 30, 30],
            "noise_std_N_Nm": [0.06, 0.06, 0.06, 0.002, 0.002, 45],
        }
    ),
    "setup-edge-string": setup_error(block_edge_m="big"),
    "setup-edge-negative": setup_error(block_edge_m=-0.08),
    "setup-transform-ragged": setup_error(
        block_in_flange=[[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    ),
    "setup-transform-nan": setup_error(block_in_flange=NAN_T),
    "setup-transform-far": setup_error(block_in_flange=FAR_T),
    "setup-transform-mirrored": setup_error(sensor_in_flange=MIRROR),
    "setup-robot-number": setup_error(robot=5),
    "setup-robot-unknown": setup_error(robot="kr6_r900"),
    "setup-format-unknown": setup_error(format="vtestbed-dataset/9"),
    "setup-convention": setup_error(angle_convention="kuka"),
    "tests-row-short": csv_lines(_cut_last_field),
    "tests-row-long": csv_lines(lambda lines: ("\n".join([*lines[:4], lines[4] + ",extra"]) + "\n").encode()),
    "tests-not-utf8": csv_lines(lambda lines: "\n".join(lines).encode() + b"\n\xff\xfe,1\n"),
    "tests-missing": _missing_tests,
    "tests-word": row_error(2, q3_deg="ninety"),
    "tests-not-finite": row_error(0, loaded_Fx_N="1e400"),
    "tests-scanner-mm": row_error(1, scanner_x_m="334"),
    "tests-scanner-deg": row_error(1, scanner_rz_rad="-108.7"),
    "tests-empty-id": row_error(3, test_id=" "),
    "tests-duplicate-id": row_error(2, test_id="T001"),
    "tests-group": row_error(2, group="calibration"),
    "tests-overload": row_error(0, sensor_range=RANGE, unloaded_Fz_N="-901.5"),
    "tests-cloud-absolute": row_error(1, cloud_loaded="/etc/passwd"),
    "tests-cloud-escapes": row_error(1, cloud_unloaded="clouds/../../x.ply"),
    "tests-cloud-missing": _missing_cloud,
    "repeats-cloud-outside": _repeats("test_id,repeat,cloud\nT000,1,/tmp/x.ply\n"),
    "repeats-own-scan": _repeats("test_id,repeat,cloud\nT000,1,clouds/T0_u.ply\n"),
    "repeats-cloud-twice": _repeats("test_id,repeat,cloud\nT000,1,clouds/r.ply\nT001,1,clouds/r.ply\n"),
    "loaded-repeats-own-scan": _loaded_repeats("test_id,repeat,cloud\nT000,1,clouds/T0_l.ply\n"),
    "gls-floor-few-repeats": _gls_floor_on_few_repeats,
    "identify-reference-no-repeats": _reference_mean_without_repeats,
    "truth-not-json": _truth('{"stiffness_true_Nm_per_rad": [1, 2'),
    "truth-number": _truth("3.5"),
    "truth-stiffness-nan": _truth('{"stiffness_true_Nm_per_rad": [1e9, NaN]}'),
    "truth-stiffness-range": _truth('{"stiffness_true_Nm_per_rad": [5, 1e9]}'),
    "truth-tests-list": _truth('{"stiffness_true_Nm_per_rad": [1e9], "tests": [1]}'),
    "truth-test-record": _truth('{"stiffness_true_Nm_per_rad": [1e9], "tests": {"T001": 5}}'),
    "truth-fingerprint": _truth('{"stiffness_true_Nm_per_rad": [1e9], "scenario_fingerprint": 7}'),
    "truth-joint-names": _truth('{"stiffness_true_Nm_per_rad": [1e9], "joint_names": [1]}'),
    "truth-effects": _truth('{"stiffness_true_Nm_per_rad": [1e9], "effects": 5}'),
    "identify-not-a-dataset": _identify_not_a_dataset,
    "sweep-part-truncated": _parquet_part,
    "sweep-part-foreign": _foreign_part,
    "sweep-manifest-not-json": _manifest('{"fingerprint": 1'),
    "sweep-manifest-plans": _manifest(json.dumps({"fingerprint": "x", "plans": [1]})),
    "report-empty-folder": _report_of_nothing,
    "tests-column-twice": csv_lines(_column_twice),
    "tests-loaded-scan-twice": _tests_edit(_copied_row),
    "tests-unloaded-scan-other-pose": _tests_edit(_other_pose_unloaded),
    "repeats-other-test-scan": _repeats("test_id,repeat,cloud\nT000,1,clouds/T1_u.ply\n"),
    "repeats-loaded-repeat-too": _both_repeat_files,
    "report-diagnosis-field-type": _report_of("report.json", DIAGNOSIS | {"named": 5}),
    "report-diagnosis-field-deep": _report_of("report.json", DIAGNOSIS),
    "report-discovery-field-type": _report_of("discover.json", DISCOVERY | {"named_before": 5}),
    "report-discovery-field-deep": _report_of("discover.json", DISCOVERY | {"rounds": [{"round": 1}]}),
    "report-campaign-field-type": _report_of(
        "campaign.json", {"scenario": "s", "joint_names": [], "campaign": 5}
    ),
    "setup-nested-deep": setup_text(b"[" * 100_000 + b"]" * 100_000),
    "setup-unknown-key": setup_error(block_edge=0.08),
    "setup-target-kind": setup_error(target={"kind": "sphere"}),
}


@pytest.mark.parametrize("key", sorted(set(ROWS) | set(CASES)))
def test_documented_message_is_the_codes(key, tmp_path, capsys):
    run_row(CASES, ROWS, key, Ctx(tmp_path, capsys))
