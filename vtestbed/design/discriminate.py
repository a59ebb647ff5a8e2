"""Discrimination design: extra tests that best tell confusable models apart (nominal model only).

When ``diagnose`` cannot decide between fitted models (the paper's model plus a candidate term,
or the bare baseline when the evidence is marginal), new tests should go where the predicted
displacements differ most *after each model has adjusted its parameters*: **T-optimality**
(Atkinson and Fedorov 1975). For an ordered pair (a true, b rival) and a design S (the tests
already run plus the new ones) ``T_ab(S) = min_x || W (y_a(S) - X_b(S) x) ||^2``, with ``y_a`` model
a's predictions (its fitted compliances and parameters), ``X_b`` model b's columns (bilinear terms
at b's compliances) and ``W`` the noise floor's whitening: the noncentrality of the
likelihood-ratio test of b when a is true. The design maximises the smallest ``T_ab`` over the
ordered pairs; a pair in which b nests a (``link_compliance(link 2)`` contains
``joint_coupling(2,3)``) has ``T_ab = 0`` on every test and is dropped. ``criterion="difference"``
is the whitened squared difference of the fitted models, ``||W (y_a - y_b)||^2`` (twice their
Kullback-Leibler divergence), which ignores that the models refit.

Candidates: random poses within the joint limits, away from singularity (inv_kappa at the wrist
centre above a floor) and inside the lab's box, with every hook, ring and tension that passes
:func:`vtestbed.design.optimal.candidate_tests` (wire outward, F/T sensor in range). Predictions
are the linear model plus the terms at the commanded pose: the exact statics are common to the
rivals and differ only to second order between their compliances. Units: SI, block frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..dataset import DatasetSetup
from ..errors import OutOfRangeError, UnknownNameError
from ..lab import DEFAULT_TENSION_N, LabSetup
from ..researcher.candidates import Candidate, ModelContext
from ..researcher.diagnose import Whitener, fit_model
from ..researcher.identify import stack
from ..researcher.kinematics import ArmKinematics
from ..researcher.measure import TestMeasurement
from ..researcher.model_fit import term_slices
from ..robots import RobotDescription
from .kappa import inv_kappa_batch
from .optimal import CandidateTest, candidate_tests, nominal_wrench
from .regions import PoseConstraints
from .rivals import (
    BASELINE,
    MARGINAL_FACTOR,
    MAX_RIVALS,
    STAND_IN_R2,
    confirming_rivals,
    rivals_from_report,
)

__all__ = [  # the rivals' selection lives in .rivals; re-exported: discover and the tests use it here
    "BASELINE", "CRITERIA", "MARGINAL_FACTOR", "MAX_RIVALS", "SEPARATION_TARGET", "STAND_IN_R2", "Choice", "Hypothesis",
    "PairBlocks", "Proposal", "choose", "confirming_rivals", "fit_hypotheses", "pair_blocks", "proposed_context", "propose",
    "require_separation", "rivals_from_report", "test_pool",
]  # fmt: skip

CRITERIA = ("T", "difference")
NESTED_TOL = 1e-9  # T_ab below this fraction of ||y_a||^2 over the whole pool: b nests a
DEFAULT_TENSIONS_N = (DEFAULT_TENSION_N, 2 * DEFAULT_TENSION_N)
# The campaigns' default lab constraints on the block (vtestbed.campaigns.spec.PoseSetOptions).
DEFAULT_CONSTRAINTS = PoseConstraints("block", 0.8, (0.3, -1.0, 0.0), (2.3, 1.0, 2.2))
MIN_INV_KAPPA = 0.3  # away from singularity: the paper's regions use 0.7, the whole range is [0, 1]
# A sized round's default target: the noncentrality at which a 1-df likelihood-ratio test at the
# 0.1 % level has 95 % power ((3.29 + 1.645)^2 = 24.4): the rival would be rejected if the other is true.
SEPARATION_TARGET = 25.0


@dataclass(frozen=True)
class Hypothesis:
    """A fitted model: the baseline's terms plus ``extra`` (None: the baseline itself)."""

    label: str
    terms: tuple[Candidate, ...]
    compliance: np.ndarray  # (n,) rad/(N*m)
    x: np.ndarray  # (n + p,) compliances then the terms' parameters (SI)
    chi2: float
    rank: int = 0  # independent columns of the fit: the parameters its BIC charges, as diagnose's

    def columns(self, ctx: ModelContext) -> np.ndarray:
        """(6 T, n + p) the model's columns on ``ctx``'s tests, bilinear terms at its compliances."""
        ms = ctx.measurements
        a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
        # a secant term at its own fitted parameters (Candidate.design)
        cols = [t.design(ctx, self.compliance, self.x[at]) for t, at in term_slices(self.terms, a.shape[1])]
        return np.hstack([a, *cols])

    def predict(self, ctx: ModelContext) -> np.ndarray:
        """(6 T,) predicted displacements [m, rad] (linear model plus the terms)."""
        return self.columns(ctx) @ self.x


