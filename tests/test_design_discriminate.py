"""The discrimination design (vtestbed.design.discriminate) against closed forms and brute force.

Real components: the KR60's nominal kinematics (Pinocchio), the paper's lab, the candidate
terms of the discrepancy workflow. References: the prediction difference of a coupling term
computed from Pinocchio Jacobians and the wire's geometry directly; T by ``numpy.linalg.lstsq``
on the stacked whitened arrays (not the normal equations the design updates); every subset of
a small pool; the identity ``in-plane hinge at mid-link 2 = (A_2 + A_3 + coupling(2,3)) / 4``.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations

import numpy as np
import pytest

from vtestbed.dataset import DatasetSetup
from vtestbed.design import discriminate as disc
from vtestbed.design.kappa import inv_kappa_batch
from vtestbed.design.optimal import nominal_wrench, sensor_load
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.errors import OutOfRangeError, UnknownNameError
from vtestbed.lab import PAPER_LAB
from vtestbed.researcher.candidates import ModelContext, candidates
from vtestbed.researcher.diagnose import Whitener
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.robots import load_robot

SIGMA = np.array([5.3e-6] * 3 + [8.5e-6] * 3)  # m, rad: the scanner's displacement noise


@pytest.fixture(scope="module")
def lab_model():
    robot = load_robot("kuka_kr60_3")
    kin = ArmKinematics(robot, PAPER_LAB.block_in_flange)
    setup = DatasetSetup(robot.name, "dh", PAPER_LAB.block_in_flange, PAPER_LAB.sensor_in_flange,
                         PAPER_LAB.block.edge, PAPER_LAB.sensor.name, PAPER_LAB.sensor.wrench_range)  # fmt: skip
    rng = np.random.default_rng(11)
    pool = disc.test_pool(robot, PAPER_LAB, rng, n_poses=12, tensions=(200.0,))
    white = Whitener(NoiseFloor(np.diag(SIGMA**2), n_samples=10**9, n_tests=20))
    terms = {c.label: c for c in candidates(kin)}
    return robot, kin, setup, pool, white, terms


def _hyp(label, terms, x_terms=()):
    c = 1.0 / PAPER_TABLE5.stiffness  # rad/(N*m)
    return disc.Hypothesis(label, tuple(terms), c, np.concatenate([c, x_terms]), 0.0)


def test_pool_is_feasible_on_the_nominal_model(lab_model):
    robot, kin, _, pool, _, _ = lab_model
    assert len(pool) > 12  # several hooks and rings per pose
    q = np.array([t.q for t in pool])
    assert np.all(q >= robot.lower - 1e-12) and np.all(q <= robot.upper + 1e-12)
    assert np.all(inv_kappa_batch(robot, q, "wrist") >= disc.MIN_INV_KAPPA)
    assert np.all(disc.DEFAULT_CONSTRAINTS.ok(robot, q))
    limit = np.asarray(PAPER_LAB.sensor.wrench_range)
    for t in pool:
        wrench, u, hook, _ = nominal_wrench(kin, PAPER_LAB, t.q, t.hook, t.anchor, t.tension)
        # an independent check of the wire's force: tension along hook -> ring
        ring = PAPER_LAB.table.anchor(t.anchor)
        np.testing.assert_allclose(wrench[:3], t.tension * (ring - hook) / np.linalg.norm(ring - hook))
        assert np.all(np.abs(sensor_load(kin, PAPER_LAB, t.q, wrench)) <= limit)


def test_difference_criterion_picks_the_largest_known_difference(lab_model):
    """Models a (coupling(5,6) with c56) and b (none) differ by c56 (J5 (J6.F) + J6 (J5.F)) per test."""
    robot, kin, setup, pool, white, terms = lab_model
    old = disc.proposed_context(kin, setup, PAPER_LAB, pool[:3])
    ctx = disc.proposed_context(kin, setup, PAPER_LAB, pool)
    c56 = 2e-8
    a = _hyp("a", [terms["joint_coupling(5,6)"]], [c56])
    b = _hyp("b", [])
    blocks = [disc.pair_blocks(a, b, old, ctx, white, "difference")]
    choice = disc.choose(blocks, 3, "difference")
    expected = []
    for t in pool:
        wrench, *_, block = nominal_wrench(kin, PAPER_LAB, t.q, t.hook, t.anchor, t.tension)
        jac = kin.jacobian(t.q, frame="base")  # base axes: the difference's norm is rotation invariant
        rot = np.kron(np.eye(2), block[:3, :3].T)
        j5, j6 = jac[:, 4], jac[:, 5]
        delta = rot @ (c56 * (j5 * (j6 @ wrench) + j6 * (j5 @ wrench)))
        expected.append(np.sum((delta / SIGMA) ** 2) / white.inflation)  # the floor's nu/(nu-7)
    expected = np.array(expected)
    assert set(choice.indices) == set(np.argsort(expected)[::-1][:3])
    old_part = choice.before["a vs b"]
    np.testing.assert_allclose(
        choice.after["a vs b"] - old_part, expected[list(choice.indices)].sum(), rtol=1e-9
    )


def _t_direct(a, b, old, ctx, white, subset):
    """T of (a true, b rival) on the old tests plus ``subset``, by lstsq on the stacked arrays."""
    rows = np.array([6 * i + k for i in subset for k in range(6)], dtype=int)
    y = np.concatenate([white(a.predict(old)), white(a.predict(ctx))[rows]])
    x = np.vstack([white(b.columns(old)), white(b.columns(ctx))[rows]])
    coef, *_ = np.linalg.lstsq(x / np.linalg.norm(x, axis=0), y, rcond=None)
    return float(np.sum((y - (x / np.linalg.norm(x, axis=0)) @ coef) ** 2))


def test_t_optimal_matches_brute_force(lab_model):
    """link 3 against coupling(4,5) (canonical correlation 0.99 on the paper's tests): k = 2 of 12."""
    robot, kin, setup, pool, white, terms = lab_model
    small = pool[:: max(1, len(pool) // 12)][:12]
    old = disc.proposed_context(kin, setup, PAPER_LAB, pool[-4:])
    ctx = disc.proposed_context(kin, setup, PAPER_LAB, small)
    a = _hyp("link3", [terms["link_compliance(link 3)"]], [3e-7, 4e-7, 5e-7])
    b = _hyp("c45", [terms["joint_coupling(4,5)"]], [1e-8])
    choice = disc.choose([disc.pair_blocks(a, b, old, ctx, white, "T")], 2, "T")
    brute = {s: _t_direct(a, b, old, ctx, white, s) for s in combinations(range(len(small)), 2)}
    best = max(brute, key=brute.get)
    np.testing.assert_allclose(choice.after["link3 vs c45"], brute[tuple(sorted(choice.indices))], rtol=1e-6)
    np.testing.assert_allclose(choice.before["link3 vs c45"], _t_direct(a, b, old, ctx, white, ()), rtol=1e-6)
    assert set(choice.indices) == set(best)
    assert brute[best] > 3 * choice.before["link3 vs c45"]  # the tests add what the old ones lacked


def test_nested_direction_is_dropped(lab_model):
    """In-plane hinge at mid-link 2 = (A_2 + A_3 + coupling(2,3)) / 4: link 2 reproduces a coupling."""
    robot, kin, setup, pool, white, terms = lab_model
    old = disc.proposed_context(kin, setup, PAPER_LAB, pool[:4])
    ctx = disc.proposed_context(kin, setup, PAPER_LAB, pool)
    c = _hyp("x", []).compliance
    a_cols = disc.Hypothesis("x", (), c, c, 0.0).columns(ctx)
    hinge = terms["link_compliance(link 2)"].columns(ctx, c)[:, 0]
    coupling = terms["joint_coupling(2,3)"].columns(ctx, c)[:, 0]
    np.testing.assert_allclose(4 * hinge, a_cols[:, 1] + a_cols[:, 2] + coupling, rtol=1e-9,
                               atol=1e-9 * np.abs(hinge).max())  # fmt: skip
    coup = _hyp("coupling", [terms["joint_coupling(2,3)"]], [5e-8])
    link = _hyp("link2", [terms["link_compliance(link 2)"]], [2e-7, 3e-7, 4e-7])
    blocks = [disc.pair_blocks(p, q, old, ctx, white) for p, q in ((coup, link), (link, coup))]
    choice = disc.choose(blocks, 3)
    assert choice.nested == [("coupling", "link2")]
    assert choice.pairs == [("link2", "coupling")]
    assert choice.separation_after > choice.separation_before


def _report(rounds, alpha=0.01):
    return {"alpha": alpha, "rounds": rounds}


def _row(label, p, bic, sig, df=1):
    return {"label": label, "p_value": p, "bic": bic, "significant": sig, "df": df}


def test_rivals_from_report():
    tests = [_row("a", 1e-9, 100.0, True), _row("b", 1e-8, 105.0, True), _row("c", 0.5, 140.0, False)]
    conf = disc.rivals_from_report(_report([{"base": [], "chosen": "a", "runner_up": "b", "delta_bic": 5.0,
                                              "tests": tests}]))  # fmt: skip
    assert conf == {"reason": "confusable", "base_terms": [], "round": 0, "rivals": ["a", "b"]}
    # chosen with adjusted p = 3 * 1e-3 = 3e-3 > alpha / 10: marginal
    weak = [_row("a", 1e-3, 100.0, True), _row("b", 0.5, 130.0, False), _row("c", 0.5, 140.0, False)]
    rnd = {"base": ["x"], "chosen": "a", "runner_up": None, "delta_bic": None, "tests": weak}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a"]
    # a weak name with a plausible rival 4 BIC behind (adjusted p 3 * 0.01 = 0.03 < 10 alpha)
    weak[1] = _row("b", 0.01, 104.0, False)
    rnd = {"base": [], "chosen": "a", "runner_up": None, "delta_bic": None, "tests": weak}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a", "b"]
    # nothing chosen, best adjusted p = 3 * 0.02 = 0.06 < 10 alpha: marginal; 3 * 0.2 = 0.6 is not
    near = [_row("a", 0.02, 100.0, False), _row("b", 0.2, 101.0, False), _row("c", 0.9, 99.0, False, 0)]
    rnd = {"base": [], "chosen": None, "runner_up": None, "delta_bic": None, "tests": near}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a"]
    decisive = [_row("a", 1e-12, 100.0, True), _row("b", 1e-3, 130.0, True)]
    rounds = [{"base": [], "chosen": "a", "runner_up": "b", "delta_bic": 30.0, "tests": decisive},
              {"base": ["a"], "chosen": None, "runner_up": None, "delta_bic": None,
               "tests": [_row("b", 0.9, 100.0, False)]}]  # fmt: skip
    assert disc.rivals_from_report(_report(rounds)) is None
    # a confusable first round whose chosen term the stepwise search dropped later: the rounds
    # after it decide, and the dropped term leaves their baseline
    stood_in = [{"base": [], "chosen": "z", "runner_up": "a", "delta_bic": 2.0, "tests": tests},
                {"base": ["z"], "chosen": "a", "runner_up": "b", "delta_bic": 5.0, "tests": tests}]  # fmt: skip
    report = _report(stood_in) | {"dropped": {"z": "named in round 1, dropped in round 2"}}
    assert disc.rivals_from_report(report) == {"reason": "confusable", "base_terms": [], "round": 1,
                                               "rivals": ["a", "b"]}  # fmt: skip
    assert disc.rivals_from_report(_report(stood_in))["round"] == 0  # without the drop, round 0 decides


def test_marginal_rivals_take_the_leads_stand_ins():
    # a weak name: after the baseline and the close candidates, those that reproduce at least half
    # of its pattern, largest share first, however far behind they rank (d: 6 parameters)
    weak = [_row("a", 1e-3, 100.0, True), _row("b", 0.01, 104.0, False), _row("c", 0.5, 140.0, False),
            _row("d", 0.5, 150.0, False, 6), _row("e", 0.5, 160.0, False), _row("f", 0.5, 170.0, False),
            _row("g", 0.9, 90.0, False, 0)]  # fmt: skip
    for row, share in zip(weak[1:], (0.2, 0.55, 0.96, disc.STAND_IN_R2 - 1e-9, 0.7, 1.0), strict=True):
        row["overlap"] = share  # g: no parameters, never a rival
    rnd = {"base": [], "chosen": "a", "runner_up": None, "delta_bic": None, "tests": weak}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a", "b", "d"]
    rnd["overlap_of"] = "a"  # recorded since the rule: the same
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a", "b", "d"]
    weak[1]["p_value"] = 0.5  # b no longer plausible: the room goes to the next stand-in, f
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a", "d", "f"]
    # a stand-in the stepwise search dropped is not a rival
    assert disc.rivals_from_report(_report([rnd]) | {"dropped": {"d": "..."}})["rivals"] == [
        disc.BASELINE, "a", "f", "c"]  # fmt: skip
    # nothing named: the shares count only when they are of the lead (the best plausible candidate)
    for row in weak:
        row["significant"] = False
    weak[0]["p_value"] = 2e-3  # not significant, adjusted 7 * 2e-3 = 0.014 < 10 alpha: marginal, a leads
    rnd |= {"chosen": None, "overlap_of": "a"}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a", "d", "f"]
    rnd["overlap_of"] = "c"  # the shares of another candidate's pattern: no stand-ins
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a"]
    del rnd["overlap_of"]  # an older report: shares only of a chosen term
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == [disc.BASELINE, "a"]


def test_confusable_rivals_keep_room_for_the_runner_ups_stand_in():
    # four close models (a chosen, b the runner-up, c and d within the margin) and e, far behind
    # but reproducing 96 % of b's pattern: e takes the third place, d drops out of the four
    close = [_row("a", 1e-9, 100.0, True), _row("b", 1e-8, 103.0, True), _row("c", 1e-7, 105.0, True),
             _row("d", 1e-6, 107.0, True), _row("e", 1e-4, 150.0, False, 6), _row("f", 0.5, 160.0, False)]  # fmt: skip
    for row, share in zip(close[2:], (0.3, 0.1, 0.96, disc.STAND_IN_R2 - 1e-9), strict=True):
        row["runner_overlap"] = share
    close[0]["runner_overlap"] = 0.99  # the chosen term stands in best: it is a rival already
    rnd = {"base": [], "chosen": "a", "runner_up": "b", "delta_bic": 3.0, "tests": close}
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "b", "e", "c"]
    close[4]["runner_overlap"] = disc.STAND_IN_R2 - 1e-9  # no stand-in: the four close ones
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "b", "c", "d"]
    close[2]["runner_overlap"] = 0.8  # the stand-in is close already: the same four
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "b", "c", "d"]
    # the chosen term's shares (the overlap column) are not the runner-up's
    close[2]["runner_overlap"], close[4]["overlap"] = 0.3, 0.96
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "b", "c", "d"]
    close[4]["runner_overlap"] = 0.96  # a stand-in the stepwise search dropped is not a rival
    dropped = _report([rnd]) | {"dropped": {"e": "..."}}
    assert disc.rivals_from_report(dropped)["rivals"] == ["a", "b", "c", "d"]
    # a plausible candidate below the level ranks second: the place follows the runner-up (the
    # shares are of the runner-up, not of x), and e takes the fourth place
    close[1]["bic"] = 103.5
    close.append(_row("x", 3e-3, 101.0, False))
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "x", "b", "e"]
    # two of them between: the runner-up is fourth, and no place is left for its stand-in
    close.append(_row("y", 3e-3, 102.0, False))
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "x", "y", "b"]
    # the runner-up's best stand-in ranked before it (x) is a rival already: the next one (e)
    close.pop()
    close[-1]["runner_overlap"] = 0.99
    assert disc.rivals_from_report(_report([rnd]))["rivals"] == ["a", "x", "b", "e"]


