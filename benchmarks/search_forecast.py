"""Forecast of what ``diagnose``'s whole stepwise search ends naming, from the linearised model:
every forward round and the backward step, where ``naming_forecast.py`` stops at the first name.
Its use is the pairs of ``bench_two_effects.py`` (two effects hidden at once, each at its realistic
size: are both named?), without ray-casting a single trial.

The problem is ``naming_forecast.effect_problem``'s (the noise-free signal of the hidden world,
every candidate's whitened columns at the noise-free fit's compliances) and datasets are drawn as
there (a floor estimate per draw, noise ``N(0, I)`` in the true floor's coordinates). The search is
``diagnose.name_effects``'s, in those coordinates:

- a round tests every candidate not yet named by its likelihood ratio beyond the stiffnesses and
  the terms named, against its critical value at the round's level (``diagnose.step_level``:
  ``alpha`` over the candidates in play for the first name, ``alpha / (max_terms - 1)`` over them
  for each later round), and adds the significant one with the least held-out error (PRESS);
- after each addition the backward step re-tests every named term beyond the others at the level
  of a forward round from them, and drops the least significant one above it, until none is;
- the search ends when nothing is significant, ``max_terms`` are named, ``max_terms - 1`` rounds
  followed a first name, or a set of terms comes back.

What it leaves out, as the first-name forecast does: the candidates' re-fit (the bilinear terms
and the exact statics are evaluated at the noise-free fit), and the block check's scale. Ordering
the backward step's terms, it takes the floor as known (the chi^2 tail of each likelihood ratio).

    .venv/bin/python benchmarks/search_forecast.py [--scenario FILE] [--pairs a+b,c+d]
        [--repeats 3] [--loaded-repeats 3] [--floors 400] [--draws 50] [--seed 1]

Units: whitened displacements (chi^2 units); each effect at its realistic size.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _discrepancy_worlds  # noqa: E402, F401  (sets the BLAS threads to 1 before numpy)
import numpy as np  # noqa: E402
from _discrepancy_tables import clopper_pearson  # noqa: E402
from _discrepancy_worlds import ALPHA, reference_floor  # noqa: E402
from bench_two_effects import PAIRS  # noqa: E402
from naming_forecast import column_rank, effect_problem, orthonormal, parse_forecast_args, per_test  # noqa: E402
from scipy.stats import chi2 as chi2_dist  # noqa: E402

from vtestbed.researcher.diagnose import MAX_TERMS, Whitener, step_level  # noqa: E402
from vtestbed.researcher.floor_calibration import floor_whiteners, lr_critical_value  # noqa: E402
from vtestbed.researcher.model_fit import leave_one_test_out  # noqa: E402
from vtestbed.world.effects import EFFECTS  # noqa: E402

# the pair the block offset's share of the two-effect target turns on (docs/discrepancy_benchmark.md)
BLOCK_PAIR = "block_offset+ft_misalignment"


class _Critical:
    """The tests of one problem's candidates beside the stiffnesses and the named terms: each
    candidate's degrees of freedom, once per (terms named, candidate), and its critical likelihood
    ratio, once per (terms named, candidate, level)."""

    def __init__(self, problem: dict) -> None:
        self.problem, self.dfs, self.crits = problem, {}, {}
        # the first round's are the problem's own (the same design, mask and level): not recomputed
        for label, cand in problem["candidates"].items():
            self.dfs[(frozenset(), label)] = cand["df"]
            self.crits[(frozenset(), label, problem["level"])] = cand["crit"]

    def columns(self, labels) -> np.ndarray:
        cands = self.problem["candidates"]
        return np.hstack([self.problem["stiffness"], *(cands[lab]["columns"] for lab in labels)])

    def df(self, named: tuple, label: str) -> int:
        """Directions ``label`` adds beside the stiffnesses and ``named`` (0: absorbed by them)."""
        key = (frozenset(named), label)
        if key not in self.dfs:
            without = column_rank(self.columns(sorted(named)))
            self.dfs[key] = column_rank(self.columns([*sorted(named), label])) - without
        return self.dfs[key]

    def get(self, named: tuple, label: str, level: float) -> tuple[int, float]:
        """(degrees of freedom, critical likelihood ratio at ``level``; inf where absorbed)."""
        df, key = self.df(named, label), (frozenset(named), label, level)
        if key not in self.crits:
            self.crits[key] = np.inf
            if df > 0:
                design = self.columns([*sorted(named), label])
                tested = (
                    np.arange(design.shape[1])
                    >= design.shape[1] - self.problem["candidates"][label]["columns"].shape[1]
                )
                self.crits[key] = float(lr_critical_value(design, tested, df, self.problem["nu"], level))
        return df, self.crits[key]


class _Draws:
    """One floor draw's datasets in its coordinates: ``y`` (6T, D), every candidate's columns, and
    the orthonormal bases of the stiffnesses beside each set of named terms (kept once made)."""

    def __init__(self, problem: dict, g: np.ndarray, noise: np.ndarray) -> None:
        self.y = per_test(g, problem["signal"][:, None] + noise)
        self.cols = {lab: per_test(g, c["columns"]) for lab, c in problem["candidates"].items()}
        self.stiffness = per_test(g, problem["stiffness"])
        self.bases: dict = {}

    def basis(self, named) -> np.ndarray:
        key = frozenset(named)
        if key not in self.bases:
            self.bases[key] = orthonormal(
                np.hstack([self.stiffness, *(self.cols[lab] for lab in sorted(key))])
            )
        return self.bases[key]

    def chi2(self, named, idx) -> np.ndarray:
        """(len(idx),) the chi^2 of the draws ``idx`` fitted with the stiffnesses and ``named``."""
        v = self.basis(named)
        r = self.y[:, idx] - v @ (v.T @ self.y[:, idx])
        return np.sum(r**2, axis=0)


def forecast_search(problem: dict, floors: int, draws: int, rng: np.random.Generator,
                    alpha: float = ALPHA, max_terms: int = MAX_TERMS) -> Counter:  # fmt: skip
    """Counts of the sets of labels the search ends naming over ``floors x draws`` datasets
    (frozensets; empty: nothing named), from ``naming_forecast.effect_problem``'s problem."""
    crit = _Critical(problem)
    labels = list(problem["candidates"])
    n_pool = problem["n_pool"]
    ends: Counter = Counter()
    for g in floor_whiteners(problem["nu"])[:floors]:
        data = _Draws(problem, g, rng.standard_normal((problem["signal"].size, draws)))
        # per draw: the terms named (in order), the sets reached, the rounds after a first name
        states = [((), {frozenset()}, 0) for _ in range(draws)]
        active = list(range(draws))
        while active:
            groups = defaultdict(list)
            for k in active:
                groups[states[k][0]].append(k)
            active = []
            for named, idx in groups.items():
                remaining = [lab for lab in labels if lab not in named and crit.df(named, lab) > 0]
                if not remaining:  # every candidate named or absorbed: nothing left to test
                    ends[frozenset(named)] += len(idx)
                    continue
                level = step_level(alpha, n_pool - len(named), len(named), max_terms)
                best = _forward_round(named, remaining, level, idx, data, crit)
                for j, k in enumerate(idx):
                    _, seen, later = states[k]
                    if best[j] is None:
                        ends[frozenset(named)] += 1
                        continue
                    chosen = _backward((*named, best[j]), k, data, crit, alpha, n_pool, max_terms)
                    later += bool(named)
                    key = frozenset(chosen)
                    if key in seen or len(chosen) >= max_terms or later >= max(max_terms - 1, 1):
                        ends[key] += 1
                        continue
                    states[k] = (chosen, seen | {key}, later)
                    active.append(k)
    return ends


