"""Screen drawn test sets by forecasts of the naming near each effect's detection limit and of
two effects hidden at once, and keep the draw furthest above issue 11's targets.

Each seed draws the paper's 20 tests with the wrist roll A6 free (and the base A1 with
``--free-a1``: ``draw_paper_variant.py``); every other table is ``scenarios/kr60_paper.toml``'s.
Per draw, each effect is sized where its own naming test has ``--limit-power`` and forecast
(``naming_forecast.py``: the linearised first round, no trials), and each pair of ``--pairs`` is
hidden at its realistic sizes and forecast through the whole search (``search_forecast.py``: both
named?). The draw's score is its worst margin to issue 11's targets: an effect's share named first
less 80 %, a pair's share with both named less 90 % (:data:`EFFECT_TARGET`, :data:`PAIR_TARGET`).
With ``--pairs ""`` that ranks the draws by the worst effect's share, as before pairs were
screened. Printed beside: how far the hardening joint's pattern and the balancer's overlap once
the stiffnesses are projected out (their largest canonical correlation in the clean world,
:func:`_discrepancy_sizes.candidate_overlap`), the pair that decided most draws tried. The screen
runs no trials, only the virtual lab's noise-free worlds and the clean world's repeat scans, so a
lab can screen its candidate draws in vtestbed before it books the robot.

Choosing the best of N by a noisy forecast flatters the winner (a winner's curse): the kept
draw's forecast is an upper estimate, and only ``bench_discrepancy.py --scenario`` trials on it
measure it. docs/discrepancy_benchmark.md has runs ("Screening drawn test sets by the forecast",
effects only; "Screening for two hidden effects", the pair weighed).

Written to ``--out-dir``: each draw's scenario (``kr60_a6[a1]_SEED.toml``) and ``screen.jsonl``,
one line per finished draw; an interrupted run re-started with the same arguments skips the draws
it finished.

    .venv/bin/python benchmarks/screen_test_sets.py --seeds 2023-2034 [--free-a1] --out-dir DIR
        [--effects a,b] [--pairs a+b,c+d] [--limit-power 0.85] [--loaded-repeats 3] [--floors 100]
        [--draws 50]

Units: shares of the forecast's datasets; sizes as factors of each effect's realistic size.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _discrepancy_worlds  # noqa: E402  (sets the BLAS threads to 1 before numpy)
import numpy as np  # noqa: E402
from _discrepancy_sizes import candidate_overlap, parse_effects  # noqa: E402
from _discrepancy_worlds import reference_floor  # noqa: E402
from draw_paper_variant import variant_text  # noqa: E402
from naming_forecast import FORECAST_EFFECTS, forecast_effect  # noqa: E402
from search_forecast import BLOCK_PAIR, forecast_pair, parse_pairs  # noqa: E402

# the middle of issue 11's "near the detection limit" band (detected 80-90 % of the time), where its
# naming target is set; bench_discrepancy.py's own default (LIMIT_POWER) is 50 %
SCREEN_POWER = 0.85
# the confusable pair whose overlap decided the hardening joint's share in every draw tried
WATCHED_PAIR = ("nonlinear_joint(2)", "gravity_compensator")
# issue 11's targets: an effect near its limit named >= 80 %, two hidden effects both named >= 90 %
EFFECT_TARGET, PAIR_TARGET = 0.80, 0.90


def seed_range(text: str) -> list[int]:
    """``"2023-2034"`` or ``"2023"`` as a list of seeds (argparse's type: a ValueError is its error)."""
    first, dash, last = text.partition("-")
    seeds = list(range(int(first), int(last if dash else first) + 1))
    if not seeds:
        raise ValueError(text)
    return seeds


def screen_draw(path: Path, names: list[str], pairs: list[str], args) -> dict:
    """One draw's forecast: per effect its size and the shares of
    :func:`naming_forecast.forecast_effect`, per pair the share :func:`search_forecast.forecast_pair`
    names both, and the draw's :func:`margins`."""
    _discrepancy_worlds.set_scenario(path)
    ref_floor = reference_floor(args.ref_repeats)
    rng = np.random.default_rng(args.forecast_seed)
    rows = [forecast_effect(n, None, ref_floor, "exact", args.limit_power, args.floors, args.draws, rng)
            for n in names]  # fmt: skip
    both = {p: forecast_pair(p, ref_floor, "exact", args.floors, args.draws, rng)["both"] for p in pairs}
    rec = {"scenario": path.name, "overlap": watched_overlap(ref_floor), "pairs": both,
           "effects": {r["name"]: {k: r[k] for k in ("factor", "own_pass", "right")} for r in rows}}  # fmt: skip
    return {**rec, **margins(rec)}


def margins(rec: dict) -> dict:
    """A draw's score from its ``effects`` and ``pairs`` shares: ``worst`` / ``worst_right`` (the
    effect named least often, None without effects), ``mean_right``, and ``margin``: its worst
    share less its target (:data:`EFFECT_TARGET`, :data:`PAIR_TARGET`), with ``short`` naming it."""
    shares = {n: e["right"] for n, e in rec["effects"].items()}
    gaps = {n: v - EFFECT_TARGET for n, v in shares.items()}
    gaps.update({p: v - PAIR_TARGET for p, v in rec.get("pairs", {}).items()})
    worst = min(shares, key=shares.get) if shares else None
    short = min(gaps, key=gaps.get)
    return {"worst": worst, "worst_right": shares.get(worst), "short": short, "margin": gaps[short],
            "mean_right": float(np.mean(list(shares.values()))) if shares else 0.0}  # fmt: skip


def watched_overlap(ref_floor) -> float:
    """The largest canonical correlation of :data:`WATCHED_PAIR`'s whitened columns, the stiffness
    columns projected out (the scenario :func:`_discrepancy_worlds.set_scenario` set, clean world)."""
    pairs = candidate_overlap(ref_floor, "exact")["pairs"]
    return pairs.get(WATCHED_PAIR, pairs.get(WATCHED_PAIR[::-1], float("nan")))


def finished(log: Path) -> dict[int, dict]:
    """The draws ``screen.jsonl`` already holds, by seed (a half-written last line is dropped)."""
    done = {}
    if log.exists():
        for line in log.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            done[rec["seed"]] = rec
    return done


def best_draw(records: list[dict]) -> dict:
    """The record whose worst margin to its target is largest (max-min, :func:`margins`), ties
    broken by the mean effect share."""
    return max(records, key=lambda r: (r["margin"], r["mean_right"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=seed_range, default=seed_range("2023-2032"), metavar="FIRST-LAST")
    ap.add_argument("--free-a1", action="store_true", help="A1 uniform within +-45 deg too")
    ap.add_argument("--out-dir", type=Path, required=True)
    ap.add_argument("--effects", default=",".join(FORECAST_EFFECTS))
    ap.add_argument(
        "--pairs", default=BLOCK_PAIR, help='pairs a+b hidden at their realistic sizes ("": none)'
    )
    ap.add_argument("--limit-power", type=float, default=SCREEN_POWER)
    ap.add_argument("--loaded-repeats", type=int, default=_discrepancy_worlds.LOADED_REPEATS)
    ap.add_argument("--ref-repeats", type=int, default=_discrepancy_worlds.REF_REPEATS)
    ap.add_argument("--floors", type=int, default=100, help="floor draws per effect (at most 400)")
    ap.add_argument("--draws", type=int, default=50, help="noise draws per floor")
    ap.add_argument("--forecast-seed", type=int, default=1)
    args = ap.parse_args()
    names = parse_effects(args.effects, ap.error)
    pairs = parse_pairs(args.pairs, ap.error)
    if not names and not pairs:
        ap.error("--effects and --pairs are both empty: nothing to screen")
    _discrepancy_worlds.set_loaded_repeats(args.loaded_repeats)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    log = args.out_dir / "screen.jsonl"
    done = finished(log)
    settings = {"free_a1": args.free_a1, "effects": names, "pairs": pairs, "limit_power": args.limit_power,
                "loaded_repeats": args.loaded_repeats, "ref_repeats": args.ref_repeats, "floors": args.floors,
                "draws": args.draws, "forecast_seed": args.forecast_seed}  # fmt: skip
    print(f"# screen_test_sets: seeds {args.seeds[0]}-{args.seeds[-1]}, {settings}")
    print(
        "| seed | "
        + " | ".join([*names, *pairs])
        + " | furthest below its target | hardening ~ balancer | s |"
    )
    print("| ---: | " + " | ".join("---:" for _ in [*names, *pairs]) + " | --- | ---: | ---: |")
    for seed in args.seeds:
        t0 = time.perf_counter()
        if seed in done and done[seed]["settings"] == settings:
            rec = done[seed]
        else:
            path = args.out_dir / f"kr60_a6{'a1' if args.free_a1 else ''}_{seed}.toml"
            path.write_text(variant_text(seed, args.free_a1))
            rec = {"seed": seed, "settings": settings, **screen_draw(path, names, pairs, args),
                   "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip
            with log.open("a") as f:  # a finished draw is kept whatever happens to the next
                f.write(json.dumps(rec) + "\n")
            done[seed] = rec
        cells = " | ".join([*(f"{rec['effects'][n]['right']:.1%}" for n in names),
                            *(f"{rec['pairs'][p]:.1%}" for p in pairs)])  # fmt: skip
        print(f"| {seed} | {cells} | {rec['short']} {100 * rec['margin']:+.1f} points "
              f"| {rec.get('overlap', float('nan')):.3f} | {rec['seconds']:.0f} |", flush=True)  # fmt: skip
    best = best_draw([done[s] for s in args.seeds])
    print(f"best draw: seed {best['seed']} ({args.out_dir / best['scenario']}), furthest below its "
          f"target: {best['short']} {100 * best['margin']:+.1f} points, mean effect {best['mean_right']:.1%}")  # fmt: skip


if __name__ == "__main__":
    main()
