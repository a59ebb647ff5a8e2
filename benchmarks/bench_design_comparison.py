"""Test designs against test count through the full pipeline: kappa, random, D, A, minimax, sequential.

Issue 16's comparison on the KR60 (``scenarios/kr60_paper.toml``'s lab, sensors and noise): for
n = 6, 12, 20 tests,

* kappa: the paper's selection, the first n tests of ``kr60_paper.toml`` (kappa regions Z1/Z4,
  A1 = 0, A6 = 45 deg, 200 N; drawn by the campaigns' ``kappa_regions`` rule and truth-checked),
* random: the first n of one seeded stream of random clear tests (the campaigns' ``random`` rule, 200 N),
* D, A, minimax: :func:`vtestbed.design.minimax.design` over one broad pool (``--pool`` random
  feasible poses, seed 0, every hook and ring, 4 tension levels up to the panel's top tension),
  prior = the paper's Table 5 (this lab's truth: these are the true-prior designs),
* refined: the minimax design with that pool grown around its poses ``--refine`` times
  (:func:`vtestbed.design.refine.refine_design`, seed ``[16, n]``; what ``vtestbed poses design --refine``
  does),
* sequential: the loop a lab runs, from a prior off by x2 / x0.5 on alternate joints (and, as
  ``sequential_inv``, by x0.5 / x2): a minimax
  pilot of 6 tests with that prior, then batches (to 9, 12, 16, 20, 24, 28, 32 tests) each chosen by
  :func:`vtestbed.design.sequential.next_tests` from the estimate and residual noise of all tests
  made so far, every test measured once through the full pipeline
  (:func:`~vtestbed.campaigns.montecarlo.measure_trial`, a seed of its own per batch) and identified
  with FGLS. One realisation per panel; it is then evaluated as a fixed test list.

Every set is then measured in ``--trials`` full-pipeline trials (MuJoCo equilibrium and ray cast
once, scanner and F/T noise per trial; the same seeds for every set: paired) and identified with
FGLS from each trial's first n tests. Printed per design and n: the worst joint's RMS relative error
with a bootstrap 95 % interval (trials resampled, the same resamples for every design), the ratio to
kappa at the same n (paired bootstrap interval) and the design's predicted worst std (linear model,
SIGMA_P / SIGMA_R, at the truth). Panels: tensions up to 200 N and up to the lab's limit
(``--panels 200,limit``); kappa and random are the 200 N sets in both. Designs and measured trials
are cached in ``--cache`` (shared machinery: ``bench_design_uncertainty.measure``).

Run: .venv/bin/python benchmarks/bench_design_comparison.py [--trials 100] [--panels 200,limit]
       [--figure docs/img/poses/design_comparison.png] [--table] [--joints] [--method fgls|gls_floor]
       [--refine 4]
(one worker, both panels from scratch on this shared machine: about 1 h of measuring at 100
trials and 30 min for the refined designs; a cached shorter run is extended, not re-measured;
seconds from the cache; docs/poses.md, "Comparison through the full pipeline").
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_design_uncertainty import (
    identify_trials,
    joint_check,
    measure,
    measured_path,
    random_scenario,
    scenario_a,
)

import vtestbed as vt
from vtestbed.campaigns.montecarlo import measure_trial, prepare
from vtestbed.campaigns.posesets import TestPlan
from vtestbed.design import minimax, pool
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.design.refine import refine_design
from vtestbed.design.sequential import next_tests, noise_from_residuals
from vtestbed.researcher.identify import identify
from vtestbed.researcher.measure import stacked

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
COUNTS = (6, 12, 20)
FIXED = ("kappa", "random", "D", "A", "minimax", "refined")
SEQ_STEPS = (6, 9, 12, 16, 20, 24, 28, 32)
PRIOR_OFF = 2.0 ** np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])  # x2 / x0.5 on alternate joints
PRIORS = {"sequential": PRIOR_OFF, "sequential_inv": 1 / PRIOR_OFF}  # the loop's start, per run
LABELS = {
    "refined": "minimax, pool grown around it",
    "sequential": "sequential (prior x2, x0.5, ...)",
    "sequential_inv": "sequential (prior x0.5, x2, ...)",
}
LOOP_SEED = 900_000  # the sequential loop's own measurements (the evaluation uses 16_000 + i)
BOOT = 2000


def plan_of(name: str, tests) -> TestPlan:
    """A test list (CandidateTests) as a campaign TestPlan (DH rad)."""
    tests = list(tests)
    return TestPlan(name, np.array([t.q for t in tests]), tuple(t.hook for t in tests),
                    tuple(t.anchor for t in tests), tuple(float(t.tension) for t in tests))  # fmt: skip


def broad_pool(base, n_poses: int, tension: float):
    """The design pool: ``n_poses`` random feasible poses (seed 0) x hooks x rings x 4 tension levels."""
    t0 = time.perf_counter()
    poses = pool.random_poses(base.robot, base.lab, n_poses, np.random.default_rng(0))
    cands = pool.candidate_pool(base.robot, base.lab, poses=poses, max_tension=tension)
    print(f"  pool up to {tension:g} N: {len(cands)} candidates from {n_poses} poses "
          f"({cands.refused}) in {time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip
    return cands


def fixed_designs(cands, k: np.ndarray) -> dict:
    """(criterion, n) -> {"plan", "bound"}: the true-prior D, A and minimax designs."""
    out = {}
    for n in COUNTS:
        for crit in ("D", "A", "minimax"):
            t0 = time.perf_counter()
            res = minimax.design(cands.a, n, k, crit, bound=crit == "minimax")
            bound = float(np.sqrt(res.relaxation.bound)) if res.relaxation is not None else None
            out[(crit, n)] = {"plan": plan_of(crit, [cands.tests[i] for i in res.selection.indices]),
                              "bound": bound}  # fmt: skip
            print(f"  {crit} {n}: {time.perf_counter() - t0:.1f} s", flush=True)
    return out


def measure_once(base, tests, seed: int) -> list:
    """One full-pipeline measurement of ``tests`` (prepared and measured with ``seed``)."""
    prepared = prepare(plan_of("batch", tests).scenario(base))
    return measure_trial(prepared, seed)


def sequential(cands, base, k_true: np.ndarray, prior: np.ndarray) -> tuple[TestPlan, list]:
    """The lab's loop: pilot of SEQ_STEPS[0] minimax tests with ``prior``, then each batch from the
    current FGLS estimate and residual noise of every test made. Returns the plan and a log."""
    chosen = list(minimax.design(cands.a, SEQ_STEPS[0], prior, bound=False).selection.indices)
    meas = measure_once(base, [cands.tests[i] for i in chosen], LOOP_SEED)
    log = []
    for step, n in enumerate(SEQ_STEPS[1:], start=1):
        j, w, d = stacked(meas)
        res = identify(j, w, d, method="fgls")
        sp, sr = noise_from_residuals(res.component_std)
        nxt = next_tests(j, w, res.stiffness, n - len(chosen), cands, sp, sr)
        log.append({"tests_made": len(chosen), "estimate_error_percent": ((res.stiffness / k_true - 1) * 100).tolist(),
                    "sigma_p_um": sp * 1e6, "sigma_r_urad": sr * 1e6,
                    "predicted_after_percent": nxt.result.selection.report.minimax_value * 100})  # fmt: skip
        new = [int(i) for i in nxt.result.selection.indices]
        chosen += new
        meas += measure_once(base, [cands.tests[i] for i in new], LOOP_SEED + step)
    return plan_of("sequential", [cands.tests[i] for i in chosen]), log


def refined_designs(base, cands, k: np.ndarray, rounds: int) -> dict:
    """name -> (TestPlan, counts, extra): the minimax design of each n with its pool grown ``rounds`` times."""
    out = {}
    for n in COUNTS:
        t0 = time.perf_counter()
        grown = refine_design(base.robot, cands, n, k, np.random.default_rng([16, n]), base.lab, rounds)
        plan = plan_of("refined", [grown.pool.tests[i] for i in grown.result.selection.indices])
        bound = float(np.sqrt(grown.result.relaxation.bound))
        out[f"refined_{n}"] = (plan, (n,), {"bound": bound, "refine_rounds": rounds, **grown.to_dict()})
        print(f"  refined {n}: {time.perf_counter() - t0:.0f} s, worst std "
              + " -> ".join(f"{h['worst_relative_std_percent']:.3f}" for h in grown.history) + " %", flush=True)  # fmt: skip
    return out


def panel_designs(base, tension: float, tag: str, n_poses: int, cache: Path, rounds: int = 0) -> dict:
    """name -> (TestPlan, counts, extra) for D, A, minimax, refined (per n) and each sequential run, cached as JSON."""
    path = cache / f"designs_{tag}.json"
    raw = json.loads(path.read_text()) if path.exists() else {}
    out = {name: (TestPlan.from_dict(v["plan"]), tuple(v["counts"]), v["extra"]) for name, v in raw.items()}
    if not rounds:
        out = {name: v for name, v in out.items() if not name.startswith("refined_")}
    stale = rounds and out.get("refined_20", (None, None, {}))[2].get("refine_rounds") != rounds
    missing = [name for name in ("minimax_20", *PRIORS) if name not in out] + (
        ["refined_20"] if stale else []
    )
    if not missing:
        return out
    k = PAPER_TABLE5.stiffness
    cands = broad_pool(base, n_poses, tension)
    if "minimax_20" in missing:
        out |= {
            f"{c}_{n}": (d["plan"], (n,), {"bound": d["bound"]})
            for (c, n), d in fixed_designs(cands, k).items()
        }
    if "refined_20" in missing:
        out |= refined_designs(base, cands, k, rounds)
    for name in (m for m in missing if m in PRIORS):
        t0 = time.perf_counter()
        plan, log = sequential(cands, base, k, k * PRIORS[name])
        print(f"  {name} loop: {time.perf_counter() - t0:.0f} s", flush=True)
        out[name] = (plan, SEQ_STEPS, {"log": log, "prior_factors": PRIORS[name].tolist()})
    path.write_text(json.dumps({name: {"plan": p.to_dict(), "counts": list(c), "extra": e}
                                for name, (p, c, e) in out.items()}, indent=1))  # fmt: skip
    return out


def worst_rms(err: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
    """Worst joint's RMS relative error, of ``err`` (trials, joints) or of each resample ``idx`` (B, trials)."""
    if idx is None:
        return np.sqrt(np.mean(err**2, axis=0)).max()
    return np.sqrt(np.mean(err[idx] ** 2, axis=1)).max(axis=1)


