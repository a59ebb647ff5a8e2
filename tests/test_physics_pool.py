"""Tests' physics on threads: the same bits as one rig in turn, results and errors in test order."""

import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

from vtestbed.clearance import ClearanceWarning
from vtestbed.errors import JointLimitError
from vtestbed.experiment import simulate
from vtestbed.scenario import load_scenario
from vtestbed.world.physics import run_test_physics
from vtestbed.world.physics_pool import physics_in_order
from vtestbed.world.rig import Rig

ROOT = Path(__file__).resolve().parents[1]
UNCLEAR = ROOT / "tests" / "data" / "kr60_paper_unclear.toml"  # the wave-1 tests, 7 not clear


@pytest.fixture(scope="module")
def paper():
    return load_scenario(ROOT / "scenarios" / "kr60_paper.toml")


def _jobs(scenario, n):
    load = scenario.load
    return [(q, load.hooks[i], load.anchors[i], load.tensions[i]) for i, q in enumerate(scenario.poses[:n])]


def _run(scenario):
    def run(rig, job):
        q, hook, anchor, tension = job
        return run_test_physics(rig, q, hook, anchor, tension, scenario.scanner.distance, clearance="off")

    return run


def test_threads_give_the_bits_of_one_rig_running_the_tests_in_turn(paper):
    jobs = _jobs(paper, 6)
    one_rig = Rig(paper.robot, paper.lab)
    serial = [_run(paper)(one_rig, job) for job in jobs]
    threaded = list(physics_in_order(lambda: Rig(paper.robot, paper.lab), _run(paper), jobs, threads=2))
    assert len(threaded) == len(serial) == 6
    for s, t in zip(serial, threaded):
        for state in ("unloaded", "loaded"):
            a, b = getattr(s, state), getattr(t, state)
            assert np.array_equal(a.qpos_all, b.qpos_all)
            assert np.array_equal(a.block_pose, b.block_pose)
            assert np.array_equal(a.sensor_wrench, b.sensor_wrench)
        assert np.array_equal(s.hits_unloaded.points_m, t.hits_unloaded.points_m)
        assert np.array_equal(s.hits_loaded.points_m, t.hits_loaded.points_m)
        assert s.hits_loaded.points_m.shape[0] > 10_000  # a real scan, not an empty one


def test_an_error_comes_after_every_earlier_result_and_the_threads_stop(paper):
    jobs = _jobs(paper, 5)
    bad = np.array(jobs[2][0], dtype=float)
    bad[1] = paper.robot.upper[1] + 0.1  # A2 beyond its limit: the rig refuses the command
    jobs[2] = (bad, *jobs[2][1:])
    before = threading.active_count()
    got = []
    with pytest.raises(JointLimitError, match="commanded pose"):
        for phys in physics_in_order(lambda: Rig(paper.robot, paper.lab), _run(paper), jobs, threads=2):
            got.append(phys)
    assert len(got) == 2  # tests 0 and 1, in order
    assert np.array_equal(got[1].unloaded.q_cmd, np.asarray(jobs[1][0], dtype=float))
    assert threading.active_count() == before  # the pool shut down with the iterator


def test_simulate_warns_about_the_unclear_tests_in_test_order(tmp_path):
    scenario = load_scenario(UNCLEAR)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        simulate(scenario, tmp_path / "dataset")
    flagged = [str(w.message).split(" ")[0] for w in caught if issubclass(w.category, ClearanceWarning)]
    # the truth world's reports, one test at a time (tests/test_clearance.py): 4, 7, 9, 10, 13, 15, 19
    assert flagged == [f"poses.angles_deg[{i}]" for i in (4, 7, 9, 10, 13, 15, 19)]
