"""The discrepancy workflow: detect where the model and the measurements disagree, name the
missing effect, add it, and show the gap shrink. Researcher side: it reads a dataset only.

1. **Detect.** The paper's model is fitted by generalised least squares with the model-free
   noise floor of the repeat scans (:mod:`.noise_floor`) as the displacement covariance, so its
   chi^2 (with ``6 T - n`` degrees of freedom) tests the model against the noise, not against
   itself (FGLS's own reduced chi^2 is 1 by construction).
2. **Name.** Each candidate term (:mod:`.candidates`) is added in turn; a likelihood-ratio test
   (``chi2_base - chi2_candidate`` against chi^2 with as many degrees of freedom as the candidate
   adds independent columns: its parameter count, less any its columns share with the model) at a
   family-wise error rate ``alpha`` (Bonferroni over the candidates still in play) decides
   whether it is needed; the significant ones are ranked by their leave-one-test-out prediction
   error (cross-validated; BIC on request: :data:`RANK_CRITERIA`); the best is kept, the terms
   kept before are re-tested given the others and dropped when no longer needed (backward
   elimination: a term can stand in for two effects until both are named), and the search
   repeats until nothing significant remains (so two hidden effects can both be named).
   A candidate that the stiffnesses already explain (its whitened columns lie in their span)
   is reported as absorbed, with the joint that absorbs it.
3. **Add and show.** The chosen terms join the model; validation tests are predicted before and
   after, as ratios to the noise floor.

Units: SI; displacements in the unloaded block frame [m, rad].
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DatasetError, UnknownNameError, require_level
from .candidates import Candidate, ModelContext
from .identify import stack
from .model_fit import ModelFit, Whitener, fit_model, scaled_svd  # the fit the search tests (re-exported)
from .noise_floor import NoiseFloor

# How the significant candidates of a round are ranked (lower is better; both in chi^2 units):
# "press", the whitened prediction error of each test from a fit without it (cross-validated),
# or "bic", chi^2 + parameters * ln(observations). BIC charges ln(120) = 4.8 per parameter on the
# paper's 20 tests, so a 6-parameter effect needs 24 more likelihood ratio than a 1-parameter
# rival; near the detection limit BIC named block_offset in 15 of 50 seeds (joint_coupling(4,5)
# and ft_misalignment took most of the rest), press in 34 (docs/discrepancy_benchmark.md,
# "Ranking by held-out error").
RANK_CRITERIA = ("press", "bic")
RANK_LABELS = {"press": "held-out error", "bic": "BIC"}
DEFAULT_RANK = "press"
CONFUSABLE_MARGIN = 10.0  # a runner-up within this of the chosen term's score could be the effect instead
ABSORBED_R2 = 0.999  # a candidate whose whitened columns the stiffness columns explain to this is absorbed
STAND_IN_R2 = 0.5  # a candidate reproducing this share of a named term's pattern could be the effect instead
DEFAULT_ALPHA = 0.01


def require_rank(rank_by: str) -> str:
    """``rank_by`` if it is one of :data:`RANK_CRITERIA`, else the error that lists them."""
    if rank_by not in RANK_CRITERIA:
        raise UnknownNameError("ranking criterion", rank_by, RANK_CRITERIA)
    return rank_by


def report_rank(report: dict) -> str:
    """The criterion ``report`` ranked its candidates by (reports before 2026-11-26 have none: BIC)."""
    return report.get("rank_by", "bic")


def rank_label(report: dict) -> str:
    """How ``report``'s candidates were ranked, in words."""
    return RANK_LABELS[report_rank(report)]


def confusable_margin(report: dict, entry: dict) -> str:
    """``"held-out error only 3.2 apart"`` for a confusable entry (or a round) of ``report``."""
    delta = entry.get("delta", entry.get("delta_bic"))
    return f"{rank_label(report)} only {delta:.1f} apart"