def run_panel(base, tag: str, tension: float, args, cache: Path, shared: dict) -> dict:
    """Measure every set of one panel; returns (design, n) -> {"err", "pred", "bound"}."""
    print(f"\npanel {tag}: tensions up to {tension:g} N", flush=True)
    cells = dict(shared)
    for name, (plan, counts, extra) in panel_designs(
        base, tension, tag, args.pool, cache, args.refine
    ).items():
        scenario = plan.scenario(base)
        data = measure(f"{name}_{tag}", scenario, args.trials, cache)
        a = scenario_a(scenario)
        design_name = name if name in PRIORS else name.rsplit("_", 1)[0]
        for n in counts:
            err = identify_trials(data, n, args.method)[0] / data["k_true"] - 1
            pred = design.evaluate(a[:n], data["k_true"]).minimax_value
            cells[(design_name, n)] = {"err": err, "pred": pred, "bound": extra.get("bound"),
                                       "plan": plan, "extra": extra}  # fmt: skip
        if args.joints and design_name in ("minimax", "refined"):
            full = cells[(design_name, len(a))]["err"]  # identified once, above
            print(joint_check(f"{name}_{tag}", scenario, data, a, full), flush=True)
    return cells


def shared_sets(base, trials: int, cache: Path, method: str = "fgls") -> dict:
    """kappa (the paper's tests) and random clear tests at 200 N: the same in every panel."""
    cells = {}
    for name, fn in (("kappa", lambda: base), ("random", lambda: random_scenario(base, 20, 7))):
        a_path = cache / f"{name}_a.npy"  # the random set's truth checks take a minute: keep its A
        scenario = None if a_path.exists() and measured_path(name, trials, cache).exists() else fn()
        data = measure(name, scenario, trials, cache)
        if scenario is not None:
            np.save(a_path, scenario_a(scenario))
        a = np.load(a_path)
        for n in COUNTS:
            err = identify_trials(data, n, method)[0] / data["k_true"] - 1
            pred = design.evaluate(a[:n], data["k_true"]).minimax_value
            cells[(name, n)] = {"err": err, "pred": pred, "bound": None}
    return cells


