import copy
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from vtestbed.errors import ScenarioError
from vtestbed.robots import available_robots
from vtestbed.scenario import load_scenario, parse_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.fixture(scope="module")
def paper_data():
    return tomllib.loads((SCENARIOS / "kr60_paper.toml").read_text())


def test_shipped_scenarios_load(paper_data):
    paper = load_scenario(SCENARIOS / "kr60_paper.toml")
    ideal = load_scenario(SCENARIOS / "kr60_ideal.toml")
    assert paper.n_tests == ideal.n_tests == 20
    assert paper.validation_poses.shape == (5, 6)
    assert not ideal.scanner.noise and paper.scanner.noise
    # controller -> DH by hand: theta = A, except theta3 = A3 - 90 deg
    a = np.array(paper_data["poses"]["angles_deg"][0])
    np.testing.assert_allclose(np.degrees(paper.poses[0]), a - [0, 0, 90, 0, 0, 0], atol=1e-12)
    assert paper.load.tensions == (200.0,) * 20
    assert paper.fingerprint != ideal.fingerprint


def _broken(data, path, value):
    out = copy.deepcopy(data)
    node = out
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return out


@pytest.mark.parametrize(
    "path,value,message",
    [
        (("colour",), "red", r"colour: unknown key; valid keys: name, description, robot"),
        (("poses", "convention"), "kuka", r"poses.convention: 'kuka' is not one of dh, controller"),
        (("poses", "angles_deg"), [[0, 0, 0]], r"poses.angles_deg\[0\]: must be a list of 6 numbers"),
        (("poses", "angles_deg"), [[0, -150, 90, 0, 60, 0]], r"joint2 = -150.000 deg .*\[-135.0, 35.0\]"),
        (
            ("load", "tension_N"),
            1500.0,
            r"load.tension_N\[0\]: = 1500 N is outside the valid range \[1, 588.6\] N "
            r"\(taut, and at most 588.6 N, set by the robot's rated payload \(60 kg \* 9.81 m/s\^2\)\)$",
        ),
        (
            ("lab",),
            {"max_tension_N": 150.0, "table": {}},
            r"load.tension_N\[0\]: = 200 N .* \[1, 150\] N .* set by the lab's max_tension_N",
        ),
        (
            ("lab",),
            {"table": {"ring_x_m": [1.1, 2.4]}},
            r"lab.table.ring_x_m\[1\]: = 2.4 is off the table top; valid range \[0.9, 2.3\]",
        ),
        (("load", "anchor"), ["ring_10"], r"load.anchor\[0\]: 'ring_10' is not one of ring_1"),
        (("load", "hook"), [], r"load.hook: must not be empty"),
        (
            ("scanner", "distance_m"),
            2.0,
            r"scanner.distance_m: = 2 m is outside the valid range \[0.17, 1.18\] m",
        ),
        (("scanner", "noise"), "yes", r"scanner.noise: must be true or false"),
        (("force_sensor", "noise_std"), [0.1] * 5, r"force_sensor.noise_std: must be a list of 6 numbers"),
        (
            ("identification", "method"),
            "lasso",
            r"identification.method: 'lasso' is not one of ols, fgls",
        ),
        (("seed",), -1, r"seed: must be a non-negative integer"),
        # the valid names are the folders under models/, whichever robots they hold
        (
            ("robot",),
            "ur5",
            r"robot: unknown robot 'ur5'; valid names: " + re.escape(", ".join(available_robots())) + "$",
        ),
        (("name",), KeyError, r"name: is required"),
    ],
)
def test_malformed_scenarios_name_the_field(paper_data, path, value, message):
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(_broken(paper_data, path, value), "test.toml")


def test_unknown_scanner_noise_parameter_lists_the_valid_ones(paper_data):
    data = _broken(paper_data, ("scanner", "noise_params"), {"speckle": 0.1})
    with pytest.raises(ScenarioError, match=r"scanner.noise_params.speckle: unknown key; valid keys: "):
        parse_scenario(data, "test.toml")


@pytest.mark.parametrize(
    "key, value, message",
    [  # each parameter's own range, as the scanner's datasheet-based model states it (scan_noise.py)
        ("range_std_m", -0.1, r"range_std_m: = -0.1 m is outside the valid range \[0, 0.001\] m$"),
        ("outlier_fraction", float("nan"), r"outlier_fraction: = nan is outside the valid range \[0, 0.5\]$"),
        (
            "drift_rotation_std_rad",
            80.0,
            r"drift_rotation_std_rad: = 80 rad is outside the valid range \[0, 0.01\] rad$",
        ),
        ("grazing_exponent", "x", r"grazing_exponent: must be a number in \[0, 4\], got 'x'$"),
    ],
)
def test_scanner_noise_parameters_state_their_own_range(paper_data, key, value, message):
    data = _broken(paper_data, ("scanner", "noise_params"), {key: value})
    with pytest.raises(ScenarioError, match=rf"^test.toml: scanner.noise_params.{message}"):
        parse_scenario(data, "test.toml")


def test_file_level_errors(tmp_path):
    with pytest.raises(ScenarioError, match="does not exist"):
        load_scenario(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)


def _with_a5(paper_data, index: int, a5_deg: float) -> dict:
    data = copy.deepcopy(paper_data)
    data["poses"]["angles_deg"][index][4] = a5_deg
    return data