def _explained(aw: np.ndarray, bw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R^2 (p,) of each column of ``bw`` on the stiffness columns ``aw`` (whitened), and each
    joint's share (n, p) of the fit: its coefficient times its column's norm."""
    coef, *_ = np.linalg.lstsq(aw, bw, rcond=None)
    r2 = 1.0 - np.sum((bw - aw @ coef) ** 2, axis=0) / np.maximum(np.sum(bw**2, axis=0), 1e-300)
    return r2, np.abs(coef * np.linalg.norm(aw, axis=0)[:, None])


def _joints(share: np.ndarray, joint_names) -> str:
    """The joints whose share is above 0.2 of the largest, largest first."""
    return ", ".join(joint_names[j] for j in np.argsort(share)[::-1] if share[j] > 0.2 * share.max())


def _stiffness_columns(ctx: ModelContext, white: Whitener) -> np.ndarray:
    ms = ctx.measurements
    return white(stack([m.jacobian for m in ms], [m.wrench for m in ms]))


def absorbed_by(ctx: ModelContext, white: Whitener, term: Candidate, compliance, joint_names) -> str | None:
    """ "absorbed into <joint(s)>" when the stiffnesses' columns explain the term's, else None."""
    r2, share = _explained(_stiffness_columns(ctx, white), white(term.columns(ctx, compliance)))
    if np.min(r2) < ABSORBED_R2:
        return None
    return f"absorbed into {_joints(share.sum(axis=1), joint_names)} (R^2 = {np.min(r2):.5f})"


def identifiable(ctx: ModelContext, white: Whitener, terms: list[Candidate], compliance) -> list[Candidate]:
    """``terms`` without the parameters the stiffnesses explain (fixed at 0, noted in ``absorbed``).

    A parameter whose whitened column the stiffness columns reproduce (R^2 >= ABSORBED_R2) cannot
    be told from them by these tests: a twist of the base about its z axis is joint 1's compliance
    when joint 1 turns about that axis. Left in the fit, least squares would split the compliance
    between the two by minimum norm and report both with the small std of the directions it kept
    (measured: joint 1 at 4.29e6 +- 0.11e6 N*m/rad, in series with the twist 2.15e6). A term all of whose
    parameters are explained is kept whole: its likelihood ratio is 0 and :func:`absorbed_by`
    reports it.
    """
    aw, out = _stiffness_columns(ctx, white), []
    names = ctx.kin.robot.joint_names
    for term in terms:
        r2, share = _explained(aw, white(term.columns(ctx, compliance)))
        gone = r2 >= ABSORBED_R2
        if not gone.any() or gone.all():
            out.append(term)
            continue
        keep = np.flatnonzero(~gone)
        notes = tuple((term.params[k], f"absorbed into {_joints(share[:, k], names)} (R^2 = {r2[k]:.5f}): fixed at 0")
                      for k in np.flatnonzero(gone))  # fmt: skip
        out.append(replace(term, params=tuple(term.params[k] for k in keep), absorbed=notes,
                           columns=lambda c, comp, f=term.columns, k=keep: f(c, comp)[:, k]))  # fmt: skip
    return out


def stand_in_overlap(
    ctx: ModelContext, white: Whitener, fit: ModelFit, term: Candidate, base, others
) -> dict:
    """How much of ``term``'s fitted pattern each of ``others`` reproduces: label -> R^2 in [0, 1].

    The pattern is the term's whitened contribution in ``fit`` (the model of ``base`` terms plus
    ``term``), with what the stiffnesses and the ``base`` terms can fit projected out; each other
    candidate's columns (at ``fit``'s compliances, projected the same way) are regressed on it. A
    candidate with a large overlap could be the effect the named term stands in for, whatever its
    parameter count costs it in the ranking (``discover --always`` puts such candidates to the test).
    """
    ms, c = ctx.measurements, fit.compliance
    a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
    span = white(np.hstack([a, *(b.columns(ctx, c) for b in base)]))
    u, s, _ = np.linalg.svd(span, full_matrices=False)
    u = u[:, s > s[0] * 1e-10]  # a base term collinear with the stiffnesses adds no direction

    def project(x):
        return x - u @ (u.T @ x)

    theta = np.array(list(fit.theta[term.label].values()))
    pattern = project(white(term.design(ctx, c, theta)) @ theta)
    norm = float(pattern @ pattern)
    out = {}
    for cand in others:
        raw = white(cand.columns(ctx, c))
        b = project(raw)
        # columns the stiffnesses and base terms explain leave round-off, which points anywhere
        b = b[:, np.linalg.norm(b, axis=0) > 1e-8 * np.linalg.norm(raw, axis=0)]
        if norm == 0 or b.shape[1] == 0:
            out[cand.label] = 0.0
            continue
        coef = np.linalg.lstsq(b, pattern, rcond=1e-10)[0]
        out[cand.label] = float(np.clip(1.0 - np.sum((pattern - b @ coef) ** 2) / norm, 0.0, 1.0))
    return out


def round_stand_ins(rnd: dict, lead: str) -> list[tuple[str, float]]:
    """The candidates of a report's round ``rnd`` that reproduce at least :data:`STAND_IN_R2` of
    ``lead``'s fitted pattern, as (label, share) pairs, largest share first: the round's
    ``overlap`` column (:func:`stand_in_overlap`) when ``lead`` is whose shares it holds
    (``overlap_of``; reports before 2026-11-26 have none: their shares are of the chosen term, and
    of nothing when nothing was chosen), the ``runner_overlap`` column when ``lead`` is a
    confusable round's runner-up (reports since 2026-11-29). Empty for any other candidate."""
    if rnd.get("overlap_of", rnd["chosen"]) == lead:
        column = "overlap"
    elif lead is not None and rnd.get("runner_up") == lead:
        column = "runner_overlap"
    else:
        return []
    alike = [
        (t["label"], t[column]) for t in rnd["tests"] if t["df"] > 0 and (t.get(column) or 0.0) >= STAND_IN_R2
    ]
    return sorted(alike, key=lambda pair: -pair[1])


