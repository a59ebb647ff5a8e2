"""The generated pose sets of a campaign: feasible in the truth world, nested, deterministic,
and their test plans' files exact; plan quality against the information matrix by hand."""

import json
import re

import numpy as np
import pytest
from quick_campaign import campaign_data

from vtestbed.campaigns import montecarlo, posesets
from vtestbed.campaigns.spec import parse_campaign
from vtestbed.design import kappa
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.researcher.kinematics import ArmKinematics


@pytest.fixture(scope="module")
def generated():
    data = campaign_data(axes={"pose_set": ["kappa_regions", "random", "design_optimal"], "n_tests": [3, 4]})
    data["campaign"]["pose_sets"] = {"pool": 12}
    c = parse_campaign(data)
    keys = {c.plan_key(x) for x in c.cells()}
    return c, posesets.build_plans(c, keys)


def test_generated_pose_sets_are_feasible_and_deterministic(generated):
    c, plans = generated
    assert set(plans) == {"kappa_regions:4", "random:4", "design_optimal:3", "design_optimal:4"}
    robot = c.scenario.robot
    # every test prepares in the truth world (montecarlo.prepare raises otherwise)
    prepared = montecarlo.prepare(plans["random:4"].scenario(c.scenario))
    assert len(prepared.tests) == 4
    # same seed, same sets; a longer nested set starts with the shorter one
    again = posesets.build_plans(c, ["kappa_regions:3", "random:3"])
    for name in ("kappa_regions", "random"):
        assert again[f"{name}:3"].digest == plans[f"{name}:4"].head(3).digest
    # kappa poses meet the threshold; random poses are inside the limits and the lab box
    k = kappa.inv_kappa_batch(robot, plans["kappa_regions:4"].q, "wrist")
    assert np.all(k >= c.pose_sets.threshold)
    q = plans["random:4"].q
    assert np.all((q >= robot.lower) & (q <= robot.upper))
    assert np.all(posesets.lab_constraints(c.pose_sets).ok(robot, q))
    # JSON round trip is exact
    plan = plans["design_optimal:4"]
    back = posesets.TestPlan.from_dict(plan.to_dict())
    assert np.array_equal(back.q, plan.q) and back.digest == plan.digest


def test_design_optimal_beats_the_kappa_rule_on_its_own_criterion(generated):
    c, plans = generated
    robot = c.scenario.robot
    d = {
        n: posesets.plan_quality(
            robot, plans[f"design_optimal:{n}"], n, c.scenario.lab, PAPER_TABLE5.stiffness
        )["d_log_det_rel"]
        for n in (3, 4)
    }
    kappa = posesets.plan_quality(robot, plans["kappa_regions:4"], 4, c.scenario.lab, PAPER_TABLE5.stiffness)[
        "d_log_det_rel"
    ]
    assert d[4] >= kappa and d[4] > d[3]
    assert plans["design_optimal:4"].notes["criterion_value"] == pytest.approx(d[4], rel=1e-9)
    # its poses come from the kappa pool (same seeded stream as kappa_regions)
    pool = posesets.kappa_pool(robot, c.pose_sets, c.pose_set_rng("kappa_regions")).q
    for q in plans["design_optimal:4"].q:
        assert np.min(np.abs(pool - q).max(axis=1)) == 0.0


def test_plan_files_round_trip_exactly_through_json_text(generated):
    _, plans = generated
    for plan in plans.values():
        text = json.dumps(plan.to_dict())
        back = posesets.TestPlan.from_dict(json.loads(text))
        assert np.array_equal(back.q, plan.q) and back.q.dtype == float  # floats as reprs: bit-exact
        assert (back.pose_set, back.hooks, back.anchors, back.tensions) == (
            plan.pose_set, plan.hooks, plan.anchors, plan.tensions
        )  # fmt: skip
        assert back.notes == json.loads(json.dumps(plan.notes)) and back.digest == plan.digest


def test_head_is_the_first_n_tests_and_the_digest_ignores_notes():
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, (5, 6))
    hooks, rings = (
        ("hook_x", "hook_y", "hook_edge", "hook_x", "hook_y"),
        tuple(f"ring_{i}" for i in range(1, 6)),
    )
    plan = posesets.TestPlan("random", q, hooks, rings, (200.0, 210.0, 220.0, 230.0, 240.0), {"a": 1})
    head = plan.head(3)
    assert len(head) == 3 and np.array_equal(head.q, q[:3])
    assert head.hooks == hooks[:3] and head.anchors == rings[:3] and head.tensions == (200.0, 210.0, 220.0)
    same = posesets.TestPlan("random", q.copy(), hooks, rings, plan.tensions, {"other": "notes"})
    assert same.digest == plan.digest and len(plan.digest) == 16
    moved = q.copy()
    moved[4, 2] = np.nextafter(moved[4, 2], 1.0)  # one ulp in one angle
    assert posesets.TestPlan("random", moved, hooks, rings, plan.tensions).digest != plan.digest


def test_a_plan_becomes_the_scenarios_identification_tests(generated):
    c, plans = generated
    plan = plans["random:4"]
    scen = plan.scenario(c.scenario)
    assert np.array_equal(scen.poses, plan.q) and scen.n_tests == 4
    assert scen.load.hooks == plan.hooks and scen.load.anchors == plan.anchors
    assert scen.validation_poses.shape == (0, 6) and scen.seed == c.scenario.seed


