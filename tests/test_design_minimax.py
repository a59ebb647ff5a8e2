"""Minimax design, its convex relaxation and lower bound, and the candidate pool, against
brute force over small pools, an independent solver (scipy SLSQP) and direct candidate tests."""

import itertools
import json

import numpy as np
import pytest
from scipy.optimize import minimize

from vtestbed.design import minimax, pool
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.errors import OutOfRangeError, UnknownNameError

K = PAPER_TABLE5.stiffness


@pytest.fixture(scope="module")
def small_pool(robot, lab):
    return pool.candidate_pool(robot, lab, n_poses=4, rng=np.random.default_rng(5), levels=2)


def _worst(a, idx) -> float:
    return design.evaluate(a[list(idx)], K).minimax_value


def test_pool_levels_match_candidate_tests_at_each_tension(small_pool, robot, lab):
    poses = np.unique(np.array([t.q for t in small_pool.tests]), axis=0)
    assert small_pool.tensions == (lab.max_tension[0] / 2, lab.max_tension[0])
    for level in small_pool.tensions:  # the scaled A and the sensor filter against a direct build
        direct = design.candidate_tests(robot, poses, tension=level, lab=lab)
        ours = [(t, a) for t, a in zip(small_pool.tests, small_pool.a) if t.tension == level]
        key = lambda t: (t.q.tobytes(), t.hook, t.anchor)  # noqa: E731
        assert {key(t) for t, _ in ours} <= set(map(key, direct))  # the pool adds the tool's weight
        assert ours  # every level offers tests
        by_key = {key(t): t.a for t in direct}
        for t, a in ours:
            np.testing.assert_allclose(a, by_key[key(t)], rtol=1e-12, atol=1e-30)


def test_random_poses_are_seeded_within_limits_and_in_the_zone(robot, lab):
    q1 = pool.random_poses(robot, lab, 50, np.random.default_rng(3))
    q2 = pool.random_poses(robot, lab, 50, np.random.default_rng(3))
    np.testing.assert_array_equal(q1, q2)
    assert (
        np.all((q1 >= robot.lower) & (q1 <= robot.upper)) and pool.zone_constraints(lab).ok(robot, q1).all()
    )
    assert np.ptp(q1[:, 0]) > np.radians(60) and np.ptp(q1[:, 5]) > np.radians(180)  # all six joints free