MAX_TERMS = 3  # the most terms the stepwise search names (name_effects)


def step_level(alpha: float, n_candidates: int, n_named: int, max_terms: int) -> float:
    """The level of one forward round's tests: Bonferroni over the ``n_candidates`` in play.

    The round for the first term spends ``alpha`` (a clean world's false-alarm rate); each round
    after a first name spends ``alpha / (max_terms - 1)``, so that the later rounds together add
    a false term with probability at most ``alpha`` (at ``alpha`` per round, 1.4-2 % of the
    discrimination benchmark's seeds ended with the right name plus a false one).
    """
    return alpha / n_candidates if n_named == 0 else alpha / (n_candidates * max(max_terms - 1, 1))


@dataclass(frozen=True)
class Step:
    """One round of the stepwise search: every candidate's test against the current model, then
    the re-test of the terms named before (``dropped``: those no longer needed)."""

    base_terms: tuple[str, ...]
    base_chi2: float
    tests: list  # dicts: label, lr, df, p_value, bic, press, significant, overlap (, runner_overlap)
    chosen: str | None
    runner_up: str | None = None  # the best other significant candidate by the ranking criterion
    delta: float | None = None  # its score minus the chosen one's (< CONFUSABLE_MARGIN: confusable)
    dropped: tuple = ()  # dicts: label, lr, df, p_value, level, others (see :func:`_drop_redundant`)
    level: float | None = None  # the tests' significance level (:func:`step_level`)
    delta_bic: float | None = None  # the runner-up's BIC minus the chosen one's (negative: BIC prefers it)
    overlap_of: str | None = None  # whose pattern the rows' "overlap" share is of: chosen, else best-ranked


def _drop_redundant(ctx, white, chosen: list, current: ModelFit, alpha: float, n_pool: int, max_terms: int):
    """Backward elimination: drop the named terms the others have made redundant.

    Each term is re-tested against the model of the other named terms, at the level at which a
    forward round from those terms would test it (:func:`step_level` over the ``n_pool -
    len(others)`` candidates then in play). The least significant term above its
    level is dropped, and the re-test repeats. A term named early can stand in for a
    combination of two effects (a block offset's rotation and translation together, 6 parameters,
    fit a wrist coupling plus a sensor misalignment better than either alone); once both are named,
    its likelihood ratio falls to the noise. Returns the kept terms, their fit, and the drops (dicts).
    """
    dropped = []
    while len(chosen) > 1:
        worst = None
        level = step_level(alpha, n_pool - len(chosen) + 1, len(chosen) - 1, max_terms)
        for term in chosen:
            others = [t for t in chosen if t is not term]
            fit = fit_model(ctx, white, others)
            lr, p, df = current.likelihood_ratio_test(fit, term.label)
            if p >= level and (worst is None or p > worst[0]):
                worst = (p, term, fit, lr, df, [t.label for t in others])
        if worst is None:
            break
        p, term, current, lr, df, others = worst
        chosen = [t for t in chosen if t is not term]
        dropped.append({"label": term.label, "lr": float(lr), "df": int(df), "p_value": p,
                        "level": float(level), "others": others})  # fmt: skip
    return chosen, current, dropped


