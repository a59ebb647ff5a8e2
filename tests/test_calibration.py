"""Is the reported k_std honest in the full virtual lab? (slow: 30 virtual experiments)"""

import warnings
from pathlib import Path

import numpy as np
import pytest

from vtestbed.analysis import identify_measurements
from vtestbed.montecarlo import measure_trial, prepare
from vtestbed.scenario import load_scenario

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml"


@pytest.mark.slow
def test_k_std_is_honest_and_error_shrinks_with_the_test_count():
    scenario = load_scenario(SCENARIO)
    prepared = prepare(scenario)
    k_true = prepared.stiffness_true
    z, errors = [], {5: [], 10: [], 20: []}
    for seed in range(30):
        ms = measure_trial(prepared, 5000 + seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for n in errors:
                res = identify_measurements(ms[:n], "fgls")
                errors[n].append(res.stiffness / k_true - 1)
        z.append((res.stiffness - k_true) / res.stiffness_std)
    z_std = np.std(z, axis=0, ddof=1)
    spread = {n: np.std(e, axis=0, ddof=1) for n, e in errors.items()}
    print(f"\nz-score std per joint (30 seeds, 20 tests): {np.round(z_std, 2)}")
    print(f"z-score mean per joint: {np.round(np.mean(z, axis=0), 2)}")
    for n, s in spread.items():
        print(f"relative error spread with {n:2d} tests [%]: {np.round(s * 100, 3)}")
    assert np.all((z_std > 0.7) & (z_std < 1.4))
    # more tests, smaller error: n=20 vs n=5 is 4x the data; 1/sqrt(n) predicts a factor 2
    # (the first five poses are not a quarter of the information of twenty: allow 1.3..4)
    ratio = spread[5] / spread[20]
    print(f"spread(5)/spread(20): {np.round(ratio, 2)}")
    assert np.all(spread[10] < spread[5] * 1.1) and np.all((ratio > 1.3) & (ratio < 4.0))