@pytest.mark.parametrize("criterion", ["minimax", "A", "D"])
def test_bound_below_brute_force_optimum_below_exchange(small_pool, criterion):
    a = small_pool.a[:: max(1, len(small_pool) // 13)][:13]
    n = 3
    values = []
    for idx in itertools.combinations(range(len(a)), n):
        rep = design.evaluate(a[list(idx)], K)
        values.append({"minimax": rep.minimax_value, "A": rep.a_value, "D": -rep.d_value}[criterion])
    best = min(values)
    result = minimax.design(a, n, K, criterion)
    rep = result.selection.report
    chosen = {"minimax": rep.minimax_value, "A": rep.a_value, "D": -rep.d_value}[criterion]
    bound = result.relaxation.bound
    if criterion == "minimax":
        assert np.sqrt(bound) <= best * (1 + 1e-9) and best <= chosen * (1 + 1e-12)
        assert chosen <= 1.05 * best and result.ratio >= 1 - 1e-9
    elif criterion == "A":
        assert bound <= best * (1 + 1e-9) <= chosen * (1 + 1e-9) and chosen <= 1.05 * best
    else:  # D maximises log det: the bound is an upper bound
        assert -bound <= best + 1e-9 <= chosen + 1e-9 and chosen <= best + 0.05
    assert sum(v <= chosen * (1 + 1e-12) for v in values) <= max(3, len(values) // 20)  # among the best 5 %


def test_relaxation_matches_an_independent_solver(small_pool):
    """Relaxed minimax on 10 candidates by SLSQP (epigraph form) against Frank-Wolfe and its bound."""
    a = small_pool.a[:: max(1, len(small_pool) // 10)][:10]
    c = minimax.whitened(a, K)
    n, t = 4, len(a)
    info = np.einsum("tki,tkj->tij", c, c)

    def d(w):
        return np.diag(np.linalg.inv(np.einsum("t,tij->ij", w, info)))

    scale = d(np.full(t, n / t)).max()
    cons = [{"type": "eq", "fun": lambda x: x[:t].sum() - n},
            {"type": "ineq", "fun": lambda x: x[t] - d(x[:t]) / scale}]  # fmt: skip
    x0 = np.r_[np.full(t, n / t), 1.0]
    res = minimize(lambda x: x[t], x0, constraints=cons, bounds=[(1e-9, 1)] * t + [(0, None)], method="SLSQP",
                   options={"maxiter": 500, "ftol": 1e-12})  # fmt: skip
    assert res.success, res.message
    reference = d(res.x[:t]).max()
    rel = minimax.relax(c, n, "minimax", iterations=600)
    assert rel.bound <= reference * (1 + 1e-6)  # certified: below the true relaxed optimum
    assert rel.value <= reference * 1.01  # Frank-Wolfe reaches it within 1 %
    assert rel.bound >= reference * 0.97  # and the bound is tight
    assert abs(rel.weights.sum() - n) < 1e-9 and rel.weights.min() >= 0 and rel.weights.max() <= 1 + 1e-12


def test_every_joint_weighting_gives_a_valid_bound(small_pool):
    """Any lambda on the simplex: the weighted-A Frank-Wolfe bound lies below every 3-test set."""
    a = small_pool.a[:12]
    c = minimax.whitened(a, K)
    best = min(_worst(a, idx) ** 2 for idx in itertools.combinations(range(len(a)), 3))
    w = np.full(len(a), 3 / len(a))
    b = np.linalg.inv(minimax._info(c, w))
    h = -np.einsum("tkj,tkj->tj", c @ b, c @ b)
    for lam in np.random.default_rng(0).dirichlet(np.ones(6), 20):
        g = h @ lam
        bound = lam @ np.diag(b) + np.sort(g)[:3].sum() - w @ g
        assert bound <= best * (1 + 1e-9)


def test_minimax_beats_d_and_a_on_the_worst_joint(robot, lab):
    p = pool.candidate_pool(robot, lab, n_poses=30, rng=np.random.default_rng(1))
    worst = {crit: minimax.design(p.a, 12, K, crit, bound=False).selection.report.minimax_value
             for crit in ("minimax", "A", "D")}  # fmt: skip
    assert worst["minimax"] <= worst["A"] and worst["minimax"] <= worst["D"]


def test_bad_input_names_the_option(small_pool):
    c = minimax.whitened(small_pool.a, K)
    with pytest.raises(UnknownNameError, match="relaxed design criterion.*minimax"):
        minimax.relax(c, 3, "E")
    with pytest.raises(OutOfRangeError, match=r"n = 0 tests is outside the valid range \[1, "):
        minimax.relax(c, 0)
    with pytest.raises(OutOfRangeError, match=r"tension levels = 0 is outside the valid range \[1, 100\]"):
        pool.tension_levels(pool.PAPER_LAB, levels=0)
    with pytest.raises(OutOfRangeError, match=r"max_tension_N = 5000 N is outside the valid range"):
        pool.tension_levels(pool.PAPER_LAB, 5000.0)


def test_cli_design_minimax_default_kappa_and_errors(capsys):
    from vtestbed.cli.main import main

    base = ["poses", "design", "--stiffness-prior", "paper_table5", "--tests", "8", "--n", "12"]
    assert main(base) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["criterion"] == "minimax" and out["pool"] == "random" and len(out["tests"]) == 8
    assert out["lower_bound_worst_relative_std_percent"] <= out["worst_relative_std_percent"]
    assert out["chosen_over_bound"] == pytest.approx(
        out["worst_relative_std_percent"] / out["lower_bound_worst_relative_std_percent"], rel=1e-12
    )
    assert max(t["tension_N"] for t in out["tests"]) <= 588.6 + 1e-9
    assert main([*base[:-2], "--criterion", "kappa", "--step-deg", "2"]) == 0
    kappa_out = json.loads(capsys.readouterr().out)
    assert {t["tension_N"] for t in kappa_out["tests"]} == {200.0} and len(kappa_out["tests"]) == 8
    assert main([*base, "--tension", "5000"]) == 2
    assert "--tension = 5000 N is outside the valid range [" in capsys.readouterr().err


def test_scanner_placeable_agrees_with_the_world_scanner_placement(robot, lab):
    """Poses the pool keeps never make ``Scanner.place`` stand the scanner below the table or floor."""
    from vtestbed.errors import ScanError
    from vtestbed.researcher.kinematics import ArmKinematics
    from vtestbed.world.scanner import Scanner

    kin = ArmKinematics(robot, lab.block_in_flange)
    q = pool.random_poses(robot, lab, 1000, np.random.default_rng(9))
    kept, below = [], []
    for pose in q:
        ok = pool.scanner_placeable(robot, lab, pose, lab.scanner_distance)
        try:
            Scanner.place(lab, kin.tool_pose(pose, lab.block_in_flange))
            refused = False
        except ScanError as exc:
            refused = "below the" in str(exc)
        kept.append(ok)
        below.append(refused)
    kept, below = np.array(kept), np.array(below)
    assert not np.any(kept & below) and below.sum() >= 3 and kept.sum() > 500  # both kinds occur
    assert np.sum(~kept & ~below) <= 0.05 * len(q)  # the 10 mm margin refuses few placeable poses


def test_pool_sensor_check_against_the_truth_world_reading(robot, lab):
    """The pool's nominal sensor load (wire + tool weight) against MuJoCo's loaded reading, on the
    tests closest to the F/T range: within 2 % of the range, and none overloads."""
    from vtestbed.world.rig import Rig
    from vtestbed.world.truth import load_truth

    p = pool.candidate_pool(robot, lab, n_poses=30, rng=np.random.default_rng(4), levels=1)
    kin = pool.ArmKinematics(robot, lab.block_in_flange)
    limit = np.asarray(lab.sensor.wrench_range)
    nominal = np.array([np.r_[design.sensor_load(kin, lab, t.q, t.wrench)[:3] + pool._tool_weight(kin, lab, t.q),
                              design.sensor_load(kin, lab, t.q, t.wrench)[3:]] for t in p.tests])  # fmt: skip
    closest = np.argsort(-np.abs(nominal / limit).max(axis=1))[:8]
    assert np.abs(nominal[closest] / limit).max() > 0.9  # the check is exercised near its edge
    rig = Rig(robot, lab, truth=load_truth(robot.name))
    for i in closest:
        t = p.tests[i]
        rig.command(t.q)
        rig.hook(t.hook, t.anchor)
        rig.solve()
        truth = rig.tighten(t.tension).sensor_wrench  # raises SensorOverloadError when out of range
        np.testing.assert_array_less(np.abs(truth[:3] - nominal[i, :3]), 0.02 * limit[:3])
        np.testing.assert_array_less(
            np.abs(truth[3:] - nominal[i, 3:]), pool._tool_torque_bound(lab) + 0.02 * limit[3:]
        )
