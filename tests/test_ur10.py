"""A second robot end to end: the UR10 (models/ur10, imported from a URDF) in its own lab.

scenarios/ur10_paper.toml (the paper's method), ur10_ideal.toml (perfect sensors) and
ur10_sweep_quick.toml (the quick campaign) are written by vtestbed.campaigns.paper_set.
References: the truth file read here with tomllib, the criterion rebuilt from Pinocchio's
Jacobian at a least-squares wrist point solved here, the lab's limits, and the seeds' own
z-scores against the normal distribution.
"""

import json
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from vtestbed.campaigns import paper_set
from vtestbed.campaigns.montecarlo import measure_trial, prepare
from vtestbed.design.clearance import NominalClearance
from vtestbed.errors import OutOfRangeError, ScenarioError
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import identify_measurements
from vtestbed.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"
ROBOT = "ur10"
SEEDS = 50  # the std of a z-score std over N seeds is about 1/sqrt(2N) = 10 %


def _k_true() -> np.ndarray:
    """The true stiffness [N*m/rad], read from the truth file itself."""
    data = tomllib.loads((ROOT / "models" / ROBOT / "truth.toml").read_text())
    return np.array([j["stiffness_Nm_per_rad"] for j in data["joints"]])


def test_ideal_run_recovers_the_truth_within_half_a_percent(tmp_path):
    from vtestbed.cli.main import main

    # `vtestbed run`, as a user types it; its result.json holds the comparison with the truth
    argv = ["run", str(SCENARIOS / f"{ROBOT}_ideal.toml"), "--out", str(tmp_path), "--no-figures", "--quiet"]
    assert main(argv) == 0
    summary = json.loads((tmp_path / "result.json").read_text())
    k_est = np.array([j["k_est"] for j in summary["joints"]])
    bias = k_est / _k_true() - 1
    print(f"\n{ROBOT} ideal bias per joint [%]: {np.round(bias * 100, 3)}")
    assert np.all(np.abs(bias) < 5e-3)  # measured: at most 0.14 % (joint 2)
    assert summary["n_tests"] == 20 and len(summary["validation"]) == 5
    # perfect sensors: the validation displacements are predicted to about 1 %
    worst = max(max(v["rel_err_translation"], v["rel_err_rotation"]) for v in summary["validation"])
    assert worst < 0.02, worst


def _wrist_point_by_hand(frames) -> np.ndarray:
    """The point nearest (least squares) to the axes of joints 4, 5, 6 (z of DH frames 4-6)."""
    m, b = np.zeros((3, 3)), np.zeros(3)
    for f in frames[3:6]:
        p = np.eye(3) - np.outer(f[:3, 2], f[:3, 2])
        m, b = m + p, b + p @ f[:3, 3]
    return np.linalg.solve(m, b)


def test_the_paper_scenarios_tests_meet_the_papers_rules_in_the_ur10_lab():
    scenario = load_scenario(SCENARIOS / f"{ROBOT}_paper.toml")
    robot, lab = scenario.robot, scenario.lab
    kin = ArmKinematics(robot, lab.block_in_flange)
    nominal = NominalClearance(robot, lab, scenario.scanner.distance)
    comments = [
        line.split("#")[1].split()
        for line in (SCENARIOS / f"{ROBOT}_paper.toml").read_text().splitlines()
        if "inv_kappa" in line and line.lstrip().startswith("[")
    ]
    assert len(comments) == scenario.n_tests == 20
    for q, hook, ring, note in zip(scenario.poses, scenario.load.hooks, scenario.load.anchors, comments):
        assert np.degrees(q[0]) == pytest.approx(0.0, abs=1e-9) and np.degrees(q[5]) == pytest.approx(45.0)
        assert nominal.check(q, hook, ring).ok and note[3:] == [hook, ring]
        # the criterion at the least-squares wrist point from Pinocchio's Jacobian (docs/poses.md)
        frames = kin.joint_poses(q)
        point = _wrist_point_by_hand(frames)
        tool = np.eye(4)
        tool[:3, 3] = (np.linalg.inv(kin.flange_pose(q)) @ np.append(point, 1.0))[:3]
        jac = kin.jacobian(q, tool_in_flange=tool)
        inv_kappa = np.prod([3.0 / (np.linalg.norm(b) * np.linalg.norm(np.linalg.inv(b)))
                             for b in (jac[:3, :3], jac[3:, 3:])])  # fmt: skip
        assert inv_kappa >= 0.7 and float(note[2]) == pytest.approx(inv_kappa, abs=5e-4)
    low, high = lab.tension_range_N
    assert all(low <= t <= high for t in scenario.load.tensions + scenario.validation_load.tensions)
    assert high == pytest.approx(10.0 * 9.81)  # the UR10's rated payload of 10 kg as a force
    low, high = lab.scanner_distance_range_m()  # the block's corners in the measuring depth
    assert (
        lab.scanner.working_distance_m[0]
        < low
        <= scenario.scanner.distance
        <= high
        < lab.scanner.working_distance_m[1]
    )


