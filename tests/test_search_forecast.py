"""The stepwise-search forecast of benchmarks/search_forecast.py, checked on small synthetic
problems against independent references: a draw-by-draw search written the way
``diagnose.name_effects`` is (one dataset at a time, every fit an explicit numpy least-squares
refit, the held-out error from refits without each test), and, with a single candidate, the
likelihood-ratio test's power from ``floor_calibration.lr_power``.
"""

import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_dist

from vtestbed.researcher.diagnose import step_level
from vtestbed.researcher.floor_calibration import floor_whiteners, lr_critical_value, lr_power

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import naming_forecast  # noqa: E402
import search_forecast  # noqa: E402
from test_naming_forecast import explicit_press  # noqa: E402

TESTS, NU, ALPHA, MAX_TERMS = 8, 40, 0.01, 3


def two_effect_problem(rng: np.random.Generator, sizes: tuple[float, float]) -> dict:
    """Six stiffness columns; candidates "a" (2 columns) and "b" (1) each carrying a signal of the
    given norm, and "c" (1), a rival that shares part of "a"'s first column."""
    stiffness = rng.standard_normal((6 * TESTS, 6))
    a, b = rng.standard_normal((6 * TESTS, 2)), rng.standard_normal((6 * TESTS, 1))
    c = 0.7 * a[:, :1] + 0.7 * rng.standard_normal((6 * TESTS, 1))
    q = naming_forecast.orthonormal(stiffness)
    signal = np.zeros(6 * TESTS)
    for cols, size, coef in ((a, sizes[0], np.array([1.0, -0.5])), (b, sizes[1], np.array([1.0]))):
        part = cols @ coef
        part -= q @ (q.T @ part)
        signal += size * part / np.linalg.norm(part)
    level = ALPHA / 3  # the first round's, and each candidate's critical value there, as effect_problem
    cands = {}
    for lab, cols in (("a", a), ("b", b), ("c", c)):
        tested = np.r_[np.zeros(6, bool), np.ones(cols.shape[1], bool)]
        crit = lr_critical_value(np.hstack([stiffness, cols]), tested, cols.shape[1], NU, level)
        cands[lab] = {"columns": cols, "df": cols.shape[1], "crit": crit}
    return {"signal": signal, "stiffness": stiffness, "candidates": cands, "nu": NU, "n_pool": 3,
            "level": level, "hidden": {"A": frozenset({"a"}), "B": frozenset({"b"})}}  # fmt: skip


def reference_search(problem: dict, g: np.ndarray, y: np.ndarray) -> frozenset:
    """``diagnose.name_effects`` on one dataset ``y`` (in the floor draw ``g``'s coordinates), with
    explicit refits: forward by likelihood ratio against its critical value, held-out error among
    the significant, backward drops, the same stopping rules."""
    cands = problem["candidates"]

    def design(labels, whiten=True):
        x = np.hstack([problem["stiffness"], *(cands[lab]["columns"] for lab in labels)])
        return naming_forecast.per_test(g, x) if whiten else x

    def chi2(labels):
        x = design(labels)
        return float(np.sum((y - x @ np.linalg.lstsq(x, y, rcond=None)[0]) ** 2))

    def test(labels, label, level):
        """(lr, df, critical value) of ``label`` beyond ``labels``."""
        without, with_ = design(labels, False), design([*labels, label], False)
        df = np.linalg.matrix_rank(with_) - np.linalg.matrix_rank(without)
        tested = np.r_[np.zeros(without.shape[1], bool), np.ones(with_.shape[1] - without.shape[1], bool)]
        return chi2(labels) - chi2([*labels, label]), df, lr_critical_value(with_, tested, df, NU, level)

    chosen, seen, later = [], {frozenset()}, 0
    while len(chosen) < MAX_TERMS:
        if chosen and later >= MAX_TERMS - 1:
            break
        remaining = [lab for lab in cands if lab not in chosen]
        level = step_level(ALPHA, len(remaining), len(chosen), MAX_TERMS)
        significant = []
        for lab in remaining:
            lr, df, crit = test(chosen, lab, level)
            if df > 0 and lr > crit:
                significant.append((explicit_press(design([*chosen, lab]), y), lab))
        if not significant:
            break
        later += bool(chosen)
        chosen = [*chosen, min(significant)[1]]
        while len(chosen) > 1:  # the backward step
            drop_level = step_level(ALPHA, problem["n_pool"] - len(chosen) + 1, len(chosen) - 1, MAX_TERMS)
            worst = None
            for term in chosen:
                lr, df, crit = test([t for t in chosen if t != term], term, drop_level)
                if lr < crit and (worst is None or chi2_dist.sf(lr, df) > worst[0]):
                    worst = (chi2_dist.sf(lr, df), term)
            if worst is None:
                break
            chosen.remove(worst[1])
        if frozenset(chosen) in seen:
            break
        seen.add(frozenset(chosen))
    return frozenset(chosen)


