"""Plausibility checks: each flags exactly the test whose readings no wire load could produce."""

import numpy as np
import pytest

from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import TestMeasurement
from vtestbed.researcher.plausibility import (
    WIRE_LINE_MAX_M,
    far_tests,
    off_block_tests,
    opposite_tests,
    plausibility_notes,
    screen,
    wire_line_distance,
)

K_TABLE5 = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7]) / 1000.0  # N*m/rad


def _tests(robot, lab, count: int, seed: int = 3) -> list[TestMeasurement]:
    """Wire loads through a hook on the block and the paper model's exact displacement."""
    rng = np.random.default_rng(seed)
    kin = ArmKinematics(robot, lab.block_in_flange)
    out = []
    for i in range(count):
        q = robot.random_pose(rng, margin=0.2)
        jac = kin.jacobian(q, frame="tool")
        hook = rng.uniform(0.0, lab.block.edge, 3)  # a point of the block, B axes [m]
        force = rng.normal(size=3)
        force *= 200.0 / np.linalg.norm(force)
        wrench = np.concatenate([force, np.cross(hook, force)])
        disp = jac @ ((jac.T @ wrench) / K_TABLE5)
        out.append(TestMeasurement(f"T{i:03d}", "identification", q, wrench, disp, jac, np.eye(4), np.eye(4)))
    return out


def _with(m: TestMeasurement, **changes) -> TestMeasurement:
    return TestMeasurement(**{**m.__dict__, **changes})


def test_wire_line_distance_is_the_hook_offset_across_the_force():
    hook, force = np.array([0.1, 0.2, 0.05]), np.array([0.0, 0.0, -200.0])
    wrench = np.concatenate([force, np.cross(hook, force)])
    assert wire_line_distance(wrench) == pytest.approx(np.hypot(0.1, 0.2), rel=1e-14)
    assert wire_line_distance(np.array([0, 0, 0, 1.0, 0, 0])) == np.inf


def test_clean_tests_pass_every_check(robot, lab):
    tests = _tests(robot, lab, 12)
    assert plausibility_notes(tests) == [] and screen(tests) == {}
    assert max(wire_line_distance(m.wrench) for m in tests) <= np.sqrt(3) * lab.block.edge + 1e-12


def test_each_check_names_only_its_broken_test(robot, lab):
    tests = _tests(robot, lab, 12)
    c = 1.0 / K_TABLE5
    swapped = _with(tests[2], displacement=-tests[2].displacement)  # loaded and unloaded scans swapped
    huge = _with(tests[5], displacement=12.0 * tests[5].displacement)  # 12x what the load causes
    just = _with(tests[6], displacement=8.0 * tests[6].displacement)  # large but below FAR_FACTOR
    torque_mm = _with(tests[8], wrench=np.concatenate([tests[8].wrench[:3], 1e3 * tests[8].wrench[3:]]))
    broken = [*tests[:2], swapped, *tests[3:5], huge, just, tests[7], torque_mm, *tests[9:]]
    assert opposite_tests(broken, c) == ["T002"]
    assert far_tests(broken, c) == ["T005"]
    assert off_block_tests(broken) == ["T008"]
    assert wire_line_distance(torque_mm.wrench) > WIRE_LINE_MAX_M
    notes = plausibility_notes(broken)  # judged by leave-one-out fits, not by the exact c
    assert [n.split(":")[0] for n in notes] == ["tests T002", "tests T005", "tests T008"]


@pytest.mark.parametrize("factor", [12.0, 50.0, -3.0])
def test_a_gross_outlier_is_named_although_it_spoils_the_joint_fit(robot, lab, factor):
    """A fit to all tests is dragged by the outlier (its compliances may turn negative); the
    screen judges each test by the other tests' fit and names only the broken one."""
    import warnings

    from vtestbed.researcher.measure import identify_measurements

    tests = _tests(robot, lab, 20)
    broken = [*tests[:5], _with(tests[5], displacement=factor * tests[5].displacement), *tests[6:]]
    assert screen(broken) == {"T005": "far" if factor > 0 else "opposite"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = identify_measurements(broken, joint_names=robot.joint_names)
    named = [w for w in result.warnings if w.startswith("tests T005: the block moved")]
    assert len(named) == 1 and not any(w.startswith("tests T0") and "T005" not in w for w in result.warnings)


def test_two_outliers_are_both_named(robot, lab):
    tests = _tests(robot, lab, 20, seed=11)
    broken = list(tests)
    broken[3] = _with(tests[3], displacement=30.0 * tests[3].displacement)
    broken[14] = _with(tests[14], displacement=-tests[14].displacement)
    assert screen(broken) == {"T003": "far", "T014": "opposite"}


def test_no_prediction_without_positive_compliances(robot, lab):
    tests = _tests(robot, lab, 4)
    flipped = [_with(m, displacement=-m.displacement) for m in tests]
    assert opposite_tests(flipped, -1.0 / K_TABLE5) == []  # a failed fit predicts nothing
    assert opposite_tests(flipped, 1.0 / K_TABLE5) == [m.test_id for m in tests]


def test_swapped_scans_warn_and_strict_refuses_through_the_command(tmp_path, capsys):
    """A real simulated dataset with one test's loaded and unloaded clouds swapped in tests.csv."""
    import csv

    from conftest import paper_scenario_data

    from vtestbed.cli.main import main
    from vtestbed.experiment import simulate
    from vtestbed.scenario import parse_scenario

    out = tmp_path / "ds"
    simulate(parse_scenario(paper_scenario_data(8, 1, "swap", 5)), out, progress=False)
    rows = list(csv.reader((out / "tests.csv").open()))
    header = rows[0]
    u, lo = header.index("cloud_unloaded"), header.index("cloud_loaded")
    rows[3][u], rows[3][lo] = rows[3][lo], rows[3][u]
    with (out / "tests.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    swapped = rows[3][0]

    assert main(["identify", str(out), "--quiet", "--no-truth"]) == 0
    printed = capsys.readouterr()
    note = f"warning: tests {swapped}: the block moved against the load"
    assert (printed.out + printed.err).count(note) == 1  # once, in words
    assert main(["identify", str(out), "--quiet", "--no-truth", "--strict"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"implausible measurements (--strict): tests {swapped}: the block moved against the load" in err