def _forward_round(named, remaining, level, idx, data: _Draws, crit: _Critical) -> list:
    """The label each draw of ``idx`` adds in a round from ``named`` (None: nothing significant)."""
    v = data.basis(named)
    r = data.y[:, idx] - v @ (v.T @ data.y[:, idx])
    score = np.full((len(remaining), len(idx)), np.inf)
    for i, lab in enumerate(remaining):
        df, c = crit.get(named, lab, level)
        q = orthonormal(data.cols[lab] - v @ (v.T @ data.cols[lab]), df)
        proj = q.T @ r
        lr = np.sum(proj**2, axis=0)
        err = leave_one_test_out(np.hstack([v, q]), r - q @ proj)
        score[i] = np.where(lr > c, err, np.inf)
    best = np.argmin(score, axis=0)
    return [remaining[b] if np.isfinite(score[b, j]) else None for j, b in enumerate(best)]


def _backward(chosen: tuple, k: int, data: _Draws, crit: _Critical, alpha, n_pool, max_terms) -> tuple:
    """``chosen`` after ``diagnose._drop_redundant`` for draw ``k``: the least significant term
    beyond the others (ordered by the chi^2 tail, the floor taken as known) dropped while its
    likelihood ratio is below its critical value."""
    while len(chosen) > 1:
        level = step_level(alpha, n_pool - len(chosen) + 1, len(chosen) - 1, max_terms)
        full = data.chi2(chosen, [k])[0]
        worst = None
        for term in chosen:
            others = tuple(t for t in chosen if t != term)
            df, c = crit.get(others, term, level)
            lr = data.chi2(others, [k])[0] - full
            if lr < c:
                p = chi2_dist.sf(lr, df)
                if worst is None or p > worst[0]:
                    worst = (p, term)
        if worst is None:
            break
        chosen = tuple(t for t in chosen if t != worst[1])
    return chosen


