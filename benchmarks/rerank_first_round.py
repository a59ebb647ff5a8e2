"""Re-rank the first naming round of a recorded confusion-matrix run under other rules, offline.

``bench_discrepancy.py --out FILE`` records, per trial, every candidate's first-round row
(likelihood ratio, degrees of freedom, p-value, held-out error ``press``, significance). This
script picks the first name again from those rows under each rule and counts, per world, how
often it is the hidden effect (nothing, for the clean world and for the balancer at its realistic
size, which the scans cannot name). No simulation: it reads the JSON only.

Rules (among the significant candidates; chi^2 = the baseline's chi^2 minus the likelihood ratio):

- ``press``: the lowest leave-one-test-out prediction error (the rule of ``diagnose``);
- ``bic``: the BIC the record holds (chi^2 + df ln(n)); ``aic``: chi^2 + 2 df; ``p``: the smallest
  p-value;
- ``press+M``: the fewest parameters among the candidates within M of the lowest held-out error
  (a one-standard-error rule), ties by held-out error.

The last column, ``ceiling``, is what no rule can beat: the trials whose hidden effect is among
the significant candidates at all (for a world that should name nothing, the trials where no
candidate is significant). A world whose ceiling is below a target misses it on the first round
whatever the ranking; the gap between a rule and the ceiling is what the ranking loses.

A second table takes the researcher's view of the same first rounds, under ``diagnose``'s own
rule: is the first name right, and does the report say it is *undecided* (what ``vtestbed
discover`` acts on: :func:`vtestbed.design.rivals.rivals_from_report`, a runner-up within the
confusable margin, a weak name, or nothing named with a candidate near the level)? A wrong name
the report calls decided is the one outcome that misleads; the others are right, flagged, or an
honest "nothing".

    .venv/bin/python benchmarks/bench_discrepancy.py --limit-only --limit-power 0.85 --out near.json
    .venv/bin/python benchmarks/rerank_first_round.py near.json
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, not installed

from vtestbed.design.rivals import rivals_from_report  # noqa: E402
from vtestbed.researcher.diagnose import DEFAULT_ALPHA  # noqa: E402

RULES = ("press", "bic", "aic", "p", "press+2", "press+4", "press+6", "press+10")


def pick(rows: list[dict], base_chi2: float, rule: str) -> str | None:
    """The effect name ``rule`` chooses first among the significant ``rows`` (None: nothing)."""
    significant = [r for r in rows if r["significant"]]
    if not significant:
        return None
    if rule.startswith("press+"):
        best = min(r["press"] for r in significant)
        near = [r for r in significant if r["press"] <= best + float(rule[len("press+") :])]
        return min(near, key=lambda r: (r["df"], r["press"]))["name"]
    keys = {
        "press": lambda r: r["press"],
        "bic": lambda r: r["bic"],  # as diagnose computed it
        "aic": lambda r: base_chi2 - r["lr"] + 2 * r["df"],
        "p": lambda r: (r["p_value"], -r["lr"]),
    }
    return min(significant, key=keys[rule])["name"]


def within_reach(rows: list[dict], want: str | None) -> bool:
    """Could some rule pick ``want`` from ``rows``: is it among the significant candidates (for
    ``want`` None: is none significant)?"""
    names = {r["name"] for r in rows if r["significant"]}
    return want in names if want is not None else not names


def expected_name(world: str) -> str | None:
    """The name a right first pick gives in ``world`` ("<effect> @ <size>")."""
    effect = world.split(" @ ")[0]
    if effect == "clean" or (effect == "gravity_compensator" and world.endswith("realistic")):
        return None  # nothing hidden, or absorbed by k2 at this size
    return effect


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="+", help="JSON files written by bench_discrepancy.py --out")
    args = parser.parse_args()
    for path in args.records:
        try:
            with open(path) as f:
                results = json.load(f)["results"]
            lines = [*tally(results), "", *verdict_table(results)]
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            parser.exit(2, f"error: {path}: not a record of bench_discrepancy.py --out (a JSON object "
                           f"with 'results', each trial with 'chi2' and 'round1' rows): {exc!r}\n")  # fmt: skip
        print(path, *lines, sep="\n")


def tally(results: dict) -> list[str]:
    """The table's lines: per world, how often each rule's first pick is the hidden effect."""
    lines = [f"{'world':42s}" + "".join(f"{rule:>9s}" for rule in (*RULES, "ceiling")) + "   trials"]
    total = Counter()
    for world, trials in results.items():
        right, n = Counter(), 0
        for trial in trials:
            if "error" in trial:  # a trial that failed is not scored
                continue
            n += 1
            for rule in RULES:
                right[rule] += pick(trial["round1"], trial["chi2"], rule) == expected_name(world)
            right["ceiling"] += within_reach(trial["round1"], expected_name(world))
        total.update(right)
        lines.append(f"{world:42s}" + "".join(f"{right[r]:9d}" for r in (*RULES, "ceiling")) + f"   {n:6d}")
    lines.append(f"{'total':42s}" + "".join(f"{total[r]:9d}" for r in (*RULES, "ceiling")))
    return lines


VERDICTS = ("right, decided", "right, undecided", "wrong, undecided", "wrong, decided",
            "nothing, undecided", "nothing, decided")  # fmt: skip


def first_round_report(rows: list[dict], alpha: float = DEFAULT_ALPHA) -> dict:
    """The part of ``diagnose``'s report that :func:`rivals_from_report` reads, for a first round
    of ``rows`` ranked by the held-out error (``press``, ties by BIC), as ``diagnose`` ranks them.
    The round's level is ``alpha`` over the rows (the first round's Bonferroni split)."""
    significant = sorted((r for r in rows if r["significant"]), key=lambda r: (r["press"], r["bic"]))
    chosen = significant[0] if significant else None
    runner = significant[1] if len(significant) > 1 else None
    delta = runner["press"] - chosen["press"] if runner else None
    rnd = {"base": [], "tests": rows, "chosen": chosen and chosen["label"],
           "runner_up": runner and runner["label"], "delta": delta, "level": alpha / len(rows)}  # fmt: skip
    return {"alpha": alpha, "rank_by": "press", "rounds": [rnd], "dropped": []}


def verdict(rows: list[dict], want: str | None, alpha: float = DEFAULT_ALPHA) -> str:
    """One of :data:`VERDICTS`: is the first name ``want`` (an effect name; None: nothing should
    be named), and does the report leave the round undecided?"""
    report = first_round_report(rows, alpha)
    label = report["rounds"][0]["chosen"]
    name = next((r["name"] for r in rows if r["label"] == label), None)
    right = "nothing" if name is None else ("right" if name == want else "wrong")
    return f"{right}, {'undecided' if rivals_from_report(report) else 'decided'}"


def verdict_table(results: dict) -> list[str]:
    """Per world, how many first rounds end in each of :data:`VERDICTS`."""
    lines = ["first round as the report states it (held-out ranking; undecided = what discover acts on)",
             f"{'world':42s}" + "".join(f"{v:>20s}" for v in VERDICTS)]  # fmt: skip
    total = Counter()
    for world, trials in results.items():
        counts = Counter(verdict(t["round1"], expected_name(world)) for t in trials if "error" not in t)
        total.update(counts)
        lines.append(f"{world:42s}" + "".join(f"{counts[v]:20d}" for v in VERDICTS))
    lines.append(f"{'total':42s}" + "".join(f"{total[v]:20d}" for v in VERDICTS))
    return lines


if __name__ == "__main__":
    main()