def test_confirming_rivals_after_a_decisive_diagnosis():
    # a decisive name: the chosen term against the next candidates by BIC (df 0 rows skipped)
    decisive = [_row("a", 1e-12, 100.0, True), _row("b", 1e-3, 130.0, True), _row("c", 0.5, 120.0, False),
                _row("d", 0.9, 150.0, False), _row("e", 0.9, 160.0, False), _row("f", 0.9, 90.0, False, 0)]  # fmt: skip
    rounds = [{"base": [], "chosen": "a", "runner_up": "b", "delta_bic": 30.0, "tests": decisive},
              {"base": ["a"], "chosen": None, "runner_up": None, "delta_bic": None,
               "tests": [_row("b", 0.9, 100.0, False)]}]  # fmt: skip
    assert disc.rivals_from_report(_report(rounds)) is None
    assert disc.confirming_rivals(_report(rounds)) == {
        "reason": "confirm", "rivals": ["a", "c", "b", "d"], "base_terms": [], "round": 0}  # fmt: skip
    # nothing named and nothing marginal: the baseline against the three strongest candidates
    quiet = [_row("a", 0.3, 100.0, False), _row("b", 0.6, 97.0, False), _row("c", 0.9, 99.0, False),
             _row("d", 0.9, 120.0, False)]  # fmt: skip
    rnd = {"base": [], "chosen": None, "runner_up": None, "delta_bic": None, "tests": quiet}
    assert disc.rivals_from_report(_report([rnd])) is None
    assert disc.confirming_rivals(_report([rnd]))["rivals"] == [disc.BASELINE, "b", "c", "a"]
    assert disc.confirming_rivals(_report([rnd]))["reason"] == "screen"
    # a first name the stepwise search dropped is not confirmed, and leaves the rivals
    report = _report(rounds) | {"dropped": {"a": "named in round 1, dropped in round 2"}}
    assert disc.confirming_rivals(report)["rivals"] == [disc.BASELINE, "c", "b", "d"]
    # candidates that reproduce at least half of the named term's pattern come first, largest first,
    # however their parameter count ranks them by BIC (e: 6 parameters, last by BIC)
    overlaps = {"b": 0.1, "c": 0.3, "d": 0.6, "e": 0.9, "f": 0.95}  # f has no parameters: not a rival
    for row in decisive:
        row["overlap"] = overlaps.get(row["label"])
    assert disc.confirming_rivals(_report(rounds))["rivals"] == ["a", "e", "d", "c"]
    decisive[4]["overlap"] = disc.STAND_IN_R2 - 1e-9  # just below: back to the BIC order
    assert disc.confirming_rivals(_report(rounds))["rivals"] == ["a", "d", "c", "b"]


