"""Forecast of ``diagnose``'s first name near each effect's detection limit, from the linearised
model: what a scenario's tests let the first round name, without ray-casting a single trial.

Per effect, the size near the limit is ``bench_discrepancy.py``'s (:func:`_discrepancy_sizes.calibrate`:
its own naming test has ``--limit-power`` against an estimated floor), or ``--factor NAME=F``. At
that size the world is reduced noise-free (a perfect scanner and F/T sensor), the paper's model is
fitted against the reference floor, and its whitened residual is the effect's *signal*; every
candidate's whitened columns are taken at the fitted compliances, as the first round tests them.

Datasets are then drawn as the trials' statistics fall. In the coordinates the true floor whitens:
a floor estimate ``S* ~ Wishart(I, nu) / nu`` per draw (the repeat scans', ``nu`` = unloaded
repeats x tests: :func:`vtestbed.researcher.floor_calibration.floor_whiteners`) that whitens
signal plus noise ``N(0, I)``; each candidate's likelihood ratio beyond the stiffnesses against
its critical value at the first round's level (alpha over the candidates: the p-values'
reference, :func:`~vtestbed.researcher.floor_calibration.lr_critical_value`); and the significant
candidates ranked by held-out error (PRESS, exact for a linear fit: ``model_fit``'s formula), as
``diagnose`` ranks them. Printed per effect: its own test's pass rate, the share the first round
names it (a label of its name, as the benchmark scores it: link 3 for a hidden link 2), with the
Clopper-Pearson interval a trial count of ``--compare`` would have, its exact label's share, and
each other label's share and nothing's.

What it leaves out: the candidates' re-fit (bilinear terms and the exact statics are evaluated at
the noise-free fit), the later rounds and the backward step (they can add a second name or drop a
first), the block check's scale. The benchmark's trials measure all of that;
docs/discrepancy_benchmark.md ("A forecast of the first name") compares the two.

    .venv/bin/python benchmarks/naming_forecast.py [--scenario FILE] [--effects a,b] [--factor NAME=F]
        [--limit-power 0.85] [--repeats 3] [--loaded-repeats 3] [--floors 400] [--draws 50] [--seed 1]

Units: whitened displacements (chi^2 units); sizes as factors of each effect's realistic size.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _discrepancy_worlds  # noqa: E402  (sets the BLAS threads to 1 before numpy)
import numpy as np  # noqa: E402
from _discrepancy_sizes import LIMIT_POWER, calibrate, parse_effects, parse_factors  # noqa: E402
from _discrepancy_tables import clopper_pearson  # noqa: E402
from _discrepancy_worlds import ALPHA, model_context, noise_free, prepared_world, reference_floor, true_labels  # noqa: E402

from vtestbed.researcher.diagnose import Whitener, fit_model, identifiable  # noqa: E402
from vtestbed.researcher.floor_calibration import floor_whiteners, lr_critical_value  # noqa: E402
from vtestbed.researcher.model_fit import leave_one_test_out  # noqa: E402
from vtestbed.world.effects import EFFECTS  # noqa: E402

FORECAST_EFFECTS = ("link_compliance", "joint_coupling", "nonlinear_joint", "base_compliance",
                    "ft_misalignment", "ft_bias_drift", "block_offset")  # fmt: skip
# not forecast: the balancer (absorbed into k2 at its realistic size), the scale (the block check
# names it: bench_block_size.py), the geometric error (opt-in), the creep (no candidate)
RANK_TOL = 1e-10  # singular values below this fraction of the largest: no direction


def orthonormal(x: np.ndarray, rank: int | None = None) -> np.ndarray:
    """(N, r) orthonormal basis of the columns of ``x`` (N, k): ``rank`` directions, or as many as
    :func:`column_rank` counts."""
    u = np.linalg.svd(x / np.linalg.norm(x, axis=0), full_matrices=False)[0]
    return u[:, : column_rank(x) if rank is None else rank]


def column_rank(x: np.ndarray) -> int:
    """The rank of ``x``'s columns each scaled to unit norm (a term's columns are tiny in SI units
    beside the compliances': the fits' rank, ``model_fit.scaled_svd``)."""
    s = np.linalg.svd(x / np.linalg.norm(x, axis=0), compute_uv=False)
    return int(np.sum(s > RANK_TOL * s[0]))


def per_test(g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(6T, k): the 6x6 ``g`` applied to every test's 6 rows of ``x`` (6T, k)."""
    return np.einsum("ij,tjk->tik", g, x.reshape(-1, 6, x.shape[-1])).reshape(x.shape)


