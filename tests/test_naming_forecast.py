"""The first-name forecast of benchmarks/naming_forecast.py, checked on a small synthetic problem
against independent references: its leave-one-test-out error against explicit refits without
each test (numpy least squares), and its own-test pass rate against
``floor_calibration.lr_power`` (the same test's power, computed from the tested directions' noise
covariance instead of from refits of drawn datasets).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from vtestbed.researcher.floor_calibration import lr_critical_value, lr_power
from vtestbed.researcher.model_fit import leave_one_test_out

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import naming_forecast as forecast  # noqa: E402

TESTS, NU, LEVEL = 8, 40, 1e-3


def explicit_press(x: np.ndarray, y: np.ndarray) -> float:
    """Sum over tests of the squared error predicting each test's 6 rows from a fit without them."""
    total = 0.0
    for t in range(len(y) // 6):
        keep = np.ones(len(y), bool)
        keep[6 * t : 6 * t + 6] = False
        beta = np.linalg.lstsq(x[keep], y[keep], rcond=None)[0]
        total += float(np.sum((y[~keep] - x[~keep] @ beta) ** 2))
    return total


def test_batched_press_equals_refits_without_each_test():
    """``model_fit.leave_one_test_out`` on K residual columns at once, as the forecasts call it."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((6 * TESTS, 9)) * np.logspace(0, 6, 9)  # columns of very different scales
    y = rng.standard_normal((6 * TESTS, 3))
    u = forecast.orthonormal(x)
    e = y - u @ (u.T @ y)
    got = leave_one_test_out(u, e)
    want = [explicit_press(x, y[:, k]) for k in range(3)]
    assert got == pytest.approx(want, rel=1e-9)


def synthetic_problem(rng: np.random.Generator, scale: float) -> dict:
    """Six stiffness columns, the true 2-parameter candidate with a signal along it, and a rival."""
    stiffness = rng.standard_normal((6 * TESTS, 6))
    own = rng.standard_normal((6 * TESTS, 2))
    rival = rng.standard_normal((6 * TESTS, 1))
    q = forecast.orthonormal(stiffness)
    signal = own @ np.array([1.0, -0.5])
    signal -= q @ (q.T @ signal)
    signal *= scale / np.linalg.norm(signal)
    cands = {}
    for label, cols in (("own", own), ("rival", rival)):
        design = np.hstack([stiffness, cols])
        tested = np.r_[np.zeros(6, bool), np.ones(cols.shape[1], bool)]
        cands[label] = {"columns": cols, "df": cols.shape[1],
                        "crit": lr_critical_value(design, tested, cols.shape[1], NU, LEVEL)}  # fmt: skip
    return {"signal": signal, "stiffness": stiffness, "candidates": cands, "nu": NU, "level": LEVEL,
            "own": frozenset({"own"}), "design": np.hstack([stiffness, own])}  # fmt: skip


def test_own_test_pass_rate_is_the_tests_power():
    rng = np.random.default_rng(7)
    problem = synthetic_problem(rng, scale=5.0)  # noncentrality 25: power about 0.8 at 1e-3
    out = forecast.forecast(problem, floors=400, draws=50, rng=np.random.default_rng(1))
    tested = np.r_[np.zeros(6, bool), np.ones(2, bool)]
    power = lr_power(problem["signal"], problem["design"], tested, 2, NU, LEVEL)
    assert 0.6 < power < 0.95  # a case where the rate can miss in either direction
    assert out["own_pass"] / out["n"] == pytest.approx(power, abs=0.012)  # 4 binomial std at n = 20000
    named = sum(out["named"].values())
    assert named == out["n"]
    # the rival's columns carry only the signal's overlap with them: named where its test passes and
    # it beats the true candidate's held-out error, 0.07 % of these draws
    assert out["named"]["rival"] / out["n"] < 0.01