def summarise(cells: dict, tag: str, trials: int) -> list[dict]:
    """Print and return the rows: worst RMS [%] with its interval, ratio to kappa with its interval."""
    rng = np.random.default_rng(0)
    idx = rng.integers(0, trials, size=(BOOT, trials))
    print(
        f"\n{tag}: worst joint's RMS relative error [%] over {trials} trials, bootstrap 95 % intervals (paired)"
    )
    print(f"{'design':>11s} {'n':>3s} {'worst RMS':>9s} {'95 % interval':>15s} {'/ kappa':>8s} {'95 % interval':>15s}"
          f" {'joint':>5s} {'pred.':>7s} {'bound':>7s}")  # fmt: skip
    rows = []
    order = (*FIXED, *PRIORS)
    for (name, n), c in sorted(cells.items(), key=lambda kv: (kv[0][1], order.index(kv[0][0]))):
        boot = worst_rms(c["err"], idx)
        worst = worst_rms(c["err"])
        joint = int(np.argmax(np.sqrt(np.mean(c["err"] ** 2, axis=0)))) + 1
        lo, hi = np.percentile(boot, [2.5, 97.5])
        row = {"panel": tag, "design": name, "n": n, "worst_rms_percent": worst * 100, "ci": [lo * 100, hi * 100],
               "worst_joint": joint, "predicted_percent": c["pred"] * 100,
               "bound_percent": None if c["bound"] is None else c["bound"] * 100}  # fmt: skip
        kappa = cells.get(("kappa", n))
        text = f"{'':>8s} {'':>15s}"
        if kappa is not None:
            ratio = boot / worst_rms(kappa["err"], idx)
            rl, rh = np.percentile(ratio, [2.5, 97.5])
            row |= {"ratio_to_kappa": worst / worst_rms(kappa["err"]), "ratio_ci": [rl, rh]}
            text = f"{row['ratio_to_kappa']:8.3f} {f'[{rl:.3f}, {rh:.3f}]':>15s}"
        bound = f"{row['bound_percent']:7.3f}" if row["bound_percent"] is not None else f"{'':>7s}"
        print(f"{name:>11s} {n:3d} {worst * 100:9.3f} {f'[{lo * 100:.3f}, {hi * 100:.3f}]':>15s} {text}"
              f" {joint:5d} {c['pred'] * 100:7.3f} {bound}")  # fmt: skip
        rows.append(row)
    for n in COUNTS:  # what growing the pool buys, paired
        if ("refined", n) in cells and ("minimax", n) in cells:
            ratio = worst_rms(cells[("refined", n)]["err"]) / worst_rms(cells[("minimax", n)]["err"])
            lo, hi = np.percentile(worst_rms(cells[("refined", n)]["err"], idx)
                                   / worst_rms(cells[("minimax", n)]["err"], idx), [2.5, 97.5])  # fmt: skip
            print(f"refined / minimax at {n} tests: {ratio:.3f} [{lo:.3f}, {hi:.3f}]")
    for run in PRIORS:
        sequential_summary(cells, run, idx)
    return rows