def _record_shares(ctx, white, rows: list, column: str, label: str, remaining, fits: dict, base) -> None:
    """Write into ``rows[column]`` each candidate's share of ``label``'s fitted pattern
    (:func:`stand_in_overlap` over the ``remaining`` candidates, with the ``base`` terms named
    before; ``label``'s own row: None)."""
    term = next(c for c in remaining if c.label == label)
    overlap = stand_in_overlap(ctx, white, fits[label], term, base, [c for c in remaining if c is not term])
    for row in rows:
        row[column] = overlap.get(row["label"])


def _score(row: dict, rank_by: str) -> tuple[float, float]:
    """A candidate's rank (lower is better): ``rank_by``'s value, BIC on a tie (a leave-one-test-out
    error is ``inf`` when some test cannot be left out)."""
    return (row[rank_by], row["bic"])


def _margin(runner: dict | None, chosen: tuple | None, rank_by: str) -> float | None:
    """The runner-up's score minus the chosen term's (``chosen[0]``: its row), or None (no
    runner-up, or not finite)."""
    margin = runner[rank_by] - chosen[0][rank_by] if runner else float("nan")
    return float(margin) if np.isfinite(margin) else None


def name_effects(
    ctx: ModelContext,
    white: Whitener,
    pool: list[Candidate],
    alpha: float = DEFAULT_ALPHA,
    max_terms: int = MAX_TERMS,
    rank_by: str = DEFAULT_RANK,
) -> tuple[list[Candidate], list[Step], ModelFit]:
    """Stepwise selection: forward by likelihood ratio (Bonferroni at ``alpha``), the significant
    candidates ranked by ``rank_by`` (:data:`RANK_CRITERIA`), and after each addition backward
    (:func:`_drop_redundant`); returns the chosen terms, the rounds, and the final fit. A set of
    terms reached twice ends the search (no cycling)."""
    require_level(alpha)
    require_rank(rank_by)
    chosen: list[Candidate] = []
    steps: list[Step] = []
    current = fit_model(ctx, white, chosen)
    pool = identifiable(ctx, white, pool, current.compliance)
    n_obs = 6 * ctx.n_tests
    seen = {frozenset()}
    while len(chosen) < max_terms:
        # The rounds after a first name spend alpha / (max_terms - 1) each (step_level): at most
        # max_terms - 1 of them, so that together they add a false term with probability at most
        # alpha also when a drop has kept the count of terms down (without drops the count of
        # terms ends the search first).
        if chosen and sum(1 for s in steps if s.base_terms) >= max(max_terms - 1, 1):
            break
        remaining = [c for c in pool if c.label not in {t.label for t in chosen}]
        if not remaining:
            break
        rows, best, fits = [], None, {}
        level = step_level(alpha, len(remaining), len(chosen), max_terms)
        for cand in remaining:
            fit = fits[cand.label] = fit_model(ctx, white, [*chosen, cand])
            lr, p, df = fit.likelihood_ratio_test(current, cand.label)
            bic = fit.chi2 + fit.rank * np.log(n_obs)
            sig = p < level
            rows.append({"label": cand.label, "name": cand.name, "lr": lr, "df": df, "p_value": p,
                         "bic": float(bic), "press": fit.press, "significant": bool(sig)})  # fmt: skip
            if sig and (best is None or _score(rows[-1], rank_by) < _score(best[0], rank_by)):
                best = (rows[-1], cand, fit)
        runner = None
        if best is not None:
            others = [r for r in rows if r["significant"] and r["label"] != best[1].label]
            runner = min(others, key=lambda r: _score(r, rank_by)) if others else None
        # the overlap column: shares of the chosen term's pattern, or with nothing significant of
        # the best-ranked candidate's (what a marginal round's design must also test it against)
        scored = [r for r in rows if r["df"] > 0]
        lead_row = (
            best[0] if best is not None else min(scored, key=lambda r: _score(r, rank_by), default=None)
        )
        if lead_row is not None:
            _record_shares(ctx, white, rows, "overlap", lead_row["label"], remaining, fits, chosen)
        margin = _margin(runner, best, rank_by)
        if margin is not None and margin < CONFUSABLE_MARGIN:
            # a confusable round: the runner-up could be the effect, and so could what stands in
            # for it (a block offset for a scanner scale), which a design must then also ask about
            _record_shares(ctx, white, rows, "runner_overlap", runner["label"], remaining, fits, chosen)
        base_terms, base_chi2 = tuple(t.label for t in chosen), current.chi2
        dropped = []
        if best is not None:
            chosen, current = [*chosen, best[1]], best[2]
            chosen, current, dropped = _drop_redundant(
                ctx, white, chosen, current, alpha, len(pool), max_terms
            )
        steps.append(
            Step(base_terms, base_chi2, rows, best[1].label if best else None, runner["label"] if runner else None,
                 margin, tuple(dropped), level, _margin(runner, best, "bic"),
                 lead_row["label"] if lead_row is not None else None)
        )  # fmt: skip
        state = frozenset(t.label for t in chosen)
        if best is None or state in seen:
            break
        seen.add(state)
    return chosen, steps, current