def effect_problem(name: str, factor: float, white: Whitener, statics: str) -> dict:
    """The noise-free first round of effect ``name`` at ``factor``: the signal (6T,) in the true
    floor's coordinates, the stiffness columns (6T, 6), each identifiable candidate's columns and
    its critical likelihood ratio at the first round's level."""
    prepared, pool = prepared_world(name, factor)
    ctx = model_context(noise_free(prepared), prepared, statics)
    base = fit_model(ctx, white, [])
    unscale = math.sqrt(white.inflation)  # the Whitener divides by sqrt(inflation): undo it
    a = base.design * unscale  # the paper's model: the whitened compliance columns
    signal = white(base.residuals.reshape(-1)) * unscale
    nu = _discrepancy_worlds.REPEATS * len(prepared.tests)  # the trials' floor: validation tests too
    level = ALPHA / len(pool)
    cands, rank_a = {}, column_rank(a)
    testable = identifiable(ctx, white, pool, base.compliance)
    for cand in testable:
        b = white(cand.columns(ctx, base.compliance)) * unscale
        design = np.hstack([a, b])
        df = column_rank(design) - rank_a
        if df <= 0:
            continue  # absorbed whole: never significant
        tested = np.r_[np.zeros(a.shape[1], bool), np.ones(b.shape[1], bool)]
        cands[cand.label] = {"columns": b, "df": int(df), "name": cand.name,
                             "crit": lr_critical_value(design, tested, df, nu, level)}  # fmt: skip
    hidden = name.split("+")  # "a+b": a pair hidden together (bench_two_effects.py)
    return {"signal": signal, "stiffness": a, "candidates": cands, "nu": nu, "level": level,
            "own": frozenset().union(*(true_labels(EFFECTS[n]()) for n in hidden)), "name": name,
            "hidden": {n: true_labels(EFFECTS[n]()) for n in hidden}, "n_pool": len(testable),
            "chi2": float(np.sum(signal**2))}  # fmt: skip


def forecast(problem: dict, floors: int, draws: int, rng: np.random.Generator) -> dict:
    """Counts over ``floors x draws`` datasets: own test significant, the first name (a label or
    None), from the problem of :func:`effect_problem`."""
    g_all = floor_whiteners(problem["nu"])[:floors]
    labels = list(problem["candidates"])
    crit = np.array([problem["candidates"][lab]["crit"] for lab in labels])
    own = np.array([lab in problem["own"] for lab in labels])
    named, own_pass = Counter(), 0
    for g in g_all:
        y = per_test(g, problem["signal"][:, None] + rng.standard_normal((problem["signal"].size, draws)))
        s = orthonormal(per_test(g, problem["stiffness"]))
        r = y - s @ (s.T @ y)
        lr = np.empty((len(labels), draws))
        err = np.empty((len(labels), draws))
        for i, label in enumerate(labels):
            c = problem["candidates"][label]
            b = per_test(g, c["columns"])
            q = orthonormal(b - s @ (s.T @ b), c["df"])
            proj = q.T @ r
            lr[i] = np.sum(proj**2, axis=0)
            err[i] = leave_one_test_out(np.hstack([s, q]), r - q @ proj)
        sig = lr > crit[:, None]
        own_pass += int(np.sum(sig[own].any(axis=0)))
        score = np.where(sig, err, np.inf)
        best = np.argmin(score, axis=0)
        for k in range(draws):
            named[labels[best[k]] if sig[best[k], k] else None] += 1
    return {"n": len(g_all) * draws, "own_pass": own_pass, "named": named}