def fit_hypotheses(ctx, white: Whitener, base_terms, rivals, pool) -> list[Hypothesis]:
    """Fit ``base_terms`` plus each rival (a candidate label, or :data:`BASELINE`) to ``ctx``'s data."""
    by_label = {c.label: c for c in pool}
    out = []
    for label in rivals:
        if label != BASELINE and label not in by_label:
            raise UnknownNameError("rival model", label, [BASELINE, *by_label])
        terms = [by_label[t] for t in base_terms] + ([] if label == BASELINE else [by_label[label]])
        fit = fit_model(ctx, white, terms)
        out.append(Hypothesis(label, tuple(terms), fit.compliance, fit.x, fit.chi2, fit.rank))
    return out


def test_pool(
    robot: RobotDescription,
    lab: LabSetup,
    rng: np.random.Generator,
    n_poses: int = 300,
    tensions=DEFAULT_TENSIONS_N,
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
    min_inv_kappa: float = MIN_INV_KAPPA,
    max_draws: int = 200_000,
) -> tuple[CandidateTest, ...]:
    """Candidate tests: ``n_poses`` random poses x every hook, ring and tension [N] that pass.

    Poses are uniform within the joint limits, kept when the block meets ``constraints`` and
    the criterion inv_kappa at the wrist centre is at least ``min_inv_kappa``; each (hook, ring,
    tension) must pass :func:`vtestbed.design.optimal.candidate_tests`' nominal checks.
    """
    if n_poses < 1:
        raise OutOfRangeError(f"n_poses = {n_poses} must be >= 1")
    if not 0.0 <= min_inv_kappa < 1.0:
        raise OutOfRangeError(f"min_inv_kappa = {min_inv_kappa:g} must be in [0, 1)")
    tensions = [lab.check_tension(t, "tension") for t in np.atleast_1d(tensions)]
    kept, drawn = [], 0
    while len(kept) < n_poses and drawn < max_draws:
        q = rng.uniform(robot.lower, robot.upper, size=(1000, robot.dof))
        drawn += len(q)
        ok = constraints.ok(robot, q) & (inv_kappa_batch(robot, q, "wrist") >= min_inv_kappa)
        kept += list(q[ok])
    if len(kept) < n_poses:
        raise OutOfRangeError(
            f"only {len(kept)} of {n_poses} random poses met the lab constraints and inv_kappa >= "
            f"{min_inv_kappa:g} in {max_draws} draws: relax the constraints"
        )
    poses = np.array(kept[:n_poses])
    out = []
    for tension in tensions:
        out += candidate_tests(robot, poses, tension=tension, lab=lab)
    return tuple(out)


def proposed_context(kin: ArmKinematics, setup: DatasetSetup, lab: LabSetup, tests) -> ModelContext:
    """A :class:`ModelContext` of would-be measurements: the nominal wrench and Jacobian per test.

    The wrench is the wire's at the commanded pose (:func:`vtestbed.design.optimal.nominal_wrench`),
    moved into block axes like a measured one; displacements are unknown (zeros).
    """
    ms = []
    for i, t in enumerate(tests):
        wrench, _, _, block = nominal_wrench(kin, lab, t.q, t.hook, t.anchor, t.tension)
        rot = block[:3, :3]
        ms.append(TestMeasurement(
            test_id=f"P{i + 1:04d}", group="identification", q=np.asarray(t.q, dtype=float),
            wrench=np.concatenate([rot.T @ wrench[:3], rot.T @ wrench[3:]]), displacement=np.zeros(6),
            jacobian=kin.jacobian(t.q, setup.block_in_flange, frame="tool"),
            frame_unloaded=np.eye(4), frame_loaded=np.eye(4),
        ))  # fmt: skip
    return ModelContext(ms, setup, kin)


