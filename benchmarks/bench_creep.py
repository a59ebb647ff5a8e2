"""How often does the creep check catch a creeping loaded block? (``load_creep``, loaded_scatter)

On the paper's experiment (``scenarios/kr60_paper.toml``: 20 identification tests and the 5
validation tests, 3 repeat scans of the unloaded and 3 of the loaded block per test), per trial
(seed 2023 + i) the tests and their repeats are drawn as ``vtestbed simulate`` writes them
(``montecarlo.measure_trial``, ``repeat_frames``) and fitted by the researcher's pipeline; the
loaded repeats are drawn once per creep rate (the same noise, only the creep differs), and the
creep check (:func:`vtestbed.researcher.loaded_scatter.loaded_scatter`) is run on each.

Printed per rate: how often the check says the loaded block moved (alpha = 0.01; at rate 0 the
false-alarm rate, which must not exceed alpha), and the median ratio of the most scattered
component. Then what the creep does to the identified stiffness (``gls_floor``, weighted by the
scaled repeat-scan floor, on the 20 identification tests, displacements against the mean unloaded scan): each joint's mean error
over the trials with the loaded scans averaged whatever the check says, and as the workflow
measures (``against_scan_mean``'s default: the loaded repeats left out when the check fails).

Run: .venv/bin/python benchmarks/bench_creep.py [--trials 40] [--rates 0,0.5,1,2,4] [--workers 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
from _discrepancy_tables import clopper_pearson  # noqa: E402

import vtestbed as vt  # noqa: E402
from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames
from vtestbed.researcher.loaded_scatter import loaded_scatter
from vtestbed.researcher.measure import identify_measurements
from vtestbed.researcher.noise_floor import noise_floor_from_frames
from vtestbed.researcher.reading_noise import with_reading_noise
from vtestbed.researcher.scan_mean import against_scan_mean
from vtestbed.world.effects import LoadCreep

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
REPEATS = 3
ALPHA = 0.01
_PREPARED: dict = {}


def prepared_world():
    if not _PREPARED:
        base = vt.load_scenario(PAPER)
        scanner = dataclasses.replace(base.scanner, repeats=REPEATS, loaded_repeats=REPEATS)
        _PREPARED["world"] = prepare(dataclasses.replace(base, scanner=scanner), include_validation=True)
    return _PREPARED["world"]


def _stiffness_error(ms, unloaded, loaded, creep_alpha, truth) -> np.ndarray:
    """(n,) relative stiffness error of the identification tests measured against the scan means."""
    measured, floor = against_scan_mean(ms, unloaded, noise_floor_from_frames(unloaded), loaded, creep_alpha)
    floor = with_reading_noise(floor, measured, prepared_world().setup)  # as `identify` does
    result = identify_measurements(measured, "gls_floor", noise_floor=floor)
    return result.stiffness / truth - 1.0


def trial(args) -> list[tuple]:
    """Per rate: (the check's p-value, its largest ratio, the stiffness errors (n,) averaged and as
    the workflow measures) for trial ``seed``."""
    seed, rates = args
    prepared = prepared_world()
    tests, noise = list(prepared.tests), prepared.scenario.scanner.noise_model
    ms = measure_trial(prepared, seed, tests)
    unloaded = repeat_frames(prepared, seed, tests, ms, noise, REPEATS)
    truth = prepared.stiffness_true
    out = []
    for rate in rates:
        world = dataclasses.replace(
            prepared.scenario, effects=(LoadCreep(rate_percent=rate),) if rate else ()
        )
        loaded = repeat_frames(
            dataclasses.replace(prepared, scenario=world), seed, tests, ms, noise, REPEATS, "loaded"
        )
        check = loaded_scatter(unloaded, loaded)
        averaged = _stiffness_error(ms, unloaded, loaded, None, truth)
        workflow = _stiffness_error(ms, unloaded, loaded, ALPHA, truth)
        out.append((check.p_value, float(np.max(check.ratio)), averaged, workflow))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--rates", default="0,0.5,1,2,4", help="creep rates [%% of the deflection per scan]")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    t0 = time.perf_counter()
    jobs = [(2023 + i, rates) for i in range(args.trials)]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        rows = list(pool.map(trial, jobs))
    results = np.array([[r[:2] for r in row] for row in rows])  # (trials, rates, 2)
    errors = np.array([[r[2:] for r in row] for row in rows])  # (trials, rates, 2, n)
    print(f"# bench_creep: kr60_paper.toml, 25 tests, {REPEATS} repeats at each end, {args.trials} trials, "
          f"alpha = {ALPHA}; wall {time.perf_counter() - t0:.0f} s")  # fmt: skip
    print("\n| creep rate [% per scan] | check says moved | 95 % interval | median largest ratio |")
    print("| ---: | ---: | ---: | ---: |")
    for j, rate in enumerate(rates):
        hits = int(np.sum(results[:, j, 0] < ALPHA))
        lo, hi = clopper_pearson(hits, args.trials)
        print(f"| {rate:g} | {hits}/{args.trials} ({hits / args.trials:.0%}) | {lo:.0%}-{hi:.0%} "
              f"| {np.median(results[:, j, 1]):.2f} |")  # fmt: skip
    n = errors.shape[-1]
    print("\nMean stiffness error over the trials [%] (+- its standard error), joints 1-6; identification "
          "tests only, gls_floor against the scan means:")  # fmt: skip
    print(
        "\n| creep rate [% per scan] | loaded scans | "
        + " | ".join(f"joint {i + 1}" for i in range(n))
        + " |"
    )
    print("| ---: | --- |" + " ---: |" * n)
    for j, rate in enumerate(rates):
        for w, label in enumerate(("averaged", "workflow")):
            mean = errors[:, j, w].mean(axis=0) * 100
            sem = errors[:, j, w].std(axis=0, ddof=1) / np.sqrt(args.trials) * 100
            cells = " | ".join(f"{m:+.3f} +- {e:.3f}" for m, e in zip(mean, sem))
            print(f"| {rate:g} | {label} | {cells} |")


if __name__ == "__main__":
    main()
