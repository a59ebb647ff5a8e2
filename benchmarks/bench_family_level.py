"""How much a correlation-aware family-wise level would gain over Bonferroni in ``diagnose``'s
first round.

``diagnose`` tests each candidate at ``alpha / m`` (Bonferroni over the ``m`` candidates in play).
The candidates' likelihood ratios are correlated (they are quadratic forms of one residual), so
Bonferroni is conservative by an amount this script measures. Under the baseline model the
whitened residual is ``(I - H) z`` with ``z`` standard normal (``H``: the hat matrix of the
stiffness columns), and candidate ``i``'s likelihood ratio is ``|Q_i^T z|^2`` (``Q_i``: an
orthonormal basis of its whitened columns with the stiffness columns projected out, at the
fitted compliances, with the parameters the stiffnesses absorb left out as ``diagnose`` leaves
them). The single-step min-P level (Westfall-Young) is the ``alpha`` quantile of the smallest
p-value over the candidates in ``--draws`` such draws; the script prints it against ``alpha / m``
and the family-wise rate Bonferroni actually spends. The floor is taken as known (the scanner's
per-component std), as the design alone sets these figures.

Run: .venv/bin/python benchmarks/bench_family_level.py [SCENARIO] [--draws 200000] [--seed 1]

Measured 2026-11-28 (the paper's 20 tests, ``scenarios/kr60_paper.toml``, the default 14
candidates, 200 000 draws, 6 s): at alpha 1 % min-P allows 8.1e-4 per candidate against
Bonferroni's 7.1e-4 (1.13 times), and Bonferroni spends 0.89 %; at 5 % 1.23 times, 4.1 %. So
Bonferroni is nearly exact here: at the 85 % power size of a one-parameter candidate min-P's
level would raise the power to about 86 % (the chi^2(1) threshold 11.4 -> 11.2 at
noncentrality 19.5), not worth its simulation in every diagnosis.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_researcher_discrepancy import SIGMA, world_measurements  # noqa: E402

from vtestbed.researcher.candidates import ModelContext, candidates  # noqa: E402
from vtestbed.researcher.diagnose import identifiable  # noqa: E402
from vtestbed.researcher.identify import stack  # noqa: E402
from vtestbed.researcher.model_fit import Whitener, fit_model  # noqa: E402
from vtestbed.researcher.noise_floor import NoiseFloor  # noqa: E402
from vtestbed.researcher.statics import ExactStatics  # noqa: E402
from vtestbed.scenario import load_scenario  # noqa: E402

CHUNK = 20_000  # draws per block (memory: 6 T x CHUNK doubles)


def orthonormal(x: np.ndarray, rel: float = 1e-8) -> np.ndarray:
    """(rows, r) orthonormal basis of ``x``'s column space (singular values above ``rel`` of the largest)."""
    u, s, _ = np.linalg.svd(x, full_matrices=False)
    return u[:, s > rel * s[0]] if s.size and s[0] > 0 else u[:, :0]


def min_p_draws(
    bases: list[np.ndarray], stiffness: np.ndarray, draws: int, rng: np.random.Generator
) -> np.ndarray:
    """(draws,) smallest per-candidate p-value under the baseline model, one per noise draw."""
    out = np.empty(draws)
    for start in range(0, draws, CHUNK):
        n = min(CHUNK, draws - start)
        z = rng.standard_normal((stiffness.shape[0], n))
        z -= stiffness @ (stiffness.T @ z)  # the residual of the stiffness fit
        smallest = np.ones(n)
        for q in bases:
            smallest = np.minimum(smallest, chi2.sf(np.sum((q.T @ z) ** 2, axis=0), q.shape[1]))
        out[start : start + n] = smallest
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", nargs="?", default=str(ROOT / "scenarios" / "kr60_paper.toml"))
    ap.add_argument("--draws", type=int, default=200_000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    t0 = time.perf_counter()
    setup, kin, ms = world_measurements(load_scenario(args.scenario))
    ctx = ModelContext(ms, setup, kin, ExactStatics(kin, setup))
    white = Whitener(NoiseFloor(np.diag(SIGMA**2), n_samples=10**9, n_tests=len(ms)))
    compliance = fit_model(ctx, white, []).compliance
    stiffness = orthonormal(white(stack([m.jacobian for m in ms], [m.wrench for m in ms])), 1e-10)
    pool = identifiable(ctx, white, candidates(kin), compliance)
    bases = []
    for cand in pool:
        b = white(cand.columns(ctx, compliance))
        q = orthonormal(b - stiffness @ (stiffness.T @ b))
        if q.shape[1]:  # a candidate the stiffnesses absorb whole has no test
            bases.append(q)
    m = len(bases)
    smallest = min_p_draws(bases, stiffness, args.draws, np.random.default_rng(args.seed))
    print(f"{len(ms)} tests, {m} candidates with a test (degrees of freedom {[q.shape[1] for q in bases]}), "
          f"{args.draws} draws, {time.perf_counter() - t0:.0f} s")  # fmt: skip
    for alpha in (0.01, 0.05):
        level = float(np.quantile(smallest, alpha))
        spent = float(np.mean(smallest < alpha / m))
        print(f"alpha {alpha:g}: min-P level {level:.3g} per candidate, Bonferroni {alpha / m:.3g} "
              f"(x{level / (alpha / m):.2f}); Bonferroni's family-wise rate {spent:.2%}")  # fmt: skip


if __name__ == "__main__":
    main()
