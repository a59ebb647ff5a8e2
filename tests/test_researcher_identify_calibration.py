"""Is the reported k_std honest in the full virtual lab? (slow: 50 virtual experiments)"""

import warnings
from pathlib import Path

import numpy as np
import pytest

from vtestbed.campaigns.montecarlo import measure_trial, prepare
from vtestbed.researcher.identify import stack
from vtestbed.researcher.measure import identify_measurements
from vtestbed.scenario import load_scenario

SEEDS = 50  # >= 30; the std of a z-score std over N seeds is about 1/sqrt(2N) = 10 %
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["kr60_paper", "kr60_chamfered"])  # the box, and a mesh target
def test_k_std_is_honest_and_error_shrinks_with_the_test_count(name):
    scenario = load_scenario(SCENARIOS / f"{name}.toml")
    prepared = prepare(scenario)
    k_true = prepared.stiffness_true
    truth = np.array([t.displacement_true for t in prepared.identification_tests()])
    z, errors, disp_errors = [], {5: [], 10: [], 20: []}, []
    for seed in range(SEEDS):
        ms = measure_trial(prepared, 5000 + seed)
        disp_errors.append(np.array([m.displacement for m in ms]) - truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for n in errors:
                res = identify_measurements(ms[:n], "fgls")
                errors[n].append(res.stiffness / k_true - 1)
        z.append((res.stiffness - k_true) / res.stiffness_std)
    z_std = np.std(z, axis=0, ddof=1)
    spread = {n: np.std(e, axis=0, ddof=1) for n, e in errors.items()}
    print(f"\nz-score std per joint ({SEEDS} seeds, 20 tests): {np.round(z_std, 2)}")
    print(f"z-score mean per joint: {np.round(np.mean(z, axis=0), 2)}")
    assert np.all((z_std > 0.7) & (z_std < 1.4))

    # The error shrinks with the number of tests as linear least-squares theory predicts for this
    # design, given the scanner's true displacement noise (pooled from the errors against the
    # truth): cov(c) = B A^T W Sigma W A B, B = (A^T W A)^-1, W = diag(Sigma)^-1 per test.
    sigma = np.cov(np.concatenate(disp_errors).T)
    w = np.diag(1.0 / np.diag(sigma))
    for n in errors:
        a = stack([m.jacobian for m in ms[:n]], [m.wrench for m in ms[:n]])
        bread = np.linalg.inv(sum(blk.T @ w @ blk for blk in a.reshape(n, 6, -1)))
        meat = sum(blk.T @ w @ sigma @ w @ blk for blk in a.reshape(n, 6, -1))
        theory = np.sqrt(np.diag(bread @ meat @ bread)) * k_true  # relative std of k
        ratio = spread[n] / theory
        print(f"{n:2d} tests: spread [%] {np.round(spread[n] * 100, 3)}, spread/theory {np.round(ratio, 2)}")
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5))
    assert np.all(spread[20] < spread[10]) and np.all(spread[10] < spread[5])