def test_a_sized_round_stops_at_the_first_size_that_reaches_the_target(lab_model):
    """``separation=``: the fewest tests whose smallest T reaches the target, else ``max_k`` (fixed
    sizes, chosen the same way, are the reference)."""
    robot, kin, setup, pool, white, terms = lab_model
    old = disc.proposed_context(kin, setup, PAPER_LAB, pool[:6])
    y = _hyp("scale", [terms["scanner_scale"]], [2e-3]).predict(old).reshape(-1, 6)
    noise = np.random.default_rng(3).normal(0.0, SIGMA, size=y.shape)
    ctx = ModelContext(
        [replace(m, displacement=y[i] + noise[i]) for i, m in enumerate(old.measurements)], setup, kin
    )
    rivals = {"reason": "marginal", "base_terms": [], "rivals": [disc.BASELINE, "scanner_scale"], "round": 0}

    def propose(k, **kw):
        return disc.propose(ctx, white, list(terms.values()), rivals, pool, PAPER_LAB, k, **kw)

    fixed = {k: propose(k).choice.separation_after for k in range(1, 7)}
    assert fixed[3] < fixed[4] < fixed[6]
    sized = propose(1, separation=(fixed[3] + fixed[4]) / 2, max_k=6)
    assert len(sized.tests) == 4 and sized.to_dict()["target_met"] is True
    assert sized.choice.separation_after == pytest.approx(fixed[4], rel=1e-12)
    short = propose(1, separation=2 * fixed[6], max_k=6)  # out of reach: the largest round, said so
    assert len(short.tests) == 6 and short.to_dict()["target_met"] is False
    assert propose(3).to_dict()["separation_target"] is None and len(propose(3, max_k=6).tests) == 3
    with pytest.raises(OutOfRangeError, match="separation = -1"):
        propose(2, separation=-1.0)
    with pytest.raises(OutOfRangeError, match="max_k = 1 is below"):
        propose(2, separation=5.0, max_k=1)


