"""Which models a diagnosis leaves undecided: the rivals a discrimination design must separate.

Read from ``diagnose``'s report (its rounds: each round's baseline terms, the candidates' tests
with Bonferroni-adjustable p-values and scores, the chosen term and its lead in the report's
ranking criterion, ``rank_by``: reports before 2026-11-26 ranked by BIC), never from the world.
:func:`rivals_from_report` is the default rule (confusable or marginal evidence);
:func:`confirming_rivals` the rivals of a round run after a decisive diagnosis
(``discover --always``). Labels are candidate labels or :data:`BASELINE`.
"""

from __future__ import annotations

from ..researcher.diagnose import (
    CONFUSABLE_MARGIN,
    STAND_IN_R2,  # noqa: F401 (its docstrings' threshold; design.discriminate re-exports it)
    report_rank,
    round_stand_ins,
)

BASELINE = "baseline"  # the label of the model without a further term
MARGINAL_FACTOR = 10.0  # evidence within this factor of the test's level is marginal
MAX_RIVALS = 4  # models in one discrimination design
ROUND_KINDS = {  # why a round of discrimination tests is run: its rivals' ``reason``, described
    "confusable": "confusable: a runner-up within the margin of the chosen term",
    "marginal": "marginal: weak evidence for the lead",
    "confirm": "confirm: a decisive name against its closest rivals (--always)",
    "screen": "screen: nothing named, the best candidates against the baseline (--always)",
}


def rivals_from_report(report: dict, alpha: float | None = None) -> dict | None:
    """The models a diagnosis leaves undecided, from ``diagnose``'s report; None when it is decisive.

    A candidate is *plausible* in a round when its p-value is below :data:`MARGINAL_FACTOR` times
    the round's level (``diagnose.step_level``: ``alpha`` over the candidates in play, shared by
    the rounds after a first name). The rounds are read in order:

    * *confusable*: the runner-up is within :data:`CONFUSABLE_MARGIN` of the chosen term; the rivals
      are the plausible candidates that close to it (the chosen one first). The place after the
      round's runner-up (the best other *significant* candidate, whose pattern's shares the
      diagnosis records as ``runner_overlap``) is kept for the candidate not ranked before it that
      best stands in for the runner-up (at least :data:`STAND_IN_R2` of its pattern), when that
      place is among the :data:`MAX_RIVALS`: the third place, or the fourth when a plausible
      candidate below the level ranks between the chosen term and the runner-up. Without that
      place, a round with four close models tested the scale world's link 2 against the scale
      and two others and never against the block offset that reproduces 96 % of the scale's
      pattern (its translation, ``block_offset(translation)``, 95 %), which won after the round;
    * *marginal*, a weak name: the chosen term's p-value is above its round's level over
      :data:`MARGINAL_FACTOR`; the rivals are the round's baseline and the plausible candidates
      within :data:`CONFUSABLE_MARGIN` of the chosen one;
    * *marginal*, nothing named: the round's baseline and the plausible candidates within
      :data:`CONFUSABLE_MARGIN` of the best of them.

    A marginal round's rivals then take, while there is room, the candidates that could stand in
    for its lead (the chosen term, else the best plausible one): those that reproduce at least
    :data:`STAND_IN_R2` of its fitted pattern (the round's ``overlap``), largest share first. The
    evidence is weak, so a design that only asks "is the lead there?" can end naming the stand-in
    it never tested against (a block offset's translation reproduces 95 % of a
    ``scanner_scale``'s pattern, and a block offset won after such rounds).

    A round whose chosen term the stepwise search later dropped (``report["dropped"]``: it stood in
    for terms named after it) is skipped, and dropped terms leave every round's baseline. At most
    ``MAX_RIVALS`` models. Returns ``{"reason", "base_terms", "rivals", "round"}``.
    """
    alpha = report["alpha"] if alpha is None else alpha
    score = _scorer(report)
    dropped = set(report.get("dropped") or ())
    for k, rnd in enumerate(report["rounds"]):
        if rnd["chosen"] in dropped:
            continue
        # the diagnosis's level (reports before 2026-11-25 have none: its alpha over the m tests),
        # scaled when another alpha is asked for: the same split of it
        level = (rnd.get("level") or report["alpha"] / len(rnd["tests"])) * (alpha / report["alpha"])
        plausible = sorted(
            (t for t in rnd["tests"] if t["df"] > 0 and t["p_value"] < MARGINAL_FACTOR * level),
            key=score,
        )
        chosen = next((t for t in rnd["tests"] if t["label"] == rnd["chosen"]), None)
        lead = chosen or (plausible[0] if plausible else None)
        if lead is None:
            return None
        close = [lead["label"]] + [
            t["label"] for t in plausible if t is not lead and score(t) - score(lead) < CONFUSABLE_MARGIN
        ]
        base = {"base_terms": [term for term in rnd["base"] if term not in dropped], "round": k}
        delta = rnd.get("delta", rnd.get("delta_bic"))  # reports before 2026-11-26: the BIC lead
        if chosen and delta is not None and delta < CONFUSABLE_MARGIN:
            # the runner-up's best stand-in not ranked before it takes the place after it: the
            # runner-up may be the effect, and the round must not leave it undecided against a
            # candidate that reproduces most of its pattern (a plausible candidate below the level
            # may rank between it and the chosen term: the place follows it while there is room)
            runner = rnd.get("runner_up")
            ahead = close.index(runner) + 1 if runner in close[1 : MAX_RIVALS - 1] else 0
            alike = _stand_ins(rnd, runner, dropped) if ahead else []
            reserved = [label for label in alike if label not in close[:ahead]][:1]  # often the chosen
            rivals = dict.fromkeys([*close[:ahead], *reserved, *close[ahead:]])
            return {"reason": "confusable", "rivals": list(rivals)[:MAX_RIVALS], **base}
        if chosen is None or chosen["p_value"] > level / MARGINAL_FACTOR:
            rivals = dict.fromkeys([BASELINE, *close, *_stand_ins(rnd, lead["label"], dropped)])
            return {"reason": "marginal", "rivals": list(rivals)[:MAX_RIVALS], **base}
    return None


