"""Named correctly before and after one round of discrimination tests, near the detection limit.

Run: .venv/bin/python benchmarks/bench_discriminate.py [--seeds 10] [--first 1] [--extra-tests 10]
     [--scenario scenarios/kr60_confusable.toml] [--factor F | --world a,b] [--always] [--rounds R]
     [--separation [T]] [--max-extra-tests K] [--loaded-repeats R] [--workers 1]
     [--rerun LOG [--reasons marginal]]
     [--out /tmp/bench_discriminate]

Each seed runs :func:`vtestbed.discovery.discover` on the scenario (by default
``scenarios/kr60_confusable.toml``: the paper's 20 tests with 3 repeats, link 2 compliance hidden
at x0.2, about 50 % power for its own naming test) with that seed: simulate, diagnose, and when
the diagnosis is confusable or marginal (every seed with ``--always``: then a decisive diagnosis
is confirmed or screened, :func:`vtestbed.design.discriminate.confirming_rivals`), propose
``--extra-tests`` T-optimal tests, simulate them in the same world and diagnose the combined
dataset. ``--factor F`` sets each hidden effect to F times its realistic size (x0.237 for link 2
is the size at 85 % power, ``bench_discrepancy.py --limit-power 0.85``). Correct = the named labels
are exactly ``--expected`` (default ``link_compliance(link 2)``; ``a+b`` for two hidden effects,
``nothing`` for the clean world, ``--factor 0``); "family" = the named effect names are exactly
those of ``--expected``. Datasets go to ``--out/s<seed>`` (about 200 MB each; deleted
unless --keep). A confusable seed's row also holds the rivals of the rule before 2026-11-29
(``rivals_without_reserve``: no place kept for the runner-up's stand-in), so a re-run shows which
seeds' rounds that rule changed.
"""

from __future__ import annotations

import argparse
import copy
import json
import multiprocessing
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from bench_discrepancy import (  # benchmarks/ is on sys.path when run as a script
    SIZE_FIELDS,
    clopper_pearson,
    scaled,
)

from vtestbed.design.discriminate import SEPARATION_TARGET
from vtestbed.design.rivals import rivals_from_report
from vtestbed.discovery import discover
from vtestbed.errors import VtestbedError
from vtestbed.scenario import parse_scenario, read_scenario_file
from vtestbed.world.effects import EFFECTS

ROOT = Path(__file__).resolve().parents[1]


def scenario_for(
    path: str, seed: int, factor: float | None, world: tuple[str, ...] = (), loaded_repeats: int | None = None
):
    """The scenario at ``path`` with ``seed``; with ``factor``, each hidden effect at ``factor`` times
    its realistic default size (the factors ``bench_discrepancy.py --limit-power`` prints); with
    ``factor = 0`` the clean world (nothing hidden); ``world`` (effect names) replaces the hidden
    effects by those effects at their realistic defaults; ``loaded_repeats`` (None: the
    scenario's) sets ``[scanner] loaded_repeats``, the further scans of the loaded block."""
    raw = copy.deepcopy(read_scenario_file(path)) | {"seed": seed}
    if loaded_repeats is not None:
        raw["scanner"] = raw.get("scanner", {}) | {"loaded_repeats": loaded_repeats}
    if world:
        raw["world"] = {"effects": [{"name": name} for name in world]}
    if factor == 0:
        raw.pop("world", None)
        return parse_scenario(raw, Path(path))
    for effect in raw.get("world", {}).get("effects", []) if factor is not None else []:
        sized = scaled(EFFECTS[effect["name"]](), factor)
        for name in SIZE_FIELDS[effect["name"]]:
            value = getattr(sized, name)
            effect[name] = list(value) if isinstance(value, tuple) else value
    return parse_scenario(raw, Path(path))


def run_seed(
    path: str,
    seed: int,
    factor,
    extra_tests: int,
    always: bool,
    out: str,
    keep: bool,
    world=(),
    rounds=1,
    separation=None,
    max_extra_tests=None,
    loaded_repeats=None,
) -> dict:
    sc = scenario_for(path, seed, factor, world, loaded_repeats)
    folder = Path(out) / f"s{seed}"
    # the seed's folder is this benchmark's scratch: one an interrupted run left (its worker killed
    # mid-seed) would make discover refuse to mix scenarios, and fail the seed
    shutil.rmtree(folder, ignore_errors=True)
    t0 = time.perf_counter()
    try:
        r = discover(sc, folder, extra_tests=extra_tests, always=always, rounds=rounds, separation=separation,
                     max_extra_tests=max_extra_tests)  # fmt: skip
    except VtestbedError as exc:  # one seed's failure is a result (scored as not named), not the run's end
        shutil.rmtree(folder, ignore_errors=True)
        return {"seed": seed, "before": None, "after": None, "proposed": None,
                "error": f"{type(exc).__name__}: {exc}", "wall_s": time.perf_counter() - t0}  # fmt: skip
    after = r["named_after"] if r["named_after"] is not None else r["named_before"]
    row = {"seed": seed, "before": r["named_before"], "after": after, "proposed": r["rivals"] is not None,
           "reason": (r["rivals"] or {}).get("reason"), "rivals": (r["rivals"] or {}).get("rivals"),
           "t_before": (r["proposal"] or {}).get("separation_before"),
           "t_after": (r["proposal"] or {}).get("separation_after"),
           "dbic_before": r.get("measured_before", {}).get("delta_bic"),
           "dbic_after": r.get("measured_after", {}).get("delta_bic"),
           "val_before": r.get("validation_gap_before"), "val_after": r.get("validation_gap_after"),
           "rounds_run": len(r.get("rounds") or ()),
           "extra_tests": sum(len(k["proposal"]["tests"]) for k in r.get("rounds") or ()),
           "after_round1": (r.get("rounds") or [{}])[0].get("named", r["named_before"]),
           "wall_s": time.perf_counter() - t0}  # fmt: skip
    row["scale"] = [
        scale_record(folder / f"round{k}" / "diagnose" / "report.json") for k in range(row["rounds_run"] + 1)
    ]
    if row["reason"] == "confusable":  # the rivals before the runner-up's stand-in had a place
        row["rivals_without_reserve"] = rivals_without_reserve(folder / "round0" / "diagnose" / "report.json")
    if not keep:
        shutil.rmtree(folder, ignore_errors=True)
    return row


