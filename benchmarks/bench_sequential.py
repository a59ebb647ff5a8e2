"""The sequential design as a procedure: many independent days, each from its own wrong prior.

Issue 16, item 4: from a prior off by x0.5 or x2 per joint, the loop ``vtestbed poses next`` runs
must reach within 1.2x of the worst-joint error of the design made with the true stiffness (20
tests), and the number of tests it needs to match the best fixed 20-test design is asked for.
``bench_design_comparison.py`` runs one realisation of the loop per prior and evaluates its test
list with 40 fresh noise draws; its intervals (upper ends 1.26-1.48) cannot confirm the target.
This benchmark measures what a lab experiences instead, a day at a time:

* realisation r draws its prior factors, each joint x0.5 or x2 at random (``default_rng([SEED, r])``),
  chooses a 6-test minimax pilot with that prior from the design pool, measures it once through the
  full pipeline (MuJoCo equilibrium and ray cast, scanner and F/T noise, the researcher's cloud fits;
  :func:`~vtestbed.campaigns.montecarlo.measure_trial`, seed ``LOOP_SEED + 100 r + batch``),
  identifies it (FGLS) and adds batches by :func:`vtestbed.design.sequential.next_tests` to 9, 12,
  16, 20, 24 and 28 tests, each measured once as it is chosen; its error at n tests is the FGLS
  estimate of its own first n measured tests against the truth;
* the reference: the true-prior 20-test minimax design (the set ``bench_design_comparison.py``
  measures, prior = Table 5), one fixed list measured in ``--ref-trials`` trials (seeds 16000 + i);
* for contrast, realisation r's prior also designs a fixed 20-test list at once (no loop), measured
  once with the loop's pilot seed.

Printed per panel (``--panels 200,limit``: top tension 200 N and the lab's limit): the worst joint's
RMS relative error at each n over the realisations with a bootstrap 95 % interval, the ratio of the
loop at 20 tests to the reference (bootstrap, realisations and trials resampled independently),
the first n at which the loop's RMS is at or below the reference's, and the linear model's
prediction at the truth. Every realisation is appended to ``--cache``/sequential_<panel>.jsonl as
it ends, so an interrupted run keeps what it finished and a second run only summarises.

Run: .venv/bin/python benchmarks/bench_sequential.py [--realisations 100] [--ref-trials 200]
       [--workers 2] [--panels 200,limit]
(about 25 s per realisation on one core, plus 20 s per worker and panel for the pool;
docs/poses.md, "Sequential design").
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one BLAS thread per worker: the workers are the parallelism

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from bench_design_comparison import broad_pool, measure_once, plan_of, worst_rms  # noqa: E402

import vtestbed as vt  # noqa: E402
from vtestbed.campaigns.montecarlo import measure_trial, prepare  # noqa: E402
from vtestbed.design import minimax  # noqa: E402
from vtestbed.design import optimal as design  # noqa: E402
from vtestbed.design.priors import PAPER_TABLE5  # noqa: E402
from vtestbed.design.sequential import next_tests, noise_from_residuals  # noqa: E402
from vtestbed.researcher.identify import identify  # noqa: E402
from vtestbed.researcher.measure import stacked  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
STEPS = (6, 9, 12, 16, 20, 24, 28)  # tests made after the pilot and each batch
TARGET_N = 20
TARGET_RATIO = 1.2
SEED = 16_016  # the prior factors of realisation r: default_rng([SEED, r])
LOOP_SEED = 900_000  # realisation r's batch b is measured with LOOP_SEED + 100 r + b
REF_SEED = 16_000  # the reference design's trial i (as bench_design_comparison.py)
POOL_POSES = 400
BOOT = 4000

_STATE: dict = {}  # per worker process: the scenario and the panel's design pool


def _init(tension: float) -> None:
    base = vt.load_scenario(PAPER)
    _STATE.update(base=base, cands=broad_pool(base, POOL_POSES, tension))


def relative_error(meas: list) -> list[float]:
    """FGLS estimate of the measured tests over the truth, minus 1 (per joint)."""
    j, w, d = stacked(meas)
    res = identify(j, w, d, method="fgls")
    return (res.stiffness / PAPER_TABLE5.stiffness - 1).tolist()


def realisation(r: int) -> dict:
    """One lab day: prior, pilot, batches; the errors after each step and the fixed wrong-prior design."""
    base, cands, k = _STATE["base"], _STATE["cands"], PAPER_TABLE5.stiffness
    t0 = time.perf_counter()
    factors = 2.0 ** np.random.default_rng([SEED, r]).choice([-1.0, 1.0], size=k.size)
    prior = k * factors
    chosen = [int(i) for i in minimax.design(cands.a, STEPS[0], prior, bound=False).selection.indices]
    meas = measure_once(base, [cands.tests[i] for i in chosen], LOOP_SEED + 100 * r)
    j, w, d = stacked(meas)
    res = identify(j, w, d, method="fgls")  # once per step: the day's error and the next batch's prior
    errors = {STEPS[0]: (res.stiffness / k - 1).tolist()}
    for b, n in enumerate(STEPS[1:], start=1):
        sp, sr = noise_from_residuals(res.component_std)
        batch = next_tests(j, w, res.stiffness, n - len(chosen), cands, sp, sr)
        new = [int(i) for i in batch.result.selection.indices]
        chosen += new
        meas += measure_once(base, [cands.tests[i] for i in new], LOOP_SEED + 100 * r + b)
        j, w, d = stacked(meas)
        res = identify(j, w, d, method="fgls")
        errors[n] = (res.stiffness / k - 1).tolist()
    predicted = {n: design.evaluate(cands.a[chosen[:n]], k).minimax_value for n in STEPS}
    once = minimax.design(cands.a, TARGET_N, prior, bound=True).selection.indices
    once_err = relative_error(measure_once(base, [cands.tests[i] for i in once], LOOP_SEED + 100 * r))
    return {"r": r, "prior_factors": factors.tolist(), "chosen": chosen,
            "errors": {str(n): e for n, e in errors.items()},
            "predicted_worst": {str(n): p for n, p in predicted.items()},
            "fixed_wrong_prior_error": once_err,
            "fixed_wrong_prior_predicted": design.evaluate(cands.a[list(once)], k).minimax_value,
            "seconds": time.perf_counter() - t0}  # fmt: skip


def reference(cache: Path, tag: str, tension: float, trials: int) -> np.ndarray:
    """(trials, joints) relative errors of the true-prior 20-test minimax design (cached .npy)."""
    path = cache / f"reference_{tag}_trials{trials}.npy"
    if path.exists():
        return np.load(path)
    if "cands" not in _STATE:
        _init(tension)
    base, cands = _STATE["base"], _STATE["cands"]
    sel = minimax.design(cands.a, TARGET_N, PAPER_TABLE5.stiffness, bound=True).selection.indices
    prepared = prepare(plan_of("minimax_true_prior", [cands.tests[i] for i in sel]).scenario(base))
    err = np.array([relative_error(measure_trial(prepared, REF_SEED + i)) for i in range(trials)])
    np.save(path, err)
    return err


def run_realisations(path: Path, count: int, tension: float, workers: int) -> list[dict]:
    """Every realisation 0..count-1, the finished ones read from ``path`` (JSON lines), the rest run."""
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                done[rec["r"]] = rec
    todo = [r for r in range(count) if r not in done]
    if todo:
        print(f"  {len(done)} realisations cached, running {len(todo)} on {workers} worker(s)", flush=True)
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init, initargs=(tension,)) as pool:
            futures = [pool.submit(realisation, r) for r in todo]
            with path.open("a") as out:
                for i, fut in enumerate(as_completed(futures), start=1):
                    rec = fut.result()
                    out.write(json.dumps(rec) + "\n")
                    out.flush()  # an interrupted run keeps every finished realisation
                    done[rec["r"]] = rec
                    print(f"  realisation {rec['r']}: {rec['seconds']:.0f} s ({i}/{len(todo)})", flush=True)
    return [done[r] for r in range(count)]


def interval(x: np.ndarray) -> str:
    lo, hi = np.percentile(x, [2.5, 97.5])
    return f"[{lo:.3f}, {hi:.3f}]"


def summarise(tag: str, recs: list[dict], ref: np.ndarray) -> dict:
    """Print the panel's table and return its numbers (percent)."""
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(recs), size=(BOOT, len(recs)))
    ref_idx = rng.integers(0, len(ref), size=(BOOT, len(ref)))
    ref_boot = worst_rms(ref, ref_idx)
    ref_worst = worst_rms(ref)
    print(f"\n{tag}: {len(recs)} realisations of the loop, the reference in {len(ref)} trials")
    print(f"reference, true-prior minimax {TARGET_N} tests: worst RMS {ref_worst * 100:.3f} % "
          f"{interval(ref_boot * 100)}")  # fmt: skip
    print(f"{'tests':>5s} {'worst RMS [%]':>13s} {'95 % interval':>17s} {'/ reference':>11s} {'95 % interval':>15s}"
          f" {'joint':>5s} {'pred. [%]':>9s}")  # fmt: skip
    rows, match = [], None
    for n in STEPS:
        err = np.array([rec["errors"][str(n)] for rec in recs])
        boot = worst_rms(err, idx)
        worst = worst_rms(err)
        ratio = boot / ref_boot
        pred = float(np.sqrt(np.mean([rec["predicted_worst"][str(n)] ** 2 for rec in recs])))
        joint = int(np.argmax(np.sqrt(np.mean(err**2, axis=0)))) + 1
        if match is None and worst <= ref_worst:
            match = n
        lo, hi = np.percentile(ratio, [2.5, 97.5])
        rows.append({"n": n, "worst_rms_percent": worst * 100, "ci": np.percentile(boot * 100, [2.5, 97.5]).tolist(),
                     "ratio": worst / ref_worst, "ratio_ci": [lo, hi], "worst_joint": joint,
                     "predicted_percent": pred * 100})  # fmt: skip
        print(f"{n:5d} {worst * 100:13.3f} {interval(boot * 100):>17s} {worst / ref_worst:11.3f} "
              f"{interval(ratio):>15s} {joint:5d} {pred * 100:9.3f}")  # fmt: skip
    once = np.array([rec["fixed_wrong_prior_error"] for rec in recs])
    once_worst, once_boot = worst_rms(once), worst_rms(once, idx)
    once_ratio = once_boot / ref_boot
    print(f"fixed {TARGET_N}-test design made once with the wrong prior: worst RMS {once_worst * 100:.3f} % "
          f"{interval(once_boot * 100)}, / reference {once_worst / ref_worst:.3f} {interval(once_ratio)}")  # fmt: skip
    at = next(r for r in rows if r["n"] == TARGET_N)
    if at["ratio_ci"][1] <= TARGET_RATIO:
        verdict = "met"
    else:
        verdict = "met as a point estimate" if at["ratio"] <= TARGET_RATIO else "MISSED"
    print(f"target: the loop at {TARGET_N} tests within {TARGET_RATIO}x of the reference: {at['ratio']:.3f} "
          f"[{at['ratio_ci'][0]:.3f}, {at['ratio_ci'][1]:.3f}]: {verdict}; tests to match the reference: "
          f"{match if match is not None else f'> {STEPS[-1]}'}")  # fmt: skip
    seconds = [rec["seconds"] for rec in recs]
    print(f"time per realisation: median {np.median(seconds):.0f} s")
    return {"panel": tag, "realisations": len(recs), "reference_trials": len(ref),
            "reference_worst_rms_percent": ref_worst * 100, "reference_ci": np.percentile(ref_boot * 100, [2.5, 97.5]).tolist(),
            "rows": rows, "tests_to_match": match, "fixed_wrong_prior_ratio": once_worst / ref_worst,
            "fixed_wrong_prior_ratio_ci": np.percentile(once_ratio, [2.5, 97.5]).tolist()}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--realisations", type=int, default=100, help="lab days per panel (default %(default)s)"
    )
    parser.add_argument("--ref-trials", type=int, default=200,
                        help="trials of the true-prior reference design (default %(default)s)")  # fmt: skip
    parser.add_argument("--workers", type=int, default=2, help="processes (default %(default)s)")
    parser.add_argument(
        "--panels", default="200,limit", help="top tensions: N or 'limit' (default %(default)s)"
    )
    parser.add_argument("--cache", default=str(ROOT / "runs" / "bench_sequential"),
                        help="directory for the realisations and the reference trials (default %(default)s)")  # fmt: skip
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    base = vt.load_scenario(PAPER)
    t0 = time.perf_counter()
    out = []
    for item in args.panels.split(","):
        tension = base.lab.max_tension[0] if item == "limit" else float(item)
        tag = f"{tension:g}N"
        print(f"\npanel {tag}: tensions up to {tension:g} N", flush=True)
        _STATE.clear()
        recs = run_realisations(cache / f"sequential_{tag}.jsonl", args.realisations, tension, args.workers)
        ref = reference(cache, tag, tension, args.ref_trials)
        out.append(summarise(tag, recs, ref))
    (cache / f"summary_{args.realisations}.json").write_text(json.dumps(out, indent=1))
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