def _inv_kappa_by_hand(kin, q):
    """1/kappa_F(J11) * 1/kappa_F(J22) at the wrist centre from Pinocchio's Jacobian."""
    wrist_in_flange = np.linalg.inv(kin.flange_pose(q)) @ kin.joint_poses(q)[4]
    jac = kin.jacobian(q, tool_in_flange=wrist_in_flange)
    return np.prod(
        [3.0 / (np.linalg.norm(m) * np.linalg.norm(np.linalg.inv(m))) for m in (jac[:3, :3], jac[3:, 3:])]
    )


def test_plan_quality_against_the_information_matrix_by_hand(generated):
    c, plans = generated
    robot, lab = c.scenario.robot, c.scenario.lab
    plan = plans["kappa_regions:4"]
    quality = posesets.plan_quality(robot, plan, 4, lab, PAPER_TABLE5.stiffness)
    kin = ArmKinematics(robot, lab.block_in_flange)
    info = np.zeros((6, 6))
    w = np.diag([1 / 5.3e-6**2] * 3 + [1 / 8.5e-6**2] * 3)  # the design's default displacement noise
    for q, hook, ring, tension in zip(plan.q, plan.hooks, plan.anchors, plan.tensions):
        block = kin.tool_pose(q)
        hook_w = block[:3, :3] @ lab.block.hook(hook) + block[:3, 3]
        force = tension * (lab.table.anchor(ring) - hook_w) / np.linalg.norm(lab.table.anchor(ring) - hook_w)
        wrench = np.r_[force, np.cross(hook_w - block[:3, 3], force)]
        jac = kin.jacobian(q, frame="base")
        a = jac @ np.diag(jac.T @ wrench)  # d = A c: A[:, j] = J[:, j] (J^T F)_j
        info += a.T @ w @ a
    s = np.diag(1.0 / PAPER_TABLE5.stiffness)
    assert quality["d_log_det_rel"] == pytest.approx(np.linalg.slogdet(s @ info @ s)[1], rel=1e-9)
    by_hand = [_inv_kappa_by_hand(kin, q) for q in plan.q]
    assert quality["inv_kappa_mean"] == pytest.approx(np.mean(by_hand), rel=1e-9)
    assert quality["inv_kappa_min"] == pytest.approx(np.min(by_hand), rel=1e-9)


def test_random_poses_meet_the_lab_box_pinocchio_gives(generated):
    c, _ = generated
    robot, opts = c.scenario.robot, c.pose_sets
    kin = ArmKinematics(robot, c.scenario.lab.block_in_flange)
    stream = posesets.random_poses(robot, opts, np.random.default_rng(3))
    box = np.array(opts.box_m)
    for _ in range(20):
        q = next(stream)
        p = kin.tool_pose(q)[:3, 3]
        assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
        assert p[2] >= opts.min_height_m and np.all(p >= box[:3]) and np.all(p <= box[3:])


def test_feasibility_is_the_truth_worlds_verdict_and_is_cached(generated):
    c, _ = generated
    import dataclasses

    from vtestbed.lab import LabSetup

    # without the KR60's payload limit (588.6 N) the sensor's torque range is what refuses 900 N
    checker = posesets.FeasibilityChecker(
        dataclasses.replace(c.scenario, lab=LabSetup(rated_payload_kg=None))
    )
    q = np.radians([0.0, -60.0, -20.0, 30.0, 50.0, 45.0])
    assert checker.check(q, "hook_x", "ring_2", 200.0) is None  # (hook_x, ring_5) cuts 4.8 mm into the block
    verdict = checker.check(q, "hook_edge", "ring_9", 900.0)  # the torque about the sensor overloads it
    assert re.match(
        r"SensorOverloadError: .*T[xyz] = .* outside the measuring range \[-30, 30\] N\*m", verdict
    )
    assert checker.tried == 2
    assert checker.check(q.copy(), "hook_edge", "ring_9", 900.0) == verdict and checker.tried == 2


def test_a_minimax_design_plan_has_the_smallest_worst_joint_std(generated):
    """criterion = "minimax": the plan's worst relative std (recomputed from the A matrices by
    hand) is at most the D-optimal plan's on the same pool, and the note records it."""
    from vtestbed.design import optimal

    c, plans = generated
    data = campaign_data(axes={"pose_set": ["design_optimal"], "n_tests": [4]})
    data["campaign"]["pose_sets"] = {"pool": 12, "criterion": "minimax"}
    cm = parse_campaign(data)
    plan = posesets.build_plans(cm, {cm.plan_key(x) for x in cm.cells()})["design_optimal:4"]

    def worst(p):
        a = [optimal.candidate_tests(c.scenario.robot, q[None], [h], [r], t, c.scenario.lab, check_sensor=False,
                                     outward=False, clearance=False)[0].a
             for q, h, r, t in zip(p.q, p.hooks, p.anchors, p.tensions)]  # fmt: skip
        info = sum(x.T @ np.linalg.inv(optimal.measurement_covariance()) @ x for x in a)
        k = PAPER_TABLE5.stiffness
        return float(np.max(np.sqrt(np.diag(np.linalg.inv(info))) * k))  # std(c)/c = std(c) k

    assert plan.notes["criterion"] == "minimax"
    assert plan.notes["criterion_value"] == pytest.approx(worst(plan), rel=1e-9)
    assert worst(plan) <= worst(plans["design_optimal:4"]) * (1 + 1e-12)
