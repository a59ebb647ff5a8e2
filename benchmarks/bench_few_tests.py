"""Is the reported std honest with few tests? Full-pipeline Monte Carlo of 2-8 test identifications.

With fewer than 8 tests ``fgls`` cannot estimate one noise variance per displacement component:
a component's T residuals can be fitted exactly once T <= n, its variance collapses and its weight
runs away. Since 2026-11-29 the components share two noise levels (translation, rotation; one
below 4 tests) and the analytic covariance is widened by the Student factor of their degrees of
freedom (:mod:`vtestbed.researcher.fgls`; docs/uncertainty.md, "Few tests"). This benchmark
measures both, the code before (``fgls, before``: per-component variances, analytic covariance
scaled by chi^2) and after, with ``ols`` (the paper's) and ``gls_floor`` (weights from the
repeat scans of the tests used) beside them.

Trials: the paper's 20 tests (``scenarios/kr60_paper.toml``) and 20 random clear tests (seed 7),
measured through the full pipeline (MuJoCo, ray-cast scans with the VTOP 200B noise and drift,
F/T noise, the researcher's cloud fits, 3 repeat scans per test), cached and shared with
``bench_design_uncertainty.py`` (trial i has seed 16 000 + i). Per trial and test count T the
identification uses the set's first T tests (``first``) and T tests drawn without replacement
from the 20 (``drawn``, generator seeded with ``[29, trial, T]``): the second varies the design
from one trial to the next.

Printed per (set, tests, subset, estimator): the z-score ``(k - k_true) / k_std`` std per joint
(honest: within [0.8, 1.25], docs/uncertainty.md), how many joints are in that range, and the
RMS error per joint [%].

Run: .venv/bin/python benchmarks/bench_few_tests.py [--trials 200] [--cache DIR]
(measuring: about 1.5 s per trial and set on this machine, one core; cached runs only identify).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_design_uncertainty import HONEST, PAPER, ROOT, measure, random_scenario  # noqa: E402

import vtestbed as vt  # noqa: E402
from vtestbed.errors import VtestbedError  # noqa: E402
from vtestbed.researcher.fgls import PER_COMPONENT, PER_COMPONENT_MIN_TESTS, fgls  # noqa: E402
from vtestbed.researcher.identify import identify, stack  # noqa: E402
from vtestbed.researcher.measure import gls_floor_covariance  # noqa: E402
from vtestbed.researcher.noise_floor import noise_floor_from_frames  # noqa: E402

COUNTS = (2, 3, 4, 5, 6, 7, 8)
ESTIMATORS = ("fgls, before", "fgls", "ols", "gls_floor")
SUBSETS = ("first", "drawn")


def fgls_before(j: np.ndarray, w: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stiffness and std [N*m/rad] as ``fgls`` gave them below 8 tests before 2026-11-29: one
    variance per component from the residuals, analytic covariance scaled by chi^2."""
    a, d_flat = stack(j, w), d.reshape(-1)
    n_tests, n = d.shape[0], a.shape[1]
    c, cov, scale = fgls(a, d_flat, n_tests, n, 5, levels=PER_COMPONENT)
    white = (d_flat - a @ c) * scale
    cov = cov * (white @ white / max(6 * n_tests - n, 1))
    return 1.0 / c, np.sqrt(np.clip(np.diag(cov), 0.0, None)) / c**2


def estimate(method: str, j, w, d, frames) -> tuple[np.ndarray, np.ndarray] | None:
    """(stiffness, std) of one identification, or None where the estimator refuses the tests
    (``gls_floor`` needs 8 repeat samples)."""
    if method == "fgls, before":
        return fgls_before(j, w, d)
    cov = None
    if method == "gls_floor":
        try:
            floor = noise_floor_from_frames({f"T{t + 1:03d}": list(fr) for t, fr in enumerate(frames)})
            cov = gls_floor_covariance(floor)
        except VtestbedError:
            return None
    res = identify(j, w, d, method=method, displacement_cov=cov)
    return res.stiffness, res.stiffness_std


def evaluate(data: dict, n: int, subset: str, method: str) -> dict | None:
    """z-score std and RMS error per joint over the trials, from n tests of each."""
    errs, zs = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, (j, w, d, fr) in enumerate(
            zip(data["jacobians"], data["wrenches"], data["displacements"], data["repeat_frames"])
        ):
            if subset == "first":
                pick = np.arange(n)
            else:
                pick = np.sort(np.random.default_rng([29, i, n]).choice(len(d), n, replace=False))
            out = estimate(method, j[pick], w[pick], d[pick], fr[pick])
            if out is None:
                return None
            k, std = out
            errs.append(k / data["k_true"] - 1.0)
            zs.append((k - data["k_true"]) / std)
    errs, zs = np.array(errs), np.array(zs)
    z_std = np.std(zs, axis=0, ddof=1)
    return {"z_std": z_std, "rms": np.sqrt(np.mean(errs**2, axis=0)),
            "honest": int(np.sum((z_std >= HONEST[0]) & (z_std <= HONEST[1])))}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="Monte Carlo trials per set (default 200)")
    parser.add_argument("--cache", default=str(ROOT / "runs" / "bench_design_uncertainty"),
                        help="directory of the measured trials, shared with bench_design_uncertainty.py")  # fmt: skip
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    base = vt.load_scenario(PAPER)
    sets = {"paper": base, "random": random_scenario(base, 20, 7)}
    print(
        f"z-score std per joint (honest: {HONEST[0]}-{HONEST[1]}), joints in range, RMS error per joint [%]"
    )
    for name, scenario in sets.items():
        data = measure(name, scenario, args.trials, cache)
        for n in COUNTS:
            for subset in SUBSETS:
                for method in ESTIMATORS:
                    if method == "fgls, before" and n >= PER_COMPONENT_MIN_TESTS:
                        continue  # the jackknife then, unchanged: "fgls"
                    t0 = time.perf_counter()
                    row = evaluate(data, n, subset, method)
                    label = f"{name:6s} {n} {subset:5s} {method:12s}"
                    if row is None:
                        print(f"{label}  (refused: too few repeat samples)")
                        continue
                    z = " ".join(f"{v:8.2f}" if v < 1e3 else f"{v:8.1e}" for v in row["z_std"])
                    rms = " ".join(f"{100 * v:6.2f}" for v in row["rms"])
                    print(f"{label}  z {z}  in range {row['honest']}/6  RMS {rms}"
                          f"  ({time.perf_counter() - t0:.1f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