def forecast_effect(name: str, factor: float | None, ref_floor, statics: str, power: float,
                    floors: int, draws: int, rng: np.random.Generator) -> dict:  # fmt: skip
    """The forecast of effect ``name`` at ``factor`` (None: its size at ``power``, as the benchmark
    searches it), as shares of ``floors x draws`` datasets: ``own_pass`` (its own test significant),
    ``right`` (named first by a label of its name, as the benchmark scores it: link 3 for a hidden
    link 2), ``exact`` (by its own label) and ``rest`` (every other first name, or "nothing")."""
    if factor is None:
        factor = calibrate(name, ref_floor, 6, statics, power)["factor"]
    problem = effect_problem(name, factor, Whitener(ref_floor), statics)
    out = forecast(problem, floors, draws, rng)
    n, cands = out["n"], problem["candidates"]
    right = sum(v for k, v in out["named"].items() if k is not None and cands[k]["name"] == name)
    exact = sum(v for k, v in out["named"].items() if k in problem["own"])
    rest = {lab or "nothing": v / n for lab, v in out["named"].most_common() if lab not in problem["own"]}
    return {"name": name, "factor": factor, "own_pass": out["own_pass"] / n, "right": right / n,
            "exact": exact / n, "rest": rest}  # fmt: skip


def parse_forecast_args(ap: argparse.ArgumentParser) -> argparse.Namespace:
    """Add the options every forecast takes (the scenario, the statics, the scans, the draws, the
    trial count whose interval is printed) to ``ap``, parse, and set the benchmark worlds' scenario
    and scans from them."""
    ap.add_argument("--scenario", type=Path, default=_discrepancy_worlds.SCENARIO)
    ap.add_argument("--statics", choices=("exact", "paper"), default="exact")
    ap.add_argument("--repeats", type=int, default=_discrepancy_worlds.REPEATS)
    ap.add_argument("--loaded-repeats", type=int, default=_discrepancy_worlds.LOADED_REPEATS)
    ap.add_argument("--ref-repeats", type=int, default=_discrepancy_worlds.REF_REPEATS)
    ap.add_argument("--floors", type=int, default=400, help="floor draws (at most 400)")
    ap.add_argument("--draws", type=int, default=50, help="noise draws per floor")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--compare", type=int, default=200, help="trials whose interval is printed beside")
    args = ap.parse_args()
    _discrepancy_worlds.set_repeats(args.repeats)
    _discrepancy_worlds.set_loaded_repeats(args.loaded_repeats)
    _discrepancy_worlds.set_scenario(args.scenario)
    return args


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--effects", default=",".join(FORECAST_EFFECTS))
    ap.add_argument("--factor", action="append", default=[], metavar="NAME=F",
                    help="a size instead of the search (e.g. block_offset=0.662)")  # fmt: skip
    ap.add_argument("--limit-power", type=float, default=LIMIT_POWER)
    args = parse_forecast_args(ap)
    names = parse_effects(args.effects, ap.error)
    given = parse_factors(args.factor, names, "--factor", ap.error)
    t0 = time.perf_counter()
    ref_floor = reference_floor(args.ref_repeats)
    print(f"# naming_forecast: {args.scenario.name}, {args.repeats}+{args.loaded_repeats} repeats, "
          f"power {args.limit_power:g}, {args.floors} floors x {args.draws} draws, reference floor "
          f"{time.perf_counter() - t0:.0f} s")  # fmt: skip
    print(
        "| effect | size | own test passes | named first | its interval at --compare trials | exact label | the rest |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | --- |")
    rng = np.random.default_rng(args.seed)
    for name in names:
        row = forecast_effect(name, given.get(name), ref_floor, args.statics, args.limit_power,
                              args.floors, args.draws, rng)  # fmt: skip
        low, high = clopper_pearson(round(row["right"] * args.compare), args.compare)
        rest = ", ".join(f"{lab} {v:.1%}" for lab, v in row["rest"].items() if v >= 0.005)
        print(f"| {name} | x{row['factor']:.3g} | {row['own_pass']:.1%} | **{row['right']:.1%}** | "
              f"{low:.0%}-{high:.0%} | {row['exact']:.1%} | {rest} |", flush=True)  # fmt: skip
    print(f"wall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