@dataclass(frozen=True)
class PairBlocks:
    """Whitened ``y_a`` and ``X_b`` of an ordered pair on the old tests and on each pool test."""

    true: str
    rival: str
    y_old: np.ndarray  # (m,)
    x_old: np.ndarray  # (m, p), columns scaled to unit norm on the old tests
    y_pool: np.ndarray  # (N, 6)
    x_pool: np.ndarray  # (N, 6, p)


def pair_blocks(hyp_a, hyp_b, ctx_old, ctx_pool, white: Whitener, criterion: str = "T") -> PairBlocks:
    """The arrays the criterion needs for (a true, b rival); ``difference`` uses b's prediction."""
    y_old, y_pool = white(hyp_a.predict(ctx_old)), white(hyp_a.predict(ctx_pool))
    if criterion == "T":
        x_old, x_pool = white(hyp_b.columns(ctx_old)), white(hyp_b.columns(ctx_pool))
    elif criterion == "difference":  # b's fixed prediction as one column with coefficient 1
        x_old, x_pool = np.zeros((len(y_old), 0)), np.zeros((len(y_pool), 0))
        y_old, y_pool = y_old - white(hyp_b.predict(ctx_old)), y_pool - white(hyp_b.predict(ctx_pool))
    else:
        raise UnknownNameError("discrimination criterion", criterion, CRITERIA)
    norms = np.linalg.norm(x_old, axis=0)
    norms[norms == 0] = 1.0  # a column with no excitation in the old tests keeps its scale
    n = ctx_pool.n_tests
    return PairBlocks(hyp_a.label, hyp_b.label, y_old, x_old / norms, y_pool.reshape(n, 6),
                      (x_pool / norms).reshape(n, 6, -1))  # fmt: skip


class _PairState:
    """Normal equations of one pair; ``T`` of the old tests plus any set of pool tests."""

    def __init__(self, pb: PairBlocks):
        self.pb = pb
        self.s0, self.g0 = float(pb.y_old @ pb.y_old), pb.x_old.T @ pb.y_old
        self.G0 = pb.x_old.T @ pb.x_old
        self.si = np.einsum("nk,nk->n", pb.y_pool, pb.y_pool)
        self.gi = np.einsum("nkp,nk->np", pb.x_pool, pb.y_pool)
        self.Gi = np.einsum("nkp,nkq->npq", pb.x_pool, pb.x_pool)
        p = self.G0.shape[0]
        # a tiny ridge keeps a parameter the tests do not excite from making G singular
        self.ridge = 1e-12 * max(np.trace(self.G0) / max(p, 1), 1.0) * np.eye(p)

    def totals(self, chosen) -> tuple:
        idx = list(chosen)
        return (self.s0 + self.si[idx].sum(), self.g0 + self.gi[idx].sum(axis=0),
                self.G0 + self.Gi[idx].sum(axis=0))  # fmt: skip

    def t_value(self, chosen) -> float:
        s, g, G = self.totals(chosen)
        if G.shape[0] == 0:
            return float(s)
        return float(s - g @ np.linalg.solve(G + self.ridge, g))

    def t_with_each(self, chosen) -> np.ndarray:
        """(N,) T of the old tests, ``chosen`` and each pool test in turn."""
        s, g, G = self.totals(chosen)
        s_n, g_n = s + self.si, g[None] + self.gi
        if G.shape[0] == 0:
            return s_n
        sol = np.linalg.solve(G[None] + self.Gi + self.ridge, g_n[..., None])[..., 0]
        return s_n - np.einsum("np,np->n", g_n, sol)