def scale_record(report_path: Path) -> dict | None:
    """What a diagnosis's block check measured and decided (``scale_ppm``, ``std_ppm``, ``action``),
    per round; None without the report or the check."""
    if not report_path.exists():
        return None
    report = json.loads(report_path.read_text())
    check, term = report.get("scale_check"), report.get("scale_term")
    if not check:
        return None
    return {"scale_ppm": check["scale_ppm"], "std_ppm": check["std_ppm"], "n_tests": check["n_tests"],
            "action": term and term["action"]}  # fmt: skip


def rivals_without_reserve(report_path: Path) -> list[str] | None:
    """A confusable round's rivals without the place kept for the runner-up's stand-in (the rule
    before 2026-11-29): the same report with its ``runner_overlap`` column left out."""
    report = json.loads(report_path.read_text())
    for rnd in report["rounds"]:
        for test in rnd["tests"]:
            test.pop("runner_overlap", None)
    return (rivals_from_report(report) or {}).get("rivals")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "kr60_confusable.toml"))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first", type=int, default=1)
    ap.add_argument("--extra-tests", type=int, default=10)
    ap.add_argument("--expected", default="link_compliance(link 2)",
                    help="the label(s) a correct diagnosis names: 'a+b' for two, 'nothing' for the clean world")  # fmt: skip
    ap.add_argument("--factor", type=float,
                    help="hidden effects at this multiple of their realistic size (0: the clean world, "
                         "scored with --expected nothing)")  # fmt: skip
    ap.add_argument("--world", default="", help="comma-separated effects to hide instead of the scenario's "
                    "(realistic sizes), e.g. link_compliance,nonlinear_joint")  # fmt: skip
    ap.add_argument("--always", action="store_true", help="discover --always: a round of tests on every seed")
    ap.add_argument("--rounds", type=int, default=1,
                    help="discover --rounds: later rounds while the diagnosis stays undecided (default 1)")  # fmt: skip
    ap.add_argument("--separation", type=float, nargs="?", const=SEPARATION_TARGET, default=None, metavar="T",
                    help="discover --separation: size each round until the predicted separation reaches T")  # fmt: skip
    ap.add_argument("--max-extra-tests", type=int, default=None, help="discover --max-extra-tests")
    ap.add_argument("--loaded-repeats", type=int, default=None, metavar="R",
                    help="[scanner] loaded_repeats for every seed (default: the scenario's)")  # fmt: skip
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="/tmp/bench_discriminate")
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--rerun", metavar="LOG",
                    help="an earlier run's printed output: re-run only its seeds whose round was of a --reasons "
                         "kind, keep its rows for the others, and score them all (a rule that changes only "
                         "those rounds, at the cost of those seeds)")  # fmt: skip
    ap.add_argument(
        "--reasons", default="marginal", help="with --rerun: comma-separated round kinds to re-run"
    )
    args = ap.parse_args()
    expected = set() if args.expected == "nothing" else set(args.expected.split("+"))  # "a+b": both hidden
    seeds = range(args.first, args.first + args.seeds)
    kept = {}
    if args.rerun:
        try:
            kept = earlier_rows(args.rerun, seeds)
        except ValueError as exc:
            ap.exit(2, f"error: --rerun {args.rerun}: {exc}\n")
        reasons = set(args.reasons.split(","))
        # a later round (--rounds > 1) can be of any kind: such seeds are re-run too
        kept = {seed: row for seed, row in kept.items()
                if row.get("reason") not in reasons and row.get("rounds_run", 1) <= 1}  # fmt: skip
    world = tuple(name.strip() for name in args.world.split(",") if name.strip())
    try:  # the options' scenario, checked once: a bad value is the run's error, not every seed's
        scenario_for(args.scenario, args.first, args.factor, world, args.loaded_repeats)
    except VtestbedError as exc:
        ap.exit(2, f"error: {exc}\n")
    task = (
        args.scenario,
        args.factor,
        args.extra_tests,
        args.always,
        args.out,
        args.keep,
        world,
        args.rounds,
        args.separation,
        args.max_extra_tests,
        args.loaded_repeats,
    )
    rows = []
    with ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {
            seed: pool.submit(run_seed, task[0], seed, *task[1:]) for seed in seeds if seed not in kept
        }
        for seed in seeds:  # in seed order
            rows.append(kept[seed] | {"kept": True} if seed in kept else futures[seed].result())
            print(json.dumps(rows[-1], default=float), flush=True)
    if kept:
        print(f"\n{len(kept)} rows kept from {args.rerun}, {len(futures)} seeds re-run")
    size = (
        f"{args.extra_tests} each"
        if args.separation is None
        else (f"{args.extra_tests} or more each, until T >= {args.separation:g}")
    )
    summarize(rows, expected, args.expected, size)