def test_bad_input(lab_model):
    robot, kin, setup, pool, white, terms = lab_model
    ctx = disc.proposed_context(kin, setup, PAPER_LAB, pool[:4])
    blocks = [disc.pair_blocks(_hyp("a", [terms["scanner_scale"]], [1e-3]), _hyp("b", []), ctx, ctx, white)]
    with pytest.raises(OutOfRangeError, match="k = 0"):
        disc.choose(blocks, 0)
    with pytest.raises(OutOfRangeError, match="valid range"):
        disc.choose(blocks, 5)
    with pytest.raises(UnknownNameError, match="discrimination criterion"):
        disc.choose(blocks, 1, "D")
    same = [disc.pair_blocks(_hyp("a", []), _hyp("b", []), ctx, ctx, white)]
    with pytest.raises(OutOfRangeError, match="same displacements"):
        disc.choose(same, 1)
    with pytest.raises(UnknownNameError, match="rival model"):
        disc.fit_hypotheses(ctx, white, [], ["nonsense"], list(terms.values()))
    with pytest.raises(OutOfRangeError, match="n_poses"):
        disc.test_pool(robot, PAPER_LAB, np.random.default_rng(0), n_poses=0)


def test_a_round_as_large_as_the_allowed_pool_uses_each_allowed_test_once(lab_model):
    """k = the number of allowed tests: the exchange has nothing to swap in (it once took index 0,
    excluded or already chosen); the set is the allowed tests, and its T is theirs."""
    robot, kin, setup, pool, white, terms = lab_model
    small = pool[:5]
    ctx = disc.proposed_context(kin, setup, PAPER_LAB, small)
    old = disc.proposed_context(kin, setup, PAPER_LAB, pool[-2:])
    blocks = [
        disc.pair_blocks(_hyp("c56", [terms["joint_coupling(5,6)"]], [5e-8]), _hyp("b", []), old, ctx, white)
    ]
    for exclude in ({0}, set()):
        allowed = [i for i in range(len(small)) if i not in exclude]
        choice = disc.choose(blocks, len(allowed), "T", exclude=exclude)
        assert sorted(choice.indices) == allowed
        state = disc._PairState(blocks[0])
        assert choice.separation_after == pytest.approx(state.t_value(allowed), rel=1e-6)