@dataclass(frozen=True)
class Choice:
    """The chosen pool indices and the separation before and after (units of the noise floor^2)."""

    indices: tuple[int, ...]
    criterion: str
    pairs: list  # (true, rival) ordered pairs that count
    nested: list  # ordered pairs dropped: the rival nests the true model
    before: dict  # "true vs rival" -> T (old tests only)
    after: dict  # "true vs rival" -> T (old tests plus the chosen ones)
    exchanges: int = 0

    @property
    def separation_before(self) -> float:
        return min(self.before.values())

    @property
    def separation_after(self) -> float:
        return min(self.after.values())


def choose(blocks: list[PairBlocks], k: int, criterion: str = "T", max_passes: int = 10,
           exclude=()) -> Choice:  # fmt: skip
    """Pick ``k`` distinct pool tests maximising the smallest T over the pairs (greedy + exchange).

    A pair whose T with the *whole* pool added stays below :data:`NESTED_TOL` of its ``||y||^2`` is
    nested (the rival reproduces the true model everywhere) and is dropped; ties of the smallest T
    go to the larger sum. Deterministic; ``exclude`` are pool indices not to use.
    """
    if criterion not in CRITERIA:
        raise UnknownNameError("discrimination criterion", criterion, CRITERIA)
    states = [_PairState(b) for b in blocks]
    if not states:
        raise OutOfRangeError("choose needs at least one pair of rival models")
    n_pool = len(states[0].si)
    allowed = np.ones(n_pool, bool)
    allowed[list(exclude)] = False
    if not 1 <= k <= int(allowed.sum()):
        raise OutOfRangeError(f"k = {k} extra tests is outside the valid range [1, {int(allowed.sum())}]")
    live, nested = [], []
    for st in states:
        scale = st.s0 + st.si.sum()
        (live if st.t_value(range(n_pool)) > NESTED_TOL * scale else nested).append(st)
    if not live:
        raise OutOfRangeError(
            "the rival models predict the same displacements on every candidate test: no test can separate them"
        )

    def scores(chosen):
        t = np.array([st.t_with_each(chosen) for st in live])  # (pairs, N)
        total = t.min(axis=0) * (1 + 1e-9) + 1e-12 * t.sum(axis=0)
        total[~allowed] = -np.inf
        total[list(chosen)] = -np.inf
        return total

    chosen: list[int] = []
    for _ in range(k):
        chosen.append(int(np.argmax(scores(chosen))))
    current = min(st.t_value(chosen) for st in live)
    swaps = 0
    for _ in range(max_passes):
        improved = False
        for pos in range(k):
            rest = chosen[:pos] + chosen[pos + 1 :]
            sc = scores(rest)
            sc[chosen[pos]] = -np.inf
            if not np.isfinite(sc.max()):  # every allowed test is in the set: nothing to swap in
                continue
            best = int(np.argmax(sc))
            value = min(st.t_value([*rest, best]) for st in live)
            if value > current * (1 + 1e-9):
                chosen[pos], current, swaps, improved = best, value, swaps + 1, True
        if not improved:
            break

    return Choice(
        tuple(chosen), criterion, [(s.pb.true, s.pb.rival) for s in live],
        [(s.pb.true, s.pb.rival) for s in nested], {f"{s.pb.true} vs {s.pb.rival}": s.t_value([]) for s in live},
        {f"{s.pb.true} vs {s.pb.rival}": s.t_value(chosen) for s in live}, swaps,
    )  # fmt: skip


@dataclass(frozen=True)
class Proposal:
    """Extra tests that separate the rival models, and why."""

    reason: str  # "confusable" or "marginal"
    base_terms: tuple[str, ...]
    rivals: tuple[str, ...]
    tests: tuple[CandidateTest, ...]
    choice: Choice
    pool_size: int
    chi2: dict = field(default_factory=dict)  # rival label -> its chi^2 on the old tests
    target: float | None = None  # the separation the round was sized to reach (None: fixed size)

    def to_dict(self) -> dict:
        c = self.choice
        return {"reason": self.reason, "base_terms": list(self.base_terms), "rivals": list(self.rivals),
                "separation_target": self.target,
                "target_met": None if self.target is None else bool(c.separation_after >= self.target),
                "criterion": c.criterion, "pairs": [list(p) for p in c.pairs],
                "nested_pairs": [list(p) for p in c.nested], "pool_size": self.pool_size,
                "separation_before": c.separation_before, "separation_after": c.separation_after,
                "per_pair_before": c.before, "per_pair_after": c.after, "chi2_old": self.chi2,
                "tests": [t.to_dict() for t in self.tests]}  # fmt: skip