def sequential_summary(cells: dict, run: str, idx: np.ndarray) -> None:
    """A sequential run against the true-prior minimax design at 20 tests, and its loop's log."""
    seq = {n: c for (name, n), c in cells.items() if name == run}
    if not seq or ("minimax", 20) not in cells:
        return
    best20 = min(worst_rms(cells[(d, 20)]["err"]) for d in ("D", "A", "minimax"))
    mm20 = cells[("minimax", 20)]
    ratio = worst_rms(seq[20]["err"], idx) / worst_rms(mm20["err"], idx)
    r = worst_rms(seq[20]["err"]) / worst_rms(mm20["err"])
    match = next((n for n in sorted(seq) if worst_rms(seq[n]["err"]) <= best20), None)
    extra = seq[20]["extra"]
    print(f"{run} (prior factors {extra['prior_factors']}) / true-prior minimax at 20 tests: {r:.3f} "
          f"[{np.percentile(ratio, 2.5):.3f}, {np.percentile(ratio, 97.5):.3f}] (target <= 1.2); tests to match "
          f"the best fixed 20-test design ({best20 * 100:.3f} %): {match if match is not None else f'> {max(seq)}'}")  # fmt: skip
    for entry in extra["log"]:
        print(f"  after {entry['tests_made']:2d} tests: estimate error [%] "
              f"{np.round(entry['estimate_error_percent'], 2).tolist()}, sigma {entry['sigma_p_um']:.2f} um "
              f"{entry['sigma_r_urad']:.2f} urad")  # fmt: skip


