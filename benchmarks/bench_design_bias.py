"""The paper's linear model against the clean world's exact statics, on the comparison's designs.

At the lab's tension limit the designed sets' errors carry a bias that grows with the tension
(the neglected load-dependent Jacobian, gravity's geometric stiffness, second-order kinematics).
This bench identifies the same full-pipeline trials as ``bench_design_comparison.py`` (the same
seeds, 16 000 + i, re-measured: the pipeline is deterministic) three ways, each from a trial's
first n tests:

* ``fgls``: the comparison's estimator (the paper's model, FGLS);
* ``floor``: the paper's model weighted with the repeat scans' noise floor (GLS,
  :func:`vtestbed.researcher.model_fit.fit_model` without terms);
* ``exact``: the same against the clean world's exact statics
  (:class:`vtestbed.researcher.statics.ExactStatics`: the nominal robot's equilibrium under its
  weight and the measured sensor load, what ``vtestbed diagnose`` takes as its baseline).

Printed per set and estimator: each joint's mean error and std [%], the worst joint's RMS error
and its ratio to the kappa set's under the same estimator, and the std of each joint's z-score
(error / reported std; honest within [0.8, 1.25], issue 16). The designs come from the
comparison's cache (``--cache``; run ``bench_design_comparison.py`` first); ``random_N`` is the
comparison's random clear tests.

Run: .venv/bin/python benchmarks/bench_design_bias.py [--trials 100] [--workers 2]
       [--sets kappa_12,kappa_20,minimax_12_588.6N,refined_12_588.6N,minimax_20_588.6N,refined_20_588.6N]
(18 min on 2 workers at 100 trials for these six sets and the four 200 N ones, 35 min for those
and random_12,random_20 with other jobs on the cores; docs/poses.md, "The bias, removed";
docs/uncertainty.md for the z-scores).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from bench_design_uncertainty import HONEST, REPEATS, random_scenario

import vtestbed as vt
from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames
from vtestbed.campaigns.posesets import TestPlan
from vtestbed.researcher.candidates import ModelContext
from vtestbed.researcher.identify import identify
from vtestbed.researcher.measure import stacked
from vtestbed.researcher.model_fit import Whitener, fit_model
from vtestbed.researcher.noise_floor import noise_floor_from_frames
from vtestbed.researcher.statics import ExactStatics

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
ESTIMATORS = ("fgls", "floor", "exact")
_PREPARED: dict = {}


def set_scenario(name: str, cache: Path):
    """(scenario, n): the kappa set's first n tests (``kappa_N``), the random set's (``random_N``) or
    a cached design (``DESIGN_N_TAG``)."""
    base = vt.load_scenario(PAPER)
    if name.startswith("kappa_"):
        return base, set_size(name)
    if name.startswith("random_"):
        return random_scenario(base, 20, 7), set_size(name)
    design, n, tag = name.rsplit("_", 2)
    plans = json.loads((cache / f"designs_{tag}.json").read_text())
    return TestPlan.from_dict(plans[f"{design}_{n}"]["plan"]).scenario(base), set_size(name)


def set_size(name: str) -> int:
    """The n of a set name: ``kappa_N`` or ``DESIGN_N_TAG``."""
    return int(name.split("_")[1])


def trial(args) -> np.ndarray:
    """(2, 3, n_joints): one trial's relative errors and reported relative stds under each estimator."""
    name, cache, seed = args
    if name not in _PREPARED:
        scenario, n = set_scenario(name, cache)
        _PREPARED.clear()
        _PREPARED[name] = (prepare(scenario), n)
    prepared, n = _PREPARED[name]
    ms = measure_trial(prepared, seed)[:n]
    tests = prepared.identification_tests()[:n]
    frames = repeat_frames(prepared, seed, tests, ms, prepared.scenario.scanner.noise_model, REPEATS)
    white = Whitener(noise_floor_from_frames(frames))
    k_true = prepared.stiffness_true
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(*stacked(ms), method="fgls")
    out, std = [res.stiffness / k_true - 1], [res.stiffness_std / res.stiffness]
    for statics in (None, ExactStatics(prepared.kinematics, prepared.setup)):
        fit = fit_model(ModelContext(ms, prepared.setup, prepared.kinematics, statics), white, [])
        out.append(1.0 / fit.compliance / k_true - 1)
        std.append(fit.compliance_std / fit.compliance)  # std(k)/k = std(c)/c (delta method)
    return np.array([out, std])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", default=str(ROOT / "runs" / "bench_design_comparison"),
                        help="bench_design_comparison.py's cache (its designs_TAG.json)")  # fmt: skip
    parser.add_argument("--sets", default="kappa_12,kappa_20,minimax_12_588.6N,refined_12_588.6N,"
                        "minimax_20_588.6N,refined_20_588.6N")  # fmt: skip
    args = parser.parse_args()
    cache, names = Path(args.cache), args.sets.split(",")
    t0 = time.perf_counter()
    jobs = [(name, cache, 16_000 + i) for name in names for i in range(args.trials)]
    with ProcessPoolExecutor(args.workers) as pool:
        errs = list(pool.map(trial, jobs, chunksize=args.trials))
    runs = {name: np.array(errs[k * args.trials : (k + 1) * args.trials]) for k, name in enumerate(names)}
    err = {name: r[:, 0] * 100 for name, r in runs.items()}  # (trials, estimator, joint) [%]
    # z = (k - k_true) / std(k), relative: err / (reported std / k) * (k / k_true)
    z = {name: r[:, 0] / (r[:, 1] * (1 + r[:, 0])) for name, r in runs.items()}
    worst = {
        name: np.sqrt(np.mean(e**2, axis=0)).max(axis=1) for name, e in err.items()
    }  # (3,) per estimator
    print(f"# {args.trials} trials per set, seeds 16000+i; errors relative to k_true [%]")
    for name, e in err.items():
        kappa = worst.get(f"kappa_{set_size(name)}")
        print(f"\n{name}")
        for j, est in enumerate(ESTIMATORS):
            ratio = f", / kappa {worst[name][j] / kappa[j]:.3f}" if kappa is not None else ""
            print(f"  {est:>5s}: mean {np.round(e[:, j].mean(0), 3).tolist()}, std "
                  f"{np.round(e[:, j].std(0, ddof=1), 3).tolist()}; worst RMS {worst[name][j]:.3f}{ratio}; "
                  f"z-score std {np.round(z[name][:, j].std(0, ddof=1), 2).tolist()}")  # fmt: skip
    print(f"\ncells (set x joint) with a z-score std in [{HONEST[0]}, {HONEST[1]}]:")
    for j, est in enumerate(ESTIMATORS):
        zs = np.array([z[name][:, j].std(0, ddof=1) for name in names])
        inside = int(np.sum((zs >= HONEST[0]) & (zs <= HONEST[1])))
        print(f"  {est:>5s}: {inside} of {zs.size} (range {zs.min():.2f}-{zs.max():.2f})")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
