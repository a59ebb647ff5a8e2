"""``discover.md``: the short report of a :func:`vtestbed.discovery.discover` run, from its result.

Reads only the result dict (what ``discover.json`` holds): the names before and after, the rivals,
each round's proposal with its predicted separation (the smallest T over the rival pairs, in
noise-floor units) and the measured BIC lead of the best rival.
"""

from __future__ import annotations

from .design.rivals import ROUND_KINDS
from .researcher.diagnose import confusable_margin

__all__ = ["markdown"]


def _tests(n: int) -> str:
    return f"{n} test" + ("" if n == 1 else "s")


def _target(proposal: dict) -> str:
    """`` (target 25: met)`` for a sized round, nothing otherwise."""
    target = proposal.get("separation_target")
    return "" if target is None else f" (target {target:g}: {'met' if proposal['target_met'] else 'not met'})"


def markdown(result: dict) -> str:
    """A short report: the names before and after, and the separation before and after."""

    def names(v):
        return ", ".join(f"`{n}`" for n in v) if v else "nothing"

    lines = [f"# discover: {result['scenario']} (seed {result['seed']}, alpha {result['alpha']:g})", "",
             f"**Before**: named {names(result['named_before'])}."]  # fmt: skip
    for c in result["confusable_before"]:
        lines.append(f"- `{c['chosen']}` could also be `{c['runner_up']}` ({confusable_margin(result, c)})")
    if result["rivals"] is None:
        return "\n".join([*lines, "", result.get("note", ""), ""])
    p, r = result["proposal"], result["rivals"]
    mb, ma = result["measured_before"], result["measured_after"]
    lines += [
        "",
        f"**Rivals** ({ROUND_KINDS.get(r['reason'], r['reason'])}): {names(r['rivals'])}"
        + (f" on top of {names(r['base_terms'])}" if r["base_terms"] else "") + ".",
        f"**Proposed** {_tests(len(p['tests']))} more ({p['criterion']}-optimal among {p['pool_size']} "
        f"candidates; {p['tests_refused_by_the_lab']} refused by the lab): predicted separation "
        f"(smallest T over the rival pairs, noise floor units) {p['separation_before']:.1f} -> "
        f"{p['separation_after']:.1f}{_target(p)}.",
        f"Measured: the best rival `{mb['best']}` leads by BIC {mb['delta_bic']:.1f} before; "
        f"`{ma['best']}` by {ma['delta_bic']:.1f} after.",
    ]  # fmt: skip
    for r in result["rounds"][1:]:  # the later rounds, each from the undecided diagnosis before it
        p, ma = r["proposal"], r["measured_after"]
        lines.append(f"**Round {r['round']}** ({r['rivals']['reason']}, after round {r['round'] - 1} named "
                     f"{names(result['rounds'][r['round'] - 2]['named'])}): {names(r['rivals']['rivals'])}; "
                     f"{_tests(len(p['tests']))} more, predicted separation {p['separation_before']:.1f} -> "
                     f"{p['separation_after']:.1f}{_target(p)}; measured: `{ma['best']}` leads by BIC {ma['delta_bic']:.1f}.")  # fmt: skip
    n = len(result["rounds"])
    after = result.get("alpha_after_round")  # discover.json before 2026-11-28: every diagnosis at alpha
    level = f" (alpha {after:g}, the level after a round: docs/discrepancy.md)" if after is not None else ""
    lines += ["", f"**After**{f' {n} rounds' if n > 1 else ''}: named {names(result['named_after'])}{level}."]
    vb, va = result.get("validation_gap_before"), result.get("validation_gap_after")
    if vb and va:
        lines.append(f"Validation prediction error over the noise floor: {vb['baseline']:.2f} with the paper's "
                     f"model, {vb['named']:.2f} with the terms named before, {va['named']:.2f} after.")  # fmt: skip
    for c in result["confusable_after"]:
        lines.append(f"- still `{c['chosen']}` or `{c['runner_up']}` ({confusable_margin(result, c)})")
    return "\n".join(lines) + "\n"