def test_the_ideal_and_quick_files_share_the_paper_files_tests():
    paper, ideal = (load_scenario(SCENARIOS / f"{ROBOT}_{v}.toml") for v in ("paper", "ideal"))
    quick = tomllib.loads((SCENARIOS / f"{ROBOT}_sweep_quick.toml").read_text())
    assert np.array_equal(paper.poses, ideal.poses) and paper.load == ideal.load
    assert np.array_equal(paper.validation_poses, ideal.validation_poses)
    assert quick["poses"] == tomllib.loads((SCENARIOS / f"{ROBOT}_paper.toml").read_text())["poses"]
    assert ideal.scanner.noise_model is None and not any(ideal.force_sensor.noise_std)


@pytest.mark.slow
def test_the_committed_files_are_what_the_generator_writes():
    drawn = paper_set.draw(paper_set.SPECS[ROBOT])
    for variant in paper_set.VARIANTS:
        committed = (SCENARIOS / f"{ROBOT}_{variant}.toml").read_text()
        assert paper_set.render(drawn, variant) == committed, f"regenerate: python -m {paper_set.__name__}"


@pytest.mark.slow
def test_k_std_is_honest_over_50_seeds():
    prepared = prepare(load_scenario(SCENARIOS / f"{ROBOT}_paper.toml"))
    k_true = _k_true()
    z = []
    for seed in range(SEEDS):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify_measurements(measure_trial(prepared, 7000 + seed), "fgls")
        z.append((res.stiffness - k_true) / res.stiffness_std)
    z_std, z_mean = np.std(z, axis=0, ddof=1), np.mean(z, axis=0)
    print(
        f"\n{ROBOT} z-score std per joint ({SEEDS} seeds): {np.round(z_std, 3)}; mean {np.round(z_mean, 3)}"
    )
    assert np.all((z_std >= 0.8) & (z_std <= 1.25))
    # unbiased within the scatter: a mean z of N(0, 1) draws has std 1/sqrt(50) = 0.14
    assert np.all(np.abs(z_mean) < 0.6)


@pytest.mark.slow
def test_the_quick_campaign_runs(tmp_path):
    from vtestbed.campaigns import load_campaign, sweep

    trials = sweep(
        load_campaign(SCENARIOS / f"{ROBOT}_sweep_quick.toml"), tmp_path, workers=1, progress=False
    )
    assert len(trials) == 40 and (trials["status"] == "ok").all()
    joints = [f"joint{i}" for i in range(1, 7)]
    assert np.allclose(trials[[f"k_true_{j}" for j in joints]].to_numpy(), _k_true())
    err = [f"err_{j}" for j in joints]
    rms = trials.groupby(["pose_set", "n_tests", "scanner_noise_scale"])[err].apply(
        lambda e: np.sqrt((e**2).mean())
    )
    for pose_set in ("scenario", "kappa_regions"):  # on every joint, common random numbers:
        for n in (4, 8):  # 4x the scanner noise, larger errors
            assert np.all(rms.loc[(pose_set, n, 2.0)] > rms.loc[(pose_set, n, 0.5)]), (pose_set, n)
        for noise in (0.5, 2.0):  # twice the tests, smaller errors
            assert np.all(rms.loc[(pose_set, 8, noise)] < rms.loc[(pose_set, 4, noise)]), (pose_set, noise)
    # the scenario's own 8 tests at half the paper's noise: RMS error within 5 % (measured: 0.2-2.6 %)
    assert np.all(rms.loc[("scenario", 8, 0.5)] < 0.05)


