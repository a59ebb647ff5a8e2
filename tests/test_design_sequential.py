"""Sequential design (tests already made as a base information) against brute force, the design
module's information matrix under a change of frame, and the command on a simulated dataset."""

import itertools
import json

import numpy as np
import pytest
from conftest import paper_scenario_data
from scipy.spatial.transform import Rotation

from vtestbed.design import minimax, pool, sequential
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.errors import OutOfRangeError

K = PAPER_TABLE5.stiffness


@pytest.fixture(scope="module")
def tiny(robot, lab):
    return pool.candidate_pool(robot, lab, n_poses=6, rng=np.random.default_rng(11), levels=2)


def test_base_information_bound_brute_force_and_exchange(tiny):
    made, cand = tiny.a[:2], tiny.a[2::2][:12]
    assert len(cand) == 12
    m0 = design.information_matrix(made)
    worst = [design.evaluate(cand[list(i)], K, base_information=m0).minimax_value
             for i in itertools.combinations(range(len(cand)), 3)]  # fmt: skip
    best = min(worst)
    result = minimax.design(cand, 3, K, "minimax", base_information=m0)
    chosen = result.selection.report.minimax_value
    assert np.sqrt(result.relaxation.bound) <= best * (1 + 1e-9) and best <= chosen * (1 + 1e-12)
    assert chosen <= 1.05 * best
    assert result.relaxation.value <= 1.02 * result.relaxation.bound  # the relaxation converged with M0
    # the union's std equals evaluating old + new tests together
    together = design.evaluate(np.concatenate([made, cand[list(result.selection.indices)]]), K)
    np.testing.assert_allclose(result.selection.report.relative_std, together.relative_std, rtol=1e-10)


def test_dataset_information_is_frame_free_and_matches_the_design_module(tiny):
    tests = tiny.tests[:5]
    jac = np.array([t.jacobian for t in tests])
    wrench = np.array([t.wrench for t in tests])
    rot = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    r6 = np.kron(np.eye(2), rot)  # the same tests in other axes (a dataset uses B's)
    m_base = sequential.dataset_information(jac, wrench, 5e-6, 9e-6)
    m_rot = sequential.dataset_information(r6 @ jac, wrench @ r6.T, 5e-6, 9e-6)
    reference = design.information_matrix(tests, 5e-6, 9e-6)
    np.testing.assert_allclose(m_base, reference, rtol=1e-10)
    np.testing.assert_allclose(m_rot, reference, rtol=1e-8)


def test_noise_from_residuals_and_bad_estimates():
    assert sequential.noise_from_residuals([3e-6, 4e-6, 12e-6 / np.sqrt(2) * 1, 1e-6, 1e-6, 1e-6])[1] == 1e-6
    sp, _ = sequential.noise_from_residuals([1e-6, 2e-6, 2e-6, 1e-6, 1e-6, 1e-6])
    assert sp == pytest.approx(np.sqrt(3e-12), rel=1e-12)
    with pytest.raises(OutOfRangeError, match="component_std must be 6 positive"):
        sequential.noise_from_residuals([1e-6] * 5)
    jac, wrench = np.zeros((1, 6, 6)), np.zeros((1, 6))
    with pytest.raises(OutOfRangeError, match="current stiffness estimate must be 6 positive values"):
        sequential.next_tests(jac, wrench, -K, 2, None, 5e-6, 9e-6)


def test_cli_next_on_a_simulated_dataset(tmp_path, capsys):
    from vtestbed.cli.main import main
    from vtestbed.experiment import identify_dataset, simulate
    from vtestbed.scenario import load_scenario, parse_scenario

    root = tmp_path / "pilot"
    simulate(parse_scenario(paper_scenario_data(6, 1, "pilot", 3), "pilot.toml"), root)
    argv = ["poses", "next", str(root), "--tests", "3", "--n", "15", "--out", str(tmp_path / "next")]
    assert main(argv) == 0, capsys.readouterr().err
    out = json.loads(capsys.readouterr().out)
    _, _, result = identify_dataset(root)
    np.testing.assert_allclose(out["estimate_Nmm_per_rad"], result.stiffness * 1e3, rtol=1e-12)
    assert out["tests_made"] == 6 and len(out["tests"]) == 3
    assert out["after_worst_relative_std_percent"] < out["current_worst_relative_std_percent"]
    assert out["chosen_over_bound"] >= 1 - 1e-9
    nxt = load_scenario(tmp_path / "next" / "next_scenario.toml")
    assert nxt.name == "next_minimax_3" and nxt.n_tests == 3
    assert main(["poses", "next", str(tmp_path / "none")]) == 2
    assert "none" in capsys.readouterr().err


def test_cli_next_on_a_one_test_dataset_says_why_and_what_to_do(tmp_path, capsys):
    from vtestbed.cli.main import main
    from vtestbed.experiment import simulate
    from vtestbed.scenario import parse_scenario

    root = tmp_path / "one"
    simulate(parse_scenario(paper_scenario_data(1, 1, "one", 3), "one.toml"), root)
    assert main(["poses", "next", str(root), "--tests", "2", "--n", "15"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        f"vtestbed: error: {root}: 1 identification test(s) leave no residual to estimate the measurement"
        " noise from (one test gives 6 equations for the 6 stiffnesses; at least 2 noisy tests are"
        " needed); add tests, or give the noise: --sigma-p M --sigma-r RAD"
    )
    # only one of the two given: the other would still come from the residuals, so still refused
    assert main(["poses", "next", str(root), "--n", "15", "--sigma-p", "5e-6"]) == 2
    assert "--sigma-p M --sigma-r RAD" in capsys.readouterr().err
    # the remedy works: both given, the design runs on the one test's estimate
    assert (
        main(
            [
                "poses",
                "next",
                str(root),
                "--tests",
                "2",
                "--n",
                "15",
                "--sigma-p",
                "5e-6",
                "--sigma-r",
                "9e-6",
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["tests_made"] == 1 and len(out["tests"]) == 2
    assert (out["sigma_p_m"], out["sigma_r_rad"]) == (5e-6, 9e-6)