def figure(rows: list[dict], path: Path) -> None:
    """Worst joint's RMS error against test count, one line per design, one panel per tension."""
    from vtestbed.plotting import pyplot, save_figure

    plt = pyplot()
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), sharey=True, squeeze=False)
    style = {"kappa": ("k", "o"), "random": ("0.55", "s"), "D": ("tab:orange", "^"), "A": ("tab:green", "v"),
             "minimax": ("tab:blue", "D"), "refined": ("tab:cyan", "P"), "sequential": ("tab:red", "x"),
             "sequential_inv": ("tab:purple", "+")}  # fmt: skip
    for ax, tag in zip(axes[0], panels):
        for name, (color, marker) in style.items():
            sel = sorted((r for r in rows if r["panel"] == tag and r["design"] == name), key=lambda r: r["n"])
            if not sel:
                continue
            n = np.array([r["n"] for r in sel])
            y = np.array([r["worst_rms_percent"] for r in sel])
            ci = np.array([r["ci"] for r in sel]).T
            label = LABELS.get(name, name)
            ax.errorbar(n, y, yerr=[y - ci[0], ci[1] - y], color=color, marker=marker, ms=5, capsize=3,
                        label=label)  # fmt: skip
        ax.set_yscale("log")
        ax.set_xlabel("tests")
        top = float(tag.removesuffix("N"))
        ax.set_title(f"tensions up to {top:g} N" + (" (the lab's limit)" if top > 200 else ""))
        ax.set_xticks([6, 9, 12, 16, 20, 24, 28, 32])
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("worst joint's RMS error [%]")
    axes[0][-1].legend(fontsize=8, title="kappa, random: 200 N in both", title_fontsize=8)
    save_figure(fig, path)


def controller_table(plan: TestPlan, robot) -> str:
    """Markdown table of a test plan: pose in KUKA controller degrees, hook, ring, tension."""
    lines = [
        "| # | A1..A6 (controller) [deg] | hook | ring | tension [N] |",
        "| --- | --- | --- | --- | --- |",
    ]
    for i, (q, h, r, t) in enumerate(zip(plan.q, plan.hooks, plan.anchors, plan.tensions), start=1):
        a = ", ".join(f"{v:.2f}" for v in np.degrees(robot.dh_to_controller(q)))
        lines.append(f"| {i} | {a} | {h} | {r} | {t:g} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--trials", type=int, default=100, help="full-pipeline trials per set (default %(default)s)"
    )
    parser.add_argument(
        "--pool", type=int, default=400, help="random poses of the design pool (default %(default)s)"
    )
    parser.add_argument(
        "--panels", default="200,limit", help="top tensions: N or 'limit' (default %(default)s)"
    )
    parser.add_argument("--cache", default=str(ROOT / "runs" / "bench_design_comparison"),
                        help="directory for the designs and the measured trials (default %(default)s)")  # fmt: skip
    parser.add_argument("--refine", type=int, default=4,
                        help="rounds of growing the pool around the minimax design (0: no refined designs; "
                             "default %(default)s)")  # fmt: skip
    parser.add_argument("--figure", help="write the comparison figure here (PNG)")
    parser.add_argument(
        "--table", action="store_true", help="print the 20-test minimax and refined designs of each panel"
    )
    parser.add_argument("--joints", action="store_true",
                        help="print each minimax and refined set's per-joint Monte Carlo std beside the design's "
                             "prediction and the Cramer-Rao bound")  # fmt: skip
    parser.add_argument("--method", default="fgls", choices=("fgls", "gls_floor"),
                        help="estimator of every set's trials (the sequential loop itself always uses "
                             "fgls); gls_floor weights with the repeat scans' noise floor (default %(default)s)")  # fmt: skip
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    base = vt.load_scenario(PAPER)
    t0 = time.perf_counter()
    shared = shared_sets(base, args.trials, cache, args.method)
    rows = []
    for item in args.panels.split(","):
        tension = base.lab.max_tension[0] if item == "limit" else float(item)
        tag = f"{tension:g}N"
        cells = run_panel(base, tag, tension, args, cache, shared)
        rows += summarise(cells, tag, args.trials)
        for kind in ("minimax", "refined") if args.table else ():
            if (kind, 20) in cells:
                print(f"\n20-test {LABELS.get(kind, kind)} design, tensions up to {tension:g} N:\n"
                      + controller_table(cells[(kind, 20)]["plan"], base.robot))  # fmt: skip
    (cache / f"summary_trials{args.trials}_{args.method}.json").write_text(json.dumps(rows, indent=1))
    if args.figure:
        figure(rows, Path(args.figure))
        print(f"figure: {args.figure}")
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