def forecast_pair(pair: str, ref_floor, statics: str, floors: int, draws: int, rng) -> dict:
    """The forecast of ``pair`` ("a+b", each at its realistic size): :func:`pair_shares` of the
    sets :func:`forecast_search` ends naming."""
    problem = effect_problem(pair, 1.0, Whitener(ref_floor), statics)
    return {"pair": pair, **pair_shares(forecast_search(problem, floors, draws, rng), problem["hidden"])}


def pair_shares(ends: Counter, hidden: dict[str, frozenset]) -> dict:
    """Shares of the named sets ``ends`` (counts by frozenset of labels): ``both`` effects of
    ``hidden`` (name -> its labels) named (one label of each, as ``bench_two_effects.tally`` counts),
    ``alone`` per effect (only it of the two), ``third`` (a label of neither among those named, with
    ``extra``: the share per such label) and ``nothing``."""
    n = sum(ends.values())
    own = frozenset().union(*hidden.values())
    out = {"both": 0.0, "alone": dict.fromkeys(hidden, 0.0), "third": 0.0, "nothing": 0.0, "extra": Counter()}
    for named, count in ends.items():
        hits = [name for name, labels in hidden.items() if named & labels]
        out["both"] += count / n * (len(hits) == 2)
        if len(hits) == 1:
            out["alone"][hits[0]] += count / n
        out["third"] += count / n * bool(named - own)
        out["nothing"] += count / n * (not named)
        out["extra"].update({lab: count / n for lab in named - own})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", default=",".join((*PAIRS, BLOCK_PAIR)))
    args = parse_forecast_args(ap)
    pairs = parse_pairs(args.pairs, ap.error)
    t0 = time.perf_counter()
    ref_floor = reference_floor(args.ref_repeats)
    print(f"# search_forecast: {args.scenario.name}, {args.repeats}+{args.loaded_repeats} repeats, "
          f"{args.floors} floors x {args.draws} draws")  # fmt: skip
    print(
        "| hidden pair | both named | its interval at --compare trials | one alone (which) | a third name (which) | nothing |"
    )
    print("| --- | ---: | ---: | --- | --- | ---: |")
    rng = np.random.default_rng(args.seed)
    for pair in pairs:
        row = forecast_pair(pair, ref_floor, args.statics, args.floors, args.draws, rng)
        low, high = clopper_pearson(round(row["both"] * args.compare), args.compare)
        alone = ", ".join(f"{k} {v:.1%}" for k, v in row["alone"].items() if v >= 0.005)
        extra = ", ".join(f"{k} {v:.1%}" for k, v in row["extra"].most_common(3) if v >= 0.005)
        print(f"| {pair.replace('+', ' + ')} | **{row['both']:.1%}** | {low:.0%}-{high:.0%} | {alone} "
              f"| {row['third']:.1%} ({extra}) | {row['nothing']:.1%} |", flush=True)  # fmt: skip
    print(f"wall {time.perf_counter() - t0:.0f} s")


def parse_pairs(text: str, error) -> list[str]:
    """``--pairs a+b,c+d`` as a list; ``error`` (argparse's, exit code 2) on anything but two
    effect names of :data:`vtestbed.world.effects.EFFECTS` joined by ``+``."""
    pairs = [p.strip() for p in text.split(",") if p.strip()]
    for pair in pairs:
        names = pair.split("+")
        if len(names) != 2 or any(n not in EFFECTS for n in names):
            error(f"--pairs: {pair!r} is not a pair of effects a+b; valid effects: {', '.join(EFFECTS)}")
    return pairs


if __name__ == "__main__":
    main()
