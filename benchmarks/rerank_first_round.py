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

    .venv/bin/python benchmarks/bench_discrepancy.py --limit-only --limit-power 0.85 --out near.json
    .venv/bin/python benchmarks/rerank_first_round.py near.json
"""

from __future__ import annotations

import argparse
import json
from collections import Counter

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
                lines = tally(json.load(f)["results"])
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            parser.exit(2, f"error: {path}: not a record of bench_discrepancy.py --out (a JSON object "
                           f"with 'results', each trial with 'chi2' and 'round1' rows): {exc!r}\n")  # fmt: skip
        print(path, *lines, sep="\n")


def tally(results: dict) -> list[str]:
    """The table's lines: per world, how often each rule's first pick is the hidden effect."""
    lines = [f"{'world':42s}" + "".join(f"{rule:>9s}" for rule in RULES) + "   trials"]
    total = Counter()
    for world, trials in results.items():
        right, n = Counter(), 0
        for trial in trials:
            if "error" in trial:  # a trial that failed is not scored
                continue
            n += 1
            for rule in RULES:
                right[rule] += pick(trial["round1"], trial["chi2"], rule) == expected_name(world)
        total.update(right)
        lines.append(f"{world:42s}" + "".join(f"{right[rule]:9d}" for rule in RULES) + f"   {n:6d}")
    lines.append(f"{'total':42s}" + "".join(f"{total[rule]:9d}" for rule in RULES))
    return lines


if __name__ == "__main__":
    main()
