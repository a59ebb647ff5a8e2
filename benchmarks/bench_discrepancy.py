"""The discrepancy workflow's confusion matrix: which hidden effect does it name, and how often?

Run: .venv/bin/python benchmarks/bench_discrepancy.py [--seeds 50] [--workers 2] [--effects a,b] [--quick]
       [--repeats 3] [--loaded-repeats 3] [--limit-factor scanner_scale=10.32]

Worlds: ``scenarios/kr60_paper.toml`` (20 identification tests at 200 N, the 5 Table 6
validation tests) clean, and with each effect of ``vtestbed.world.effects.EFFECTS`` hidden alone
at two sizes: its realistic default (x1) and "near the detection limit" (x f_lim, below).

Per world the physics is done once (:func:`vtestbed.campaigns.montecarlo.prepare`, the rig of
``dataclasses.replace(scenario, effects=(effect,))``); per seed the noise is drawn exactly as
``vtestbed simulate`` would write that dataset with ``[scanner] repeats = 3``
(:func:`~vtestbed.world.physics.test_rng` and ``draw_readings`` with the world's effects for the
test's own scans and readings, :func:`~vtestbed.world.repeats.repeat_rng` and
``draw_repeat_scans`` for 3 repeats of every test, validation tests included; ``--repeats R``
for R), reduced by the
researcher's own code (``measure_arrays``; ``scan_frames`` -> ``noise_floor_from_frames``, the
floor ``estimate_noise_floor`` gives from the files; ``against_scan_mean``: every displacement
against its test's mean unloaded scan, as ``load_with_floor`` measures a dataset since
2026-11-27; with ``--loaded-repeats R`` also R repeats of the loaded block,
``[scanner] loaded_repeats``, averaged at the other end) and diagnosed as
:func:`vtestbed.researcher.discrepancy.diagnose` does by default: ``name_effects(ModelContext(...,
ExactStatics(kin, setup)), Whitener(floor), candidates(kin), alpha=0.01)`` (stepwise: forward,
and backward after each addition) and ``validation_gap``
before and after (``--statics paper``: the paper's linear model as the baseline). As ``diagnose``,
the trial first settles ``scanner_scale`` by the block's size (``block_size.scale_check`` on the
tests' apparent edges, ``scale_term.settle_scale``: measured and the translations corrected,
ruled out, or left a candidate); a trial's record keeps the check and what it decided.

Size "near the detection limit": the factor ``f_lim`` on the effect's size (stiffness of a
compliance divided by f, everything else multiplied by f) at which the first round's
likelihood-ratio test of the effect's own candidate (the best of its family on noise-free data,
df = its parameter count, Bonferroni level alpha / the number of candidates) has 50 % power
(``--limit-power``; issue 11 scores its accuracy target at 0.8-0.9) against a floor estimated,
as in the trials, from 3 repeats of the 25 tests
(:func:`vtestbed.researcher.floor_calibration.lr_power`: the noise-free effect's likelihood
ratio under the floor's parametric bootstrap and Gaussian noise, beyond the calibrated critical
value). ``--known-floor`` sizes by the chi^2 power with the floor known exactly instead (the
sizes until 2026-11-26, 5-10 % smaller). The noise-free noncentrality is ``lambda =
chi2(baseline) - chi2(baseline + candidate)`` on noise-free data (perfect scanner and F/T
sensor, the researcher's own reduction) whitened by a reference floor (clean world, 200 repeats
of the 25 tests, seed 977; 10 until 2026-11-29); the target ``lambda*`` is the effect's pattern at x1 scaled until
it has the power. For an effect without a candidate the global detection test (chi^2 of the
baseline, df 114, level alpha) is used instead, with the floor known.
``lambda`` grows as f^2; f_lim is found by a secant search on log f (at most 6 noise-free
evaluations, to 20 % in lambda), bounded by the parameter's range and by the largest size whose
scans the researcher can still reduce (a world the cloud fit refuses is a bound, not a result).
The power at the f_lim found is printed beside the accuracy. ``--limit-factor NAME=F`` gives an
effect's near-limit size instead, for an effect another test detects first: the scanner's scale,
which the block's size check detects at about x10.32 in 85 % of datasets
(``bench_block_size.py``), far below its naming test's size.

Scoring: "correct" when the set of named effect names is exactly the hidden effect's (several
labels of one family count once); for gravity_compensator at its realistic size, below detection
by design, "nothing" is correct too; a clean world is correct when nothing is named (a false
alarm otherwise). An effect without a candidate term (``candidates.CANDIDATE_NAMES``; today
geometric_error) is shown, not scored. Every random draw comes from a numpy Generator seeded from
the trial's seed.

Code: ``_discrepancy_worlds.py`` (the worlds and one trial), ``_discrepancy_sizes.py`` (f_lim and
the candidates' overlap), ``_discrepancy_tables.py`` (scoring and the printed tables); this file
runs them on a process pool. ``bench_discriminate.py`` and ``bench_two_effects.py`` import the
names they share from here.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import _discrepancy_worlds  # before numpy: it sets the BLAS threads to 1 (in every spawned worker too)
import numpy as np
from _discrepancy_sizes import (
    LIMIT_POWER,
    calibrate,
    candidate_overlap,
    given_size,
    parse_effects,
    parse_factors,
)
from _discrepancy_tables import clopper_pearson, report
from _discrepancy_worlds import (  # the names bench_discriminate / bench_two_effects use
    ALPHA,
    CHUNK,
    DEFAULT_EFFECTS,
    REF_REPEATS,
    REF_SEED,
    SCENARIO,
    SEED0,
    SIZE_FIELDS,
    expected_label,
    reference_floor,
    run_chunk,
    scaled,
    world_key,
)

from vtestbed.researcher.diagnose import RANK_CRITERIA
from vtestbed.world.effects import EFFECTS

__all__ = ["ALPHA", "CHUNK", "SCENARIO", "SEED0", "SIZE_FIELDS", "clopper_pearson", "expected_label",
           "run_chunk", "scaled"]  # fmt: skip


# ---------------------------------------------------------------------------- main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=50, help="trials per world")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--effects", default=",".join(DEFAULT_EFFECTS), help="comma-separated effect names")
    parser.add_argument("--quick", action="store_true", help="smoke run: 2 seeds, a coarse f_lim search")
    parser.add_argument("--statics", choices=("exact", "paper"), default="exact",
                        help="the baseline, as `vtestbed diagnose --statics` (default exact)")  # fmt: skip
    parser.add_argument("--out", type=Path, help="write every trial's record to this JSON file")
    parser.add_argument("--limit-power", type=float, default=LIMIT_POWER,
                        help="theoretical power of the naming test that defines 'near the detection limit' "
                             "(default 0.5: the 50 %% detection magnitude; issue 11's accuracy target is at 0.8-0.9)")  # fmt: skip
    parser.add_argument("--known-floor", action="store_true",
                        help="size 'near the detection limit' by the power with the floor known exactly "
                             "(the sizes until 2026-11-26; default: against the trials' estimated floor)")  # fmt: skip
    only = parser.add_mutually_exclusive_group()
    only.add_argument(
        "--limit-only", action="store_true", help="only the near-limit worlds (no clean, no x1)"
    )
    only.add_argument(
        "--realistic-only", action="store_true", help="only the realistic sizes, x1 (no clean, no near-limit)"
    )
    parser.add_argument("--limit-factor", action="append", default=[], metavar="NAME=F",
                        help="size NAME's near-limit world at F instead of by its naming test's power: an "
                             "effect another test detects first (scanner_scale: the block's size, "
                             "benchmarks/bench_block_size.py); repeatable")  # fmt: skip
    parser.add_argument(
        "--scenario",
        type=Path,
        default=_discrepancy_worlds.SCENARIO,
        help="the experiment (default: the paper's)",
    )
    parser.add_argument("--repeats", type=int, default=_discrepancy_worlds.REPEATS,
                        help="further scans of the unloaded block per test, the floor's samples and "
                             "averaged into each displacement (default %(default)s; [scanner] repeats)")  # fmt: skip
    parser.add_argument("--loaded-repeats", type=int, default=_discrepancy_worlds.LOADED_REPEATS,
                        help="further scans of the loaded block per test, averaged into each displacement "
                             "(default 0: the paper's one loaded scan; [scanner] loaded_repeats)")  # fmt: skip
    parser.add_argument("--rank", choices=RANK_CRITERIA, default=_discrepancy_worlds.RANK,
                        help="how diagnose ranks the significant candidates (default %(default)s)")  # fmt: skip
    args = parser.parse_args()
    # the workers read them from the environment when they import _discrepancy_worlds
    _discrepancy_worlds.RANK = os.environ["VTESTBED_BENCH_RANK"] = args.rank
    if args.repeats < 1 or args.loaded_repeats < 0:
        parser.error(f"--repeats {args.repeats}, --loaded-repeats {args.loaded_repeats}: valid: "
                     "--repeats 1 or more (the floor needs them), --loaded-repeats 0 or more")  # fmt: skip
    _discrepancy_worlds.set_repeats(args.repeats)
    _discrepancy_worlds.set_loaded_repeats(args.loaded_repeats)
    _discrepancy_worlds.set_scenario(args.scenario)
    names = parse_effects(args.effects, parser.error)
    seeds = 2 if args.quick else args.seeds
    max_evals = 3 if args.quick else 6
    given = parse_factors(args.limit_factor, names, "--limit-factor", parser.error)

    limit_names = [] if args.realistic_only else names  # the effects sized near their detection limit
    given = {n: f for n, f in given.items() if n in limit_names}
    t0 = time.perf_counter()
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=ctx) as pool:
        ref = pool.submit(reference_floor, 3 if args.quick else REF_REPEATS)
        ref_floor = ref.result()
        print(f"reference floor (clean world, seed {REF_SEED}): std "
              + " ".join(f"{s * 1e6:.2f}" for s in np.sqrt(np.diag(ref_floor.covariance))) + " (um, urad)", file=sys.stderr)  # fmt: skip
        cal_futures = {
            pool.submit(
                calibrate, n, ref_floor, max_evals, args.statics, args.limit_power, args.known_floor
            ): n
            for n in limit_names
            if n not in given
        }
        for n, f in given.items():  # sized by another test: no noncentrality to report
            cal_futures[pool.submit(given_size, n, f, args.limit_power)] = n
        overlap_future = pool.submit(candidate_overlap, ref_floor, args.statics)
        clean = [] if args.limit_only or args.realistic_only else [(None, "clean", 1.0)]
        worlds = clean + ([] if args.limit_only else [(n, "realistic", 1.0) for n in names])
        pending, results, t_prep = {}, {}, 0.0
        seed_list = [SEED0 + k for k in range(seeds)]

        def submit_world(name, size, factor):
            results[world_key(name, size)] = []
            for i in range(0, len(seed_list), CHUNK):
                fut = pool.submit(run_chunk, name, factor, seed_list[i : i + CHUNK], args.statics)
                pending[fut] = world_key(name, size)

        for w in worlds:
            submit_world(*w)
        cal, waiting = {}, set(cal_futures) | set(pending)
        total = seeds * (len(worlds) + len(cal_futures))  # each calibration adds a near-limit world
        while waiting:
            done, waiting = wait(waiting, return_when=FIRST_COMPLETED)
            for fut in done:
                if fut in cal_futures:
                    c = fut.result()
                    cal[c["name"]] = c
                    worlds.append((c["name"], "limit", c["factor"]))
                    before = set(pending)
                    submit_world(c["name"], "limit", c["factor"])
                    waiting |= set(pending) - before
                    print(f"f_lim {c['name']}: x{c['factor']:.3g} (lambda {c['lambda_at_limit']:.1f} for "
                          f"{c['target']:.1f})", file=sys.stderr)  # fmt: skip
                else:
                    recs, tp = fut.result()
                    results[pending.pop(fut)].extend(recs)
                    t_prep += tp
                    n_done = sum(len(v) for v in results.values())
                    print(f"{n_done}/{total} trials, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        overlap = overlap_future.result()
    wall = time.perf_counter() - t0

    order = {n: i for i, n in enumerate(EFFECTS)}
    worlds.sort(key=lambda w: (-1 if w[0] is None else order[w[0]], w[1] != "realistic"))
    for rs in results.values():
        rs.sort(key=lambda r: r["seed"])
    cal = {n: cal[n] for n in sorted(cal, key=order.get)}
    print(f"# bench_discrepancy: {_discrepancy_worlds.SCENARIO.name}, {seeds} seeds per world (seed {SEED0}+k), r = {_discrepancy_worlds.REPEATS} "
          f"repeats per test, {_discrepancy_worlds.LOADED_REPEATS} loaded repeats, alpha = {ALPHA}, {args.statics} statics, {args.workers} workers; wall {wall:.0f} s")  # fmt: skip
    if args.out:  # before the tables: a run's records outlive a fault in the report
        args.out.write_text(
            json.dumps({"worlds": worlds, "calibration": cal, "results": results}, default=float)
        )
    report(worlds, results, cal, overlap, seeds, wall, t_prep)
    errors = [(k, r) for k, rs in results.items() for r in rs if "error" in r]
    for k, r in errors[:3]:
        print(f"\nERROR in {k}, seed {r['seed']}: {r['error']}\n{r['trace']}")


if __name__ == "__main__":
    main()
