"""docs/errors.md, rows of measurements that cannot be right and of scans that cannot be made:
a small simulated dataset with one row of its tests.csv edited, given to the real ``vtestbed
identify``; tests built from the real kinematics (a wire load on the block and the paper model's
exact displacement, as in tests/test_researcher_plausibility.py) broken one way and identified by
the researcher's code; the scanner placed where it cannot see the block, through ``vtestbed scan``."""

from __future__ import annotations

import csv
import json
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from errors_table import Ctx, cli, refused, run_row, section_rows
from test_researcher_plausibility import _tests, _with

from vtestbed.errors import ImplausibleDataError, SingularPoseError
from vtestbed.files import dumps
from vtestbed.lab import LabSetup
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import identify_measurements
from vtestbed.robots import load_robot

ROWS = section_rows("Measurements and scans that cannot be right")


def _clean():
    robot = load_robot("kuka_kr60_3")
    return robot, _tests(robot, LabSetup(), 12)


def _broken(kind: str):
    robot, tests = _clean()
    m = tests[3]
    if kind == "opposite":  # loaded and unloaded scans swapped
        tests[3] = _with(m, displacement=-m.displacement)
    elif kind == "far":
        tests[3] = _with(m, displacement=12.0 * m.displacement)
    elif kind == "off-block":  # torques recorded in N*mm as N*m
        tests[3] = _with(m, wrench=np.concatenate([m.wrench[:3], 1e3 * m.wrench[3:]]))
    elif kind == "all-opposite":  # every test's scans swapped (or every wrench's sign flipped)
        tests = [_with(t, displacement=-t.displacement) for t in tests]
    elif kind == "singular":
        q = m.q.copy()
        q[4] = 0.0  # theta5 = 0: joints 4 and 6 aligned
        jac = ArmKinematics(robot, LabSetup().block_in_flange).jacobian(q, frame="tool")
        tests[3] = _with(m, q=q, jacobian=jac, displacement=jac @ np.linalg.pinv(jac) @ m.displacement)
    return robot, tests


def warning(kind: str):
    """A case: the note that the identification's result carries for a broken test."""

    def case(ctx: Ctx) -> str:
        robot, tests = _broken(kind)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = identify_measurements(tests, joint_names=robot.joint_names)
        notes = [w for w in result.warnings if w.startswith("tests T")]
        assert len(notes) == 1, result.warnings
        return notes[0]

    return case


def error(kind: str, expected, strict: bool = False):
    def case(ctx: Ctx) -> str:
        robot, tests = _broken(kind)
        return refused(
            lambda: identify_measurements(tests, joint_names=robot.joint_names, strict=strict), expected
        )

    return case


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A small simulated dataset (8 + 1 tests of the paper's scenario, about 4 s), read-only."""
    from conftest import paper_scenario_data

    from vtestbed.experiment import simulate
    from vtestbed.scenario import parse_scenario

    out = tmp_path_factory.mktemp("errors_table") / "ds"
    simulate(parse_scenario(paper_scenario_data(8, 1, "errors_table", 5)), out, progress=False)
    return out


def _swap(row):
    row["cloud_loaded"], row["cloud_unloaded"] = row["cloud_unloaded"], row["cloud_loaded"]


def _same_scan(row):
    row["cloud_loaded"] = row["cloud_unloaded"]


def _same_scan_copied(ctx: Ctx) -> Path:
    """The simulated dataset with its fourth test's unloaded PLY copied as its loaded scan (a file of
    its own: the reader's check that no scan is listed twice cannot see it, the fit can)."""
    root = _edited(ctx, lambda row: row.update(cloud_loaded="clouds/T004_copy.ply"))
    shutil.copy(root / "clouds" / "T004_unloaded.ply", root / "clouds" / "T004_copy.ply")
    return root


def _slack(row):
    for key in [k for k in row if k.startswith("loaded_")]:
        row[key] = row[key.replace("loaded_", "unloaded_")]


def _edited(ctx: Ctx, edit):
    """A copy of the simulated dataset with its fourth test's row changed by ``edit(row)``."""
    root = ctx.tmp / "ds"
    shutil.copytree(ctx.shared, root)
    with (root / "tests.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    edit(rows[3])
    with (root / "tests.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return root


def identify_warning(edit=None, make=None):
    """A case: ``vtestbed identify`` on an edited dataset, exit 0 and one warning naming the test
    (``edit``: the fourth row's edit; ``make``: a function of ``ctx`` that returns the dataset)."""

    def case(ctx: Ctx) -> str:
        from vtestbed.cli.main import main

        root = make(ctx) if make is not None else _edited(ctx, edit)
        ctx.capsys.readouterr()
        assert main(["identify", str(root), "--quiet", "--no-truth"]) == 0
        printed = ctx.capsys.readouterr()
        lines = (printed.out + printed.err).splitlines()
        notes = [line.split("warning: ", 1)[1] for line in lines if "warning: tests T" in line]
        assert len(notes) == 1, printed
        return notes[0]

    return case


def identify_error(edit, *options):
    """A case: ``vtestbed identify`` on an edited dataset, exit 2 and one error line."""
    return lambda ctx: cli(ctx, ["identify", _edited(ctx, edit), "--quiet", "--no-truth", *options])


def _half_edge(ctx: Ctx):
    """``vtestbed identify`` on the simulated dataset with half its block's edge in setup.json."""
    root = ctx.tmp / "ds"
    shutil.copytree(ctx.shared, root)
    setup = json.loads((root / "setup.json").read_text())
    (root / "setup.json").write_text(json.dumps(setup | {"block_edge_m": setup["block_edge_m"] / 2}))
    return cli(ctx, ["identify", root, "--quiet", "--no-truth"])


def _strict_json(ctx: Ctx) -> str:
    return dumps({"chi2": math.nan, "std": [math.inf, 2.0]}, indent=None)


def scan(*argv):
    return lambda ctx: cli(ctx, ["scan", "--out", ctx.tmp / "s", "--noise-free", *argv])


CASES = {
    "same-scan-twice": identify_warning(make=_same_scan_copied),
    "same-scan-listed-twice": identify_error(_same_scan),
    "scans-swapped": identify_warning(_swap),
    "moved-too-far": warning("far"),
    "off-block-wrench": warning("off-block"),
    "strict": identify_error(_swap, "--strict"),
    "strict-library": error("opposite", ImplausibleDataError, strict=True),
    "strict-all-opposite": error("all-opposite", ImplausibleDataError, strict=True),
    "slack-wire": identify_error(_slack),
    "edge-too-small": _half_edge,
    "singular-in-dataset": error("singular", SingularPoseError),
    "scan-faces-hidden": scan("--view", "1,1,-0.2"),
    "scan-too-close": scan("--distance-mm", "100"),
    "scan-too-far": scan("--distance-mm", "2000"),
    "strict-json": _strict_json,
}
SIMULATED = (
    "same-scan-twice",
    "same-scan-listed-twice",
    "scans-swapped",
    "strict",
    "slack-wire",
    "edge-too-small",
)


@pytest.mark.parametrize("key", sorted(set(ROWS) | set(CASES)))
def test_documented_message_is_the_codes(key, tmp_path, capsys, request):
    shared = request.getfixturevalue("simulated") if key in SIMULATED else None
    run_row(CASES, ROWS, key, Ctx(tmp_path, capsys, shared))
