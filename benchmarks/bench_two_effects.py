"""Two hidden effects at once: does `vtestbed diagnose` name both? (issue target: >= 90 %).

Worlds: ``scenarios/kr60_paper.toml`` with two effects hidden together, each at its realistic
default (docs/effects.md), for the pairs of the effects the workflow detects alone at that size
(docs/discrepancy_benchmark.md). Every trial is exactly a trial of
``benchmarks/bench_discrepancy.py`` (same noise draws, 3 repeat scans per test or ``--repeats``, exact statics,
alpha 0.01, stepwise naming until nothing is significant). Prints per pair: both named, one named
(and which), a wrong name among those named (the third names), nothing, with 95 % Clopper-Pearson
intervals, and the terms the backward step dropped (named in an early round, redundant once both
effects were named: diagnose.name_effects). An effect counts as named when one of its labels is
(``_discrepancy_worlds.true_labels``: the block offset's rotation or its translation).
``--out FILE`` writes every trial's record as ``bench_discrepancy.py --out`` does;
``--noise-free`` runs no trials and prints, per pair, each effect's noise-free likelihood ratio
alone and beyond the other's, with the power the search's second round has at it: with the floor
known (a chi^2 test) and against a floor estimated from the trials' repeat scans
(``floor_calibration.lr_power``, as ``bench_discrepancy.py`` sizes its worlds near the limit).

    .venv/bin/python benchmarks/bench_two_effects.py [--seeds 50] [--workers 2] [--pairs a+b,c+d]
        [--repeats 3] [--loaded-repeats 3] [--out two.json] [--noise-free]
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _discrepancy_worlds  # noqa: E402  (sets the BLAS threads to 1 before numpy)
import bench_discrepancy as bench  # noqa: E402
from _discrepancy_sizes import lr_power_inputs  # noqa: E402
from scipy.stats import chi2, ncx2  # noqa: E402

from vtestbed.files import write_json_atomic  # noqa: E402
from vtestbed.researcher.diagnose import MAX_TERMS, Whitener, fit_model, identifiable, step_level  # noqa: E402
from vtestbed.researcher.floor_calibration import lr_power  # noqa: E402
from vtestbed.world.effects import EFFECTS  # noqa: E402

PAIRS = (
    "link_compliance+joint_coupling",
    "link_compliance+ft_misalignment",
    "joint_coupling+ft_misalignment",
    "link_compliance+nonlinear_joint",
)


def tally(pair: str, records: list[dict]) -> dict:
    """Counts over the trials of ``pair`` ("a+b"): both named, one named (and which), nothing, a
    third name (a label of neither), failed trials, and the terms the backward step dropped."""
    # each hidden effect's labels: one named counts it named; a label outside them is a third name
    per_effect = [_discrepancy_worlds.true_labels(EFFECTS[n]()) for n in pair.split("+")]
    expected = frozenset().union(*per_effect)
    out = {
        "both": 0,
        "one": 0,
        "wrong": 0,
        "nothing": 0,
        "error": 0,
        "extra": Counter(),
        "dropped": Counter(),
        "alone": Counter(),  # where one of the two is named: which one
    }
    for r in records:
        if "error" in r:
            out["error"] += 1
            continue
        named = set(r["named"])
        hit = sum(bool(named & labels) for labels in per_effect)
        out["both"] += hit == 2
        out["one"] += hit == 1
        if hit == 1:
            out["alone"].update(n for n, labels in zip(pair.split("+"), per_effect) if named & labels)
        out["nothing"] += not named
        out["wrong"] += bool(named - expected)
        out["extra"].update(named - expected)
        out["dropped"].update(r.get("dropped", ()))
    return out


def noise_free_overlap(pair: str, white) -> list[dict]:
    """Noise-free, per effect of ``pair`` at its realistic size: its label's likelihood ratio alone
    and beyond the other effect's label, with its degrees of freedom and the power of the search's
    second round at that noncentrality (its level ``diagnose.step_level`` with one term named, the
    floor known). What the first pass can do for the effect named second."""
    names = pair.split("+")
    prepared, pool = _discrepancy_worlds.prepared_world(pair, 1.0)
    ctx = _discrepancy_worlds.model_context(_discrepancy_worlds.noise_free(prepared), prepared, "exact")
    base = fit_model(ctx, white, [])
    by_label = {c.label: c for c in identifiable(ctx, white, pool, base.compliance)}
    own = [by_label.get(_discrepancy_worlds.expected_label(EFFECTS[n]())) for n in names]
    level = step_level(bench.ALPHA, len(by_label) - 1, 1, MAX_TERMS)
    rows = []
    for k, name in enumerate(names):
        cand, other = own[k], own[1 - k]
        if cand is None or other is None:  # no candidate of its own (or the other's): nothing to test
            rows.append({"effect": name, "label": None})
            continue
        alone, given, both = (fit_model(ctx, white, terms) for terms in ([cand], [other], [other, cand]))
        lam, df = given.chi2 - both.chi2, both.rank - given.rank
        signal, power_args = lr_power_inputs(white, given, both, cand.label, df, len(prepared.tests), level)
        rows.append({"effect": name, "label": cand.label, "chi2": base.chi2, "alone": base.chi2 - alone.chi2,
                     "beyond_other": lam, "df": df, "level": level,
                     "power": float(ncx2.sf(chi2.isf(level, df), df, lam)),
                     "power_estimated_floor": lr_power(signal, *power_args)})  # fmt: skip
    return rows


def print_noise_free(pairs: list[str]) -> None:
    white = Whitener(_discrepancy_worlds.reference_floor(_discrepancy_worlds.REF_REPEATS))
    print(
        "| hidden pair | effect (label) | likelihood ratio alone | beyond the other's | df "
        "| power, second round (level) | the same, floor estimated |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for pair in pairs:
        for r in noise_free_overlap(pair, white):
            if r["label"] is None:
                print(f"| {pair} | {r['effect']} (no candidate) | - | - | - | - | - |")
                continue
            print(f"| {pair} (chi^2 {r['chi2']:.1f}) | {r['effect']} ({r['label']}) | {r['alone']:.1f} "
                  f"| {r['beyond_other']:.1f} | {r['df']} | {100 * r['power']:.0f} % ({r['level']:.1e}) "
                  f"| {100 * r['power_estimated_floor']:.0f} % |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--pairs", default=",".join(PAIRS), help="comma-separated a+b effect pairs")
    parser.add_argument("--out", type=Path, help="write every trial's record to this JSON file too")
    parser.add_argument("--noise-free", action="store_true",
                        help="print each pair's noise-free likelihood ratios (each effect alone and beyond the "
                             "other's) and the second round's power, and run no trials")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=_discrepancy_worlds.REPEATS,
                        help="further scans of the unloaded block per test, as bench_discrepancy.py's "
                             "(default %(default)s)")  # fmt: skip
    parser.add_argument("--loaded-repeats", type=int, default=_discrepancy_worlds.LOADED_REPEATS,
                        help="further scans of the loaded block per test, as bench_discrepancy.py's "
                             "(default 0: the paper's one loaded scan)")  # fmt: skip
    args = parser.parse_args()
    if args.loaded_repeats < 0:
        parser.error(f"--loaded-repeats: {args.loaded_repeats} is negative; valid: 0 or more")
    if args.repeats < 1:
        parser.error(f"--repeats: {args.repeats} is below 1; valid: 1 or more (the floor needs them)")
    _discrepancy_worlds.set_repeats(args.repeats)
    _discrepancy_worlds.set_loaded_repeats(args.loaded_repeats)
    pairs = [p.strip() for p in args.pairs.split(",") if p.strip()]
    for pair in pairs:
        bad = [n for n in pair.split("+") if n not in EFFECTS] or ([] if pair.count("+") == 1 else [pair])
        if bad:
            parser.error(
                f"--pairs: {bad[0]!r} is not a pair of effects a+b; valid effects: {', '.join(EFFECTS)}"
            )
    if args.noise_free:
        print_noise_free(pairs)
        return
    seeds = [bench.SEED0 + k for k in range(args.seeds)]
    t0 = time.perf_counter()
    results: dict[str, list[dict]] = {p: [] for p in pairs}
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=ctx) as pool:
        futures = {
            pool.submit(bench.run_chunk, pair, 1.0, seeds[i : i + bench.CHUNK], "exact"): pair
            for pair in pairs
            for i in range(0, len(seeds), bench.CHUNK)
        }
        for fut in as_completed(futures):
            results[futures[fut]].extend(fut.result()[0])
            done = sum(map(len, results.values()))
            print(
                f"{done}/{len(pairs) * len(seeds)} trials, {time.perf_counter() - t0:.0f} s", file=sys.stderr
            )
    wall = time.perf_counter() - t0
    if args.out:  # before the tables: a fault in them must not lose the run
        write_json_atomic(
            args.out,
            {
                "seeds": seeds,
                "repeats": args.repeats,
                "loaded_repeats": args.loaded_repeats,
                "results": results,
            },
        )
    print(f"# bench_two_effects: {bench.SCENARIO.name}, {args.seeds} seeds per world (seed {bench.SEED0}+k), "
          f"realistic sizes, {args.repeats} unloaded and {args.loaded_repeats} loaded repeats, alpha {bench.ALPHA}; wall {wall:.0f} s\n")  # fmt: skip
    print(
        "| hidden pair | n | both named [95 % CI] | one named (which) | a third name too | nothing | errors "
        "| third names (count) | dropped by the backward step (count) |"
    )
    print("| --- | ---: | ---: | --- | ---: | ---: | ---: | --- | --- |")
    for pair in pairs:
        t, n = tally(pair, results[pair]), len(results[pair])
        lo, hi = bench.clopper_pearson(t["both"], n)
        print(f"| {pair.replace('+', ' + ')} | {n} | {100 * t['both'] / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] "
              f"| {t['one']}{' (' + ', '.join(f'{k} {v}' for k, v in t['alone'].most_common()) + ')' if t['one'] else ''} "
              f"| {t['wrong']} | {t['nothing']} | {t['error']} "
              f"| {', '.join(f'{k} ({v})' for k, v in t['extra'].most_common(3))} "
              f"| {', '.join(f'{k} ({v})' for k, v in t['dropped'].most_common(3))} |")  # fmt: skip
    for pair in pairs:
        for r in results[pair]:
            if "error" in r:
                print(f"error in {pair} seed {r['seed']}: {r['error']}", file=sys.stderr)
                break


if __name__ == "__main__":
    main()