def _stand_ins(rnd: dict, lead: str, dropped) -> list[str]:
    """The labels of :func:`~vtestbed.researcher.diagnose.round_stand_ins` (largest share first)
    that the stepwise search did not drop."""
    return [label for label, _ in round_stand_ins(rnd, lead) if label not in dropped]


def _scorer(report: dict):
    """A test row's score in the report's ranking criterion (lower is better; a leave-one-test-out
    error the strict JSON wrote as null, because some test could not be left out, ranks last)."""
    rank_by = report_rank(report)

    def score(test: dict) -> float:
        value = test.get(rank_by)
        return float("inf") if value is None else float(value)

    return score


def confirming_rivals(report: dict) -> dict:
    """The rivals of a round of tests after a decisive diagnosis (``discover --always``).

    The first round decides what is named first, so its closest models are the ones to test.
    With a name (reason "confirm"), the chosen term against the candidates that could stand in
    for it (those that reproduce at least :data:`STAND_IN_R2` of its fitted pattern, the round's
    ``overlap``, largest first), then the next candidates by the report's ranking: a wrong name
    clear of the confusable band is put to the test against the effect it may stand for, even
    when that effect ranks low (a 6-parameter ``block_offset`` behind a ``joint_coupling``, by
    BIC). Without a name (reason "screen"), the baseline against the best-ranked candidates (an
    effect just below the level). Terms the stepwise search dropped are
    left out. At most :data:`MAX_RIVALS` models.
    """
    dropped = set(report.get("dropped") or ())
    rnd = report["rounds"][0]
    ranked = [t["label"] for t in sorted(rnd["tests"], key=_scorer(report)) if t["df"] > 0]
    chosen = rnd["chosen"] if rnd["chosen"] not in dropped else None
    lead = chosen or BASELINE
    if chosen:
        ranked = _stand_ins(rnd, chosen, dropped) + ranked
    order = dict.fromkeys(label for label in ranked if label not in (lead, *dropped))
    rivals = [lead, *order][:MAX_RIVALS]
    base_terms = [term for term in rnd["base"] if term not in dropped]
    return {
        "reason": "confirm" if chosen else "screen",
        "rivals": rivals,
        "base_terms": base_terms,
        "round": 0,
    }