# The UR10's lab scale (docs/lab.md): its reach a2 + a3 + |(d5, d6)| over the KR60's
# a2 + |(a3, d4)| + d6, about the shoulder point (0, 0, d1) instead of (0.35, 0, 0.815) m.
SCALE = (0.612 + 0.5723 + np.hypot(0.1157, 0.0922)) / (0.85 + np.hypot(0.145, 0.82) + 0.17)
SHOULDER_Z = 0.1273


def test_a_campaigns_pose_set_defaults_come_from_its_robots_lab():
    from vtestbed.campaigns.spec import PoseSetOptions, parse_campaign

    data = tomllib.loads((SCENARIOS / f"{ROBOT}_sweep_quick.toml").read_text())
    del data["campaign"]["pose_sets"]["tension_N"]
    opts = parse_campaign(data, "quick.toml").pose_sets
    assert opts.tension_N == pytest.approx(10.0 * 9.81 / 2)  # half the rated payload's force
    assert opts.min_height_m == pytest.approx(SHOULDER_Z + SCALE * (0.8 - 0.815), abs=1e-8)  # 0.117 m
    box = [SCALE * (v - 0.35) for v in (0.3, 2.3)]  # x about the shoulder; z from the floor
    np.testing.assert_allclose(np.array(opts.box_m)[[0, 3]], box, atol=1e-8)
    assert opts.box_m[2] == 0.0 and opts.box_m[5] == pytest.approx(SHOULDER_Z + SCALE * (2.2 - 0.815))
    # the paper's robot keeps the paper's defaults exactly (its campaigns' fingerprints unchanged)
    kr60 = tomllib.loads((SCENARIOS / "kr60_sweep_quick.toml").read_text())
    assert parse_campaign(kr60, "kr60.toml").pose_sets == PoseSetOptions(pool=20)
    # a tension above the robot's limit names the field and the range
    data["campaign"]["pose_sets"]["tension_N"] = 150.0
    with pytest.raises(ScenarioError, match=r"campaign.pose_sets.tension_N: .*150.* \[1, 98.1\]"):
        parse_campaign(data, "quick.toml")


def test_load_and_scan_commands_use_the_robots_lab(capsys, tmp_path):
    from vtestbed.cli.main import main

    pose = ["--robot", ROBOT, "--controller-deg", "0,-67.42,143.31,101,61.95,-135", "--anchor", "ring_3"]
    assert main(["load", *pose, "--json"]) == 0
    out = capsys.readouterr().out
    assert '"wire_tension_N": 49.05' in out  # the lab's default, half of 98.1 N
    assert main(["load", *pose, "--tension", "150"]) == 2
    err = capsys.readouterr().err
    assert "--tension = 150 N is outside the valid range [1, 98.1] N" in err and "rated payload" in err
    assert main(["scan", *pose, "--out", str(tmp_path), "--noise-free"]) == 0
    assert f"at {0.6 * SCALE * 1e3:.6g} mm" in capsys.readouterr().out  # the lab's stand-off, 431 mm


def test_the_generator_refuses_bad_input_with_the_valid_range(capsys):
    assert paper_set.main(["ur5"]) == 2
    assert "unknown robot 'ur5'; valid names: ur10" in capsys.readouterr().err
    with pytest.raises(OutOfRangeError, match=r"PaperSetSpec\('ur10'\).tension_N = 150 N .* \[1, 98.1\] N"):
        paper_set.draw(paper_set.PaperSetSpec(ROBOT, tension_N=150.0))  # above the rated payload's force