def propose(
    ctx: ModelContext,
    white: Whitener,
    pool_candidates,
    rivals: dict,
    tests,
    lab: LabSetup,
    k: int,
    criterion: str = "T",
    feasible=None,
    max_rounds: int = 60,
    separation: float | None = None,
    max_k: int | None = None,
) -> Proposal:
    """Choose ``k`` of ``tests`` (candidate tests) that separate ``rivals`` (see :func:`rivals_from_report`).

    ``ctx`` holds the dataset's identification measurements (nominal model, no truth), ``white`` its
    noise floor and ``pool_candidates`` the candidate terms the diagnosis used. ``feasible``
    (optional, ``CandidateTest -> bool``) is the lab's answer to "can this test be run?" (the
    scanner must see the block): a chosen test it refuses is excluded and the choice is redone,
    ``max_rounds`` times at most (the tests that separate best are often at the edge of what the
    lab allows: one world of ``bench_discriminate`` needed 46 exclusions).

    With ``separation`` (noise-floor units, e.g. :data:`SEPARATION_TARGET`) the round is sized:
    ``k``, ``k + 1``, ... up to ``max_k`` tests until the smallest predicted T over the rival pairs
    reaches it (the proposal says whether it did).
    """
    tests = tuple(tests)
    if separation is not None:
        require_separation(separation)
    max_k = k if separation is None or max_k is None else max_k
    if max_k < k:
        raise OutOfRangeError(f"max_k = {max_k} is below the round's first size k = {k}")
    hyps = fit_hypotheses(ctx, white, rivals["base_terms"], rivals["rivals"], pool_candidates)
    ctx_pool = proposed_context(ctx.kin, ctx.setup, lab, tests)
    # every ordered pair for T; "difference" is symmetric: one direction per pair
    blocks = [pair_blocks(a, b, ctx, ctx_pool, white, criterion) for i, a in enumerate(hyps)
              for j, b in enumerate(hyps) if i < j or (i > j and criterion == "T")]  # fmt: skip
    excluded: set[int] = set()  # refused by the lab: stays refused at every size
    for size in range(k, max_k + 1):
        choice = _lab_choice(blocks, size, criterion, tests, feasible, excluded, max_rounds)
        if separation is None or choice.separation_after >= separation:
            break
    return Proposal(rivals["reason"], tuple(rivals["base_terms"]), tuple(rivals["rivals"]),
                    tuple(tests[i] for i in choice.indices), choice, len(tests),
                    {h.label: h.chi2 for h in hyps}, separation)  # fmt: skip


def require_separation(separation) -> float:
    """``separation`` [noise-floor units] as a float; OutOfRangeError unless a positive finite number."""
    if not (isinstance(separation, (int, float, np.floating)) and np.isfinite(separation) and separation > 0):
        raise OutOfRangeError(f"separation = {separation!r} must be a positive number (noise-floor units)")
    return float(separation)


def _lab_choice(blocks, k, criterion, tests, feasible, excluded: set, max_rounds: int) -> Choice:
    """:func:`choose` ``k`` tests, excluding (and adding to ``excluded``) those ``feasible`` refuses."""
    for _ in range(max_rounds):
        choice = choose(blocks, k, criterion, exclude=excluded)
        bad = {i for i in choice.indices if feasible is not None and not feasible(tests[i])}
        if not bad:
            return choice
        excluded |= bad
    raise OutOfRangeError(
        f"after {max_rounds} choices the lab still refused some of the {k} proposed tests "
        f"({len(excluded)} of {len(tests)} candidates refused: the scanner cannot see the block, or "
        "the sensor leaves its range): draw more candidate poses (discover --n-poses, now "
        f"a pool of {len(tests)} tests) or ask for fewer tests (--extra-tests)"
    )