def earlier_rows(path: str, seeds) -> dict:
    """The rows of an earlier run's output at ``path`` (its JSON lines), by seed; every seed of
    ``seeds`` must be there (ValueError otherwise: a partial log would silently change the sample)."""
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise ValueError(f"cannot read it ({exc.strerror})") from None
    rows = {}
    for k, line in enumerate(lines, start=1):
        if line.startswith("{"):
            try:
                row = json.loads(line)
                rows[row["seed"]] = row
            except (ValueError, KeyError, TypeError):
                raise ValueError(
                    f"line {k} is not a row of this benchmark (a JSON object with a seed)"
                ) from None
    missing = [seed for seed in seeds if seed not in rows]
    if missing:
        raise ValueError(f"no row for seeds {missing[:5]}{' ...' if len(missing) > 5 else ''} "
                         f"(it has {len(rows)} rows): give the --seeds and --first of that run")  # fmt: skip
    return rows


def summarize(rows: list[dict], expected: set[str], label: str, size: str) -> None:
    """Print the scores of ``rows`` (one per seed, as ``run_seed`` returns them): named correctly
    before and after the round with the after-rate's 95 % interval, the right family, and the
    same per round type (confusable, marginal, confirm, screen)."""
    n = len(rows)
    family = {x.split("(")[0] for x in expected}

    def right(r, key, fam=False):
        if "error" in r:
            return False
        if fam:
            return {x.split("(")[0] for x in r[key]} == family
        return len(r[key]) == len(expected) and set(r[key]) == expected

    def score(key, fam=False, among=rows):
        return sum(right(r, key, fam) for r in among)

    errors = [r for r in rows if "error" in r]
    print(f"\n{n} seeds, {sum(bool(r['proposed']) for r in rows)} with discrimination tests "
          f"({size}), {len(errors)} failed (scored as not named); expected {label}")  # fmt: skip
    for r in errors:
        print(f"  seed {r['seed']}: {r['error']}")
    lo, hi = clopper_pearson(score("after"), n)
    print(f"named correctly: before {score('before')}/{n}, after {score('after')}/{n} "
          f"(95 % interval {lo * 100:.0f}-{hi * 100:.0f} %)")  # fmt: skip
    print(f"right family:    before {score('before', True)}/{n}, after {score('after', True)}/{n}")
    for reason in ("confusable", "marginal", "confirm", "screen"):
        among = [r for r in rows if r.get("reason") == reason]
        if among:
            print(
                f"  {reason} rounds: {score('before', among=among)} -> {score('after', among=among)} of {len(among)}"
            )
    gaps = [(r["val_before"]["baseline"], r["val_before"]["named"], (r["val_after"] or r["val_before"])["named"])
            for r in rows if r.get("val_before")]  # fmt: skip
    if gaps:
        base, before, after = np.median(np.array(gaps), axis=0)
        print(f"validation error / noise floor (median of {len(gaps)}): paper's model {base:.2f}, named before "
              f"{before:.2f} (excess removed {(base - before) / (base - 1) * 100:.0f} %), after the round "
              f"{after:.2f} ({(base - after) / (base - 1) * 100:.0f} %)")  # fmt: skip
    if any(r.get("rounds_run", 0) > 1 for r in rows):  # discover --rounds: what the later rounds changed
        later = [r for r in rows if r.get("rounds_run", 0) > 1]
        print(f"later rounds: {len(later)} seeds ran more than one round (at most {max(r['rounds_run'] for r in rows)}); "
              f"named correctly after round 1 {score('after_round1')}/{n}, after the last round {score('after')}/{n}")  # fmt: skip
    sized = [r for r in rows if r.get("extra_tests") is not None]
    if sized:  # rows of runs before 2026-11-26 have no count
        counts = np.array([r["extra_tests"] for r in sized])
        print(f"extra tests per seed: mean {counts.mean():.1f}, median {np.median(counts):.0f}, "
              f"max {counts.max()} ({len(sized)} seeds)")  # fmt: skip
    print(f"wall per seed: {sum(r['wall_s'] for r in rows) / n:.1f} s")


if __name__ == "__main__":
    main()