@pytest.mark.parametrize("a5_deg", [0.0, 0.2, -0.3])
def test_singular_pose_is_refused_at_load(paper_data, a5_deg):
    # A5 = 0 is the KR60's wrist singularity (joints 4 and 6 aligned); within about 0.33 deg of
    # it the scaled Jacobian's sigma_min/sigma_max falls below NEAR_SINGULAR.
    with pytest.raises(ScenarioError, match=r"poses\.angles_deg\[3\]: the pose is at or near a singularity"):
        parse_scenario(_with_a5(paper_data, 3, a5_deg))


def test_pose_a_degree_from_the_wrist_singularity_is_accepted(paper_data):
    assert parse_scenario(_with_a5(paper_data, 3, 1.0)).n_tests == 20


def test_jacobian_conditioning_matches_pinocchio():
    from vtestbed.lab import PAPER_LAB
    from vtestbed.researcher.kinematics import ArmKinematics
    from vtestbed.robots import JACOBIAN_LENGTH_SCALE_M, load_robot

    robot = load_robot("kuka_kr60_3")
    arm = ArmKinematics(robot, PAPER_LAB.block_in_flange)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = robot.random_pose(rng)
        jac = arm.jacobian(q)
        jac[:3] /= JACOBIAN_LENGTH_SCALE_M
        s = np.linalg.svd(jac, compute_uv=False)
        ours = robot.jacobian_conditioning(q, PAPER_LAB.block_in_flange[:3, 3])
        assert ours == pytest.approx(s[-1] / s[0], rel=1e-9, abs=1e-14)


UR10_POSE = [[0.0, -60.0, -60.0, -60.0, 60.0, 30.0]]  # DH, deg: in the limits, away from singularities


def test_a_ur10_scenario_gets_a_lab_scaled_to_its_reach():
    from vtestbed.robot_lab import lab_for_robot

    scenario = parse_scenario({"name": "u", "robot": "ur10", "poses": {"angles_deg": UR10_POSE}})
    scale = (0.612 + 0.5723 + np.hypot(0.1157, 0.0922)) / (0.85 + np.hypot(0.145, 0.82) + 0.17)
    assert scenario.lab == lab_for_robot(scenario.robot)
    assert scenario.scanner.distance == pytest.approx(0.6 * scale, abs=1e-8)  # the lab's stand-off
    # default tension: half the UR10's 10 kg * 9.81 m/s^2, below the paper's 200 N
    assert scenario.load.tensions == (pytest.approx(49.05, abs=1e-12),)


@pytest.mark.parametrize(
    "extra, message",
    [
        ({"load": {"tension_N": 200.0}}, r"load.tension_N\[0\]: = 200 N .* \[1, 98.1\] N .* rated payload \(10 kg"),
        ({"lab": {"table": {"center_m": [1.6, 0.0], "ring_x_m": [1.1, 1.6, 2.1]}}},
         r"u.toml: lab.table.ring_x_m\[1\], ring_y_m\[0\]: ring_4 .* beyond the wire's reach; valid: at most 1.450 m"),
        ({"scanner": {"distance_m": 0.05}}, r"scanner.distance_m: = 0.05 m is outside the valid range \[0.17, 1.18\] m"),
    ],
)  # fmt: skip
def test_a_ur10_scenario_outside_its_lab_names_the_field(extra, message):
    data = {"name": "u", "robot": "ur10", "poses": {"angles_deg": UR10_POSE}, **extra}
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(data, "u.toml")


def test_a_stand_off_inside_the_working_distance_but_not_the_blocks_is_refused_at_load(paper_data):
    """D11: 1.25 m is the datasheet's far limit, but the paper's 80 mm block reaches 0.0693 m
    (0.04 * sqrt(3)) behind its centre, so every test's scan would fail; the file is refused when
    read, naming the file, the field, the value and the range that works (checked against the
    scanner's own placement in tests/test_world_scanner.py)."""
    half = 0.04 * np.sqrt(3)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(_broken(paper_data, ("scanner", "distance_m"), 1.25), "paper.toml")
    assert str(exc.value).startswith(
        "paper.toml: scanner.distance_m: = 1.25 m is outside the valid range [0.17, 1.18] m: the block's "
        "corners must all lie within the TECHLEGO VTOP 200B's working distance [0.1, 1.25] m, and they lie "
        f"up to {half:.4f} m in front of"
    )
    for ok in (1.18, 0.17):  # the range's ends, rounded inward from 0.1 + 0.0693 and 1.25 - 0.0693
        assert parse_scenario(_broken(paper_data, ("scanner", "distance_m"), ok)).scanner.distance == ok
    bigger = _broken(paper_data, ("lab",), {"block": {"edge_m": 0.12}})  # corners 0.1039 m out
    with pytest.raises(
        ScenarioError, match=r"scanner.distance_m: = 1.18 m is outside the valid range \[0.204, 1.146\] m"
    ):
        parse_scenario(_broken(bigger, ("scanner", "distance_m"), 1.18), "paper.toml")
    without = _broken(
        _broken(bigger, ("scanner", "distance_m"), KeyError), ("lab",), {"block": {"edge_m": 0.173}}
    )
    assert parse_scenario(without).scanner.distance == 0.6  # the lab's default fits
    deep = _broken(paper_data, ("lab",), {"block": {"edge_m": 0.2}})
    with pytest.raises(ScenarioError, match=r"^paper.toml: lab.block.edge_m: no scanner.distance_m can scan a block "
                       r"of edge 0.2 m: .*; valid: a block edge of at most 0.173 m$"):  # fmt: skip
        parse_scenario(deep, "paper.toml")