def require_tests(root, n_tests: int, dof: int, n_params: int, what: str, remedy: str) -> None:
    """A fit must leave a residual to test: ``6 T > n + p`` (``n`` stiffnesses, ``p`` ``what``'s parameters)."""
    need = dof + n_params
    if 6 * n_tests <= need:
        raise DatasetError(
            f"{root}: {n_tests} identification tests give {6 * n_tests} displacement components; {what} "
            f"({n_params} parameters) with the {dof} stiffnesses needs more than {need}, so at least "
            f"{need // 6 + 1} tests. {remedy}"
        )


def require_floor(floor: NoiseFloor | None, root) -> NoiseFloor:
    if floor is None:
        raise DatasetError(
            f"{root}: the dataset has no repeat scans (repeats.csv), so there is no model-free noise floor "
            "to test the model against. Record r >= 2 further scans of the unloaded block at each test's "
            "pose without touching anything (a simulated scenario: [scanner] repeats = 3). Without them "
            "only the model's own residual structure can be shown (vtestbed identify)."
        )
    return floor


def validation_gap(ctx: ModelContext, white: Whitener, fit: ModelFit, terms: list[Candidate]) -> dict:
    """Validation tests' prediction error as a ratio to the noise floor (1 = as good as the noise)."""
    if ctx.n_tests == 0:
        return {}
    theta = [list(fit.theta[t.label].values()) for t in terms]
    cols = [t.design(ctx, fit.compliance, p) for t, p in zip(terms, theta)]  # the exact prediction
    ms = ctx.measurements
    a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
    x_mat = np.hstack([a, *cols]) if cols else a
    gap = ctx.statics.gap(ms, fit.compliance) if ctx.statics is not None else 0.0
    residual = np.concatenate([m.displacement for m in ms]) - gap - x_mat @ fit.x
    per_test = np.sum(white(residual).reshape(-1, 6) ** 2, axis=1) / 6.0
    return {"ratio_to_floor": float(np.sqrt(np.mean(per_test))), "per_test": np.sqrt(per_test).tolist(),
            "test_ids": [m.test_id for m in ms],
            "expected_ratio": expected_validation_ratio(fit.design, white(x_mat))}  # fmt: skip


def expected_validation_ratio(design: np.ndarray, validation_design: np.ndarray) -> float:
    """The validation ratio a *correct* model reaches on average: ``sqrt(1 + mean leverage)``.

    A validation prediction errs by the validation scan's noise (1 in whitened units) plus the
    identified parameters' estimation error carried to the validation pose, whose whitened
    variance per component is ``x_v (X^T X)^+ x_v^T`` (``X``: the fit's whitened identification
    columns ``design`` (6T, k); ``x_v``: a row of ``validation_design`` (6V, k)). The more
    parameters a model carries and the farther the validation poses lie from the identification
    ones, the further above 1 even the true model sits, so the gap's ratio reads against this.
    """
    _, s, vt, norms = scaled_svd(design)  # the fit's own kept directions (model_fit._lstsq)
    projected = (validation_design / norms) @ vt.T / s
    return float(np.sqrt(1.0 + np.mean(np.sum(projected**2, axis=1))))