def test_search_matches_a_draw_by_draw_search_with_explicit_refits():
    problem = two_effect_problem(np.random.default_rng(3), sizes=(5.5, 4.5))
    floors, draws = 4, 25
    got = search_forecast.forecast_search(problem, floors, draws, np.random.default_rng(11))
    rng = np.random.default_rng(11)  # the same noise, drawn in the same order
    want = Counter()
    for g in floor_whiteners(NU)[:floors]:
        noise = rng.standard_normal((problem["signal"].size, draws))
        y = naming_forecast.per_test(g, problem["signal"][:, None] + noise)
        want.update(reference_search(problem, g, y[:, k]) for k in range(draws))
    assert sum(got.values()) == floors * draws
    # the sizes put the draws on both sides: some name both, some one, some a rival or nothing
    assert len(want) >= 3 and want[frozenset({"a", "b"})] < floors * draws
    assert got == want


def test_a_lone_candidate_is_named_at_its_tests_power():
    problem = two_effect_problem(np.random.default_rng(5), sizes=(5.0, 0.0))
    design = np.hstack([problem["stiffness"], problem["candidates"]["a"]["columns"]])
    tested = np.r_[np.zeros(6, bool), np.ones(2, bool)]
    # a pool of one: its first round's level is alpha, and the search takes that critical value
    # from the problem (as effect_problem gives it)
    crit = lr_critical_value(design, tested, 2, NU, ALPHA)
    problem.update(candidates={"a": {**problem["candidates"]["a"], "crit": crit}}, n_pool=1, level=ALPHA)
    ends = search_forecast.forecast_search(problem, 400, 50, np.random.default_rng(2))
    power = lr_power(problem["signal"], design, tested, 2, NU, ALPHA)
    assert 0.5 < power < 0.95  # a case where the share can miss in either direction
    assert ends[frozenset({"a"})] / 20000 == pytest.approx(power, abs=0.012)  # 4 binomial std


def test_pair_shares_count_as_the_two_effect_benchmark_does():
    hidden = {"block_offset": frozenset({"rot", "shift"}), "ft_misalignment": frozenset({"mis"})}
    ends = Counter({frozenset({"rot", "mis"}): 6, frozenset({"rot", "shift", "mis", "x"}): 1,
                    frozenset({"mis"}): 2, frozenset({"y"}): 1})  # fmt: skip
    shares = search_forecast.pair_shares(ends, hidden)
    assert shares["both"] == pytest.approx(0.7)  # both parts of the block offset count once
    assert shares["alone"] == pytest.approx({"block_offset": 0.0, "ft_misalignment": 0.2})
    assert shares["third"] == pytest.approx(0.2) and shares["nothing"] == 0.0
    assert shares["extra"] == pytest.approx({"x": 0.1, "y": 0.1})


@pytest.mark.parametrize("text", ["block_offset", "block_offset+nope", "a+b+c", "block_offset+"])
def test_pairs_refuse_anything_but_two_effects(text):
    def error(message):
        raise SystemExit(message)

    with pytest.raises(SystemExit, match="is not a pair of effects a\\+b; valid effects: .*block_offset"):
        search_forecast.parse_pairs(text, error)
