"""Displacements against the test's own unloaded scan or the mean of its unloaded scans (identify).

``vtestbed identify --reference mean`` measures each displacement against the mean of the test's
unloaded scan and its repeats (:mod:`vtestbed.researcher.scan_mean`). With ``r`` repeats the
displacement noise is ``(1 + 1 / (r + 1)) / 2`` of the paper's single-scan one (0.625 at 3), so
every joint's std should fall to its square root (0.79) if nothing else limits the estimate. This
bench measures it on the paper's tests with the full pipeline: per trial (seeds 16 000 + i, as
``bench_design_comparison.py``'s), the tests and their ``--repeats`` repeat scans are measured once
and identified four ways (``fgls`` and ``gls_floor``, each against the scan and the mean).

Printed per test count and way: each joint's RMS relative error [%], the worst joint's, its ratio
to the single-scan ``fgls`` (the paper's reference), and the std of each joint's z-score
(error / reported std; honest within [0.8, 1.25], docs/uncertainty.md).

Run: .venv/bin/python benchmarks/bench_reference.py [--trials 100] [--tests 12,20] [--repeats 3]
       [--workers 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import vtestbed as vt
from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames
from vtestbed.researcher.measure import identify_measurements
from vtestbed.researcher.noise_floor import noise_floor_from_frames
from vtestbed.researcher.scan_mean import REFERENCES, against_reference

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
METHODS = ("fgls", "gls_floor")
WAYS = tuple((method, reference) for reference in REFERENCES for method in METHODS)
HONEST = (0.8, 1.25)  # z-score std range called honest (docs/uncertainty.md)
_PREPARED: dict = {}


def trial(args) -> np.ndarray:
    """(2, len(WAYS), n_joints): one trial's relative errors and reported relative stds."""
    n, repeats, seed = args
    if (n, repeats) not in _PREPARED:
        _PREPARED.clear()
        base = vt.load_scenario(PAPER)
        scenario = dataclasses.replace(base, scanner=dataclasses.replace(base.scanner, repeats=repeats))
        _PREPARED[(n, repeats)] = prepare(scenario, include_validation=False)
    prepared = _PREPARED[(n, repeats)]
    tests = prepared.identification_tests()[:n]
    ms = measure_trial(prepared, seed, tests)
    frames = repeat_frames(prepared, seed, tests, ms, prepared.scenario.scanner.noise_model, repeats)
    floor = noise_floor_from_frames(frames)
    names, k_true = prepared.scenario.robot.joint_names, prepared.stiffness_true
    err, std = [], []
    for method, reference in WAYS:
        # with the F/T readings' noise in the floor, as `identify` does
        measured, floor_r = against_reference(reference, ms, frames, floor, setup=prepared.setup)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify_measurements(measured, method, names, noise_floor=floor_r)
        err.append(res.stiffness / k_true - 1)
        std.append(res.stiffness_std / res.stiffness)
    return np.array([err, std])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--tests", default="12,20", help="comma-separated test counts (the paper's first n)")
    parser.add_argument("--repeats", type=int, default=3, help="repeat scans per test (>= 2)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    counts = [int(n) for n in args.tests.split(",")]
    t0 = time.perf_counter()
    jobs = [(n, args.repeats, 16_000 + i) for n in counts for i in range(args.trials)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(trial, jobs, chunksize=max(1, args.trials // args.workers)))
    scale = (1 + 1 / (args.repeats + 1)) / 2
    print(f"# {args.trials} trials per test count, seeds 16000+i, {args.repeats} repeat scans per test; "
          f"expected std ratio mean / scan sqrt({scale:.3f}) = {np.sqrt(scale):.3f}")  # fmt: skip
    for k, n in enumerate(counts):
        r = np.array(rows[k * args.trials : (k + 1) * args.trials])  # (trials, 2, ways, joints)
        e, s = r[:, 0] * 100, r[:, 1]
        rms = np.sqrt(np.mean(e**2, axis=0))  # (ways, joints)
        z = r[:, 0] / (s * (1 + r[:, 0]))  # (k - k_true) / std(k)
        zstd = z.std(axis=0, ddof=1)
        print(f"\n{n} tests")
        for w, (method, reference) in enumerate(WAYS):
            print(f"  {method:>9s} against the {reference:4s}: RMS {np.round(rms[w], 3).tolist()} %, "
                  f"worst {rms[w].max():.3f} % (/ fgls scan {rms[w].max() / rms[0].max():.3f}); "
                  f"z-score std {np.round(zstd[w], 2).tolist()}")  # fmt: skip
        for method in METHODS:
            i, j = WAYS.index((method, "scan")), WAYS.index((method, "mean"))
            print(f"  {method}: RMS mean / scan per joint {np.round(rms[j] / rms[i], 3).tolist()}, "
                  f"reported std mean / scan {np.round(s[:, j].mean(0) / s[:, i].mean(0), 3).tolist()}")  # fmt: skip
        inside = int(np.sum((zstd >= HONEST[0]) & (zstd <= HONEST[1])))
        print(f"  z-score std in [{HONEST[0]}, {HONEST[1]}]: {inside} of {zstd.size} cells")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
