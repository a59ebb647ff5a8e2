"""The design comparison's bridges (benchmarks/bench_design_comparison.py), checked by hand.

* a sequential step: the next tests' predicted worst std at the estimate equals the one computed
  from ``M0 + sum_new A_t^T Sigma^-1 A_t`` by hand, and adding the chosen tests one at a time never
  raises any joint's predicted std;
* a design, turned into the test list of a scenario with the paper's lab (as the benchmark runs it
  through the full pipeline), keeps every test's ``A``;
* the docs' table in KUKA controller degrees, read back as a ``convention = "controller"``
  scenario, gives the designed DH poses.
"""

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from vtestbed.design import minimax, pool, sequential
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.scenario import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_design_comparison as bench  # noqa: E402
from bench_design_uncertainty import scenario_a  # noqa: E402

K = PAPER_TABLE5.stiffness
PAPER = Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml"


@pytest.fixture(scope="module")
def small(robot, lab):
    return pool.candidate_pool(robot, lab, n_poses=8, rng=np.random.default_rng(5), levels=2)


def _worst_by_hand(a, m0, k, sigma_p, sigma_r):
    w = 1.0 / np.diag(design.measurement_covariance(sigma_p, sigma_r))
    m = m0 + np.einsum("tki,k,tkj->ij", a, w, a)
    rel = np.sqrt(np.diag(np.linalg.inv(m))) / (1.0 / k)  # std(c_j) / c_j = std(k_j) / k_j (delta method)
    return rel


def test_sequential_step_against_the_information_by_hand(small):
    made = small.tests[:: max(1, len(small) // 6)][:6]
    jac = np.array([t.jacobian for t in made])
    wrench = np.array([t.wrench for t in made])
    estimate = K * np.array([2.0, 0.5, 2.0, 0.5, 2.0, 0.5])
    sp, sr = 6e-6, 9e-6
    nxt = sequential.next_tests(jac, wrench, estimate, 4, small, sp, sr)
    m0 = sequential.dataset_information(jac, wrench, sp, sr)
    a_made = np.array([t.a for t in made])
    current = _worst_by_hand(a_made, np.zeros_like(m0), estimate, sp, sr)
    np.testing.assert_allclose(nxt.current.relative_std, current, rtol=1e-9)
    chosen = small.a[list(nxt.result.selection.indices)]
    after = _worst_by_hand(chosen, m0, estimate, sp, sr)
    np.testing.assert_allclose(nxt.result.selection.report.relative_std, after, rtol=1e-9)
    prev = current
    for i in range(1, len(chosen) + 1):  # one test at a time: information only adds
        now = _worst_by_hand(chosen[:i], m0, estimate, sp, sr)
        assert np.all(now <= prev * (1 + 1e-12))
        prev = now
    assert after.max() < current.max()


def test_design_plan_keeps_each_tests_a(small):
    base = load_scenario(PAPER)
    result = minimax.design(small.a, 6, K, "minimax", bound=False)
    tests = [small.tests[i] for i in result.selection.indices]
    scenario = bench.plan_of("minimax", tests).scenario(base)
    np.testing.assert_allclose(scenario_a(scenario), small.a[list(result.selection.indices)], rtol=1e-9)
    assert len(scenario.validation_poses) == 0


def test_controller_table_reads_back_as_the_designed_poses(small, robot, tmp_path):
    tests = small.tests[:5]
    table = bench.controller_table(bench.plan_of("x", tests), robot)
    rows = table.splitlines()[2:]
    angles = [[float(v) for v in re.split(r"\|", r)[2].split(",")] for r in rows]
    hooks = [r.split("|")[3].strip() for r in rows]
    rings = [r.split("|")[4].strip() for r in rows]
    path = tmp_path / "table.toml"
    path.write_text(
        'name = "table"\nrobot = "kuka_kr60_3"\n[poses]\nconvention = "controller"\nangles_deg = '
        f"{angles}\n[load]\nhook = {hooks!r}\nanchor = {rings!r}\ntension_N = {[t.tension for t in tests]}\n".replace(
            "'", '"'
        )
    )
    sc = load_scenario(path)
    np.testing.assert_allclose(sc.poses, np.array([t.q for t in tests]), atol=np.radians(0.006))
    assert list(sc.load.hooks) == [t.hook for t in tests] and list(sc.load.anchors) == [
        t.anchor for t in tests
    ]


def test_measure_extends_a_cached_shorter_run_to_what_a_fresh_run_gives(small, tmp_path):
    # two designed tests through the full pipeline: 1 trial cached, extended to 2, against 2 fresh
    from bench_design_uncertainty import measure

    base = load_scenario(PAPER)
    tests = minimax.design(small.a, 2, K, "minimax").selection.indices
    scenario = bench.plan_of("x", [small.tests[i] for i in tests]).scenario(base)
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    measure("x", scenario, 1, tmp_path / "a")
    extended = measure("x", scenario, 2, tmp_path / "a")
    fresh = measure("x", scenario, 2, tmp_path / "b")
    assert extended["displacements"].shape == (2, 2, 6) and extended["repeat_frames"].shape[:2] == (2, 2)
    for key, value in fresh.items():
        np.testing.assert_array_equal(extended[key], value, err_msg=key)
    # the second trial is not a copy of the first: the extension measured it with its own seed
    assert not np.array_equal(extended["displacements"][0], extended["displacements"][1])
