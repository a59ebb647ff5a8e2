"""The test lists of a campaign's pose sets, drawn once per campaign and checked in the truth world.

Pose sets (``campaign.axes.pose_set``):

``scenario``
    The base scenario's own tests, in file order.
``kappa_regions``
    The paper's selection: ``pool`` poses drawn from the usable high-criterion regions of the
    joint 2-3 map (:mod:`vtestbed.regions`: optimum at the wrist centre, joint 1 = 0,
    joint 6 = 45 deg, joints 4-5 jittered, lab constraints on the block), in draw order.
``random``
    Uniform random poses within the joint limits that meet the same lab constraints.
``design_optimal``
    The D- (or A-, E-) optimal choice of ``n`` tests among all (pose, hook, ring) candidates of
    a pool (:func:`vtestbed.design.select_tests`; the pool is the ``kappa_regions`` pool by
    default), chosen anew for every test count.

Hook and ring of a generated pose (``kappa_regions``, ``random``): the hooks take turns
(``hook_x``, ``hook_y``, ``hook_edge`` starting at test i mod 3) and the rings are tried
nearest first (horizontal distance to the block); the first combination that passes the
nominal checks (:func:`vtestbed.design.candidate_tests`: the wire leaves the block outward and
the sensor stays in range) and the truth-world check below is used. A pose with none is
dropped, so the n tests of a nested set are the first n feasible poses of one seeded stream:
more tests extend the list without changing its start.

Truth-world check (:class:`FeasibilityChecker`): exactly what :func:`vtestbed.campaigns.montecarlo.prepare`
does (command, hook, solve, place the scanner, cast, tighten, cast); a test that raises any
:class:`~vtestbed.errors.VtestbedError` (scanner sees fewer than three faces, sensor overload,
no convergence, or a test that is not physically possible: a link in the table, the wire through a
link, the scanner's view blocked, docs/clearance.md) is dropped deterministically. Clearance is
checked twice: on the nominal model before the truth world is asked (``candidate_tests``) and in
the truth world at the loaded equilibrium; both refusals are counted in the plan's notes
(``clearance_refused_nominal``, ``clearance_refused_truth``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

import numpy as np

from ..design import kappa, regions
from ..design import optimal as design
from ..design.clearance import NominalClearance
from ..design.priors import stiffness_prior
from ..errors import ClearanceError, VtestbedError
from ..lab import LabSetup
from ..researcher.kinematics import ArmKinematics
from ..scenario import LoadPlan, Scenario
from ..world.physics import run_test_physics
from ..world.rig import Rig
from ..world.truth import load_truth


@dataclass(frozen=True, eq=False)
class TestPlan:
    """An ordered list of tests (pose, hook, ring, tension) that a campaign cell runs on."""

    __test__ = False  # a data class, not a pytest test class

    pose_set: str
    q: np.ndarray  # (n, 6) DH [rad]
    hooks: tuple[str, ...]
    anchors: tuple[str, ...]
    tensions: tuple[float, ...]  # N
    notes: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.hooks)

    def head(self, n: int) -> TestPlan:
        return TestPlan(
            self.pose_set, self.q[:n], self.hooks[:n], self.anchors[:n], self.tensions[:n], self.notes
        )

    def scenario(self, base: Scenario) -> Scenario:
        """The base scenario with these identification tests and no validation tests."""
        return dataclasses.replace(
            base,
            poses=np.array(self.q, dtype=float),
            load=LoadPlan(self.hooks, self.anchors, self.tensions),
            validation_poses=np.zeros((0, self.q.shape[1])),
            validation_load=LoadPlan((), (), ()),
        )

    @property
    def digest(self) -> str:
        text = json.dumps(self.to_dict() | {"notes": None})
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        """JSON-ready; floats as Python reprs, so a round trip is exact."""
        return {"pose_set": self.pose_set, "q_rad": self.q.tolist(), "hooks": list(self.hooks),
                "anchors": list(self.anchors), "tensions_N": list(self.tensions), "notes": self.notes}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict) -> TestPlan:
        q = np.array(d["q_rad"], dtype=float).reshape(-1, 6)
        return cls(d["pose_set"], q, tuple(d["hooks"]), tuple(d["anchors"]),
                   tuple(float(t) for t in d["tensions_N"]), d.get("notes", {}))  # fmt: skip


class FeasibilityChecker:
    """Tries a test in the truth world as :func:`vtestbed.montecarlo.prepare` would (cached)."""

    def __init__(self, scenario: Scenario, lab: LabSetup | None = None):
        self.lab = lab or scenario.lab
        self.rig = Rig(
            scenario.robot, self.lab, truth=load_truth(scenario.robot_name), effects=scenario.effects
        )
        self.distance = scenario.scanner.distance
        self.placement = scenario.scanner.placement
        self.cache: dict = {}
        self.tried = 0
        # the same rules on the nominal model, for candidate_tests (its .refused counts them)
        self.nominal = NominalClearance(scenario.robot, self.lab, self.distance,
                                        self.placement.get("view_direction_block", (1.0, 1.0, 1.0)))  # fmt: skip
        self.clearance_refused = 0  # tests the truth world refused for clearance

    def check(self, q, hook: str, anchor: str, tension: float) -> str | None:
        """None if the test can be run; else why not (the error's message)."""
        key = (np.asarray(q, dtype=float).tobytes(), hook, anchor, float(tension))
        if key not in self.cache:
            self.tried += 1
            try:
                run_test_physics(self.rig, q, hook, anchor, tension, self.distance, self.placement,
                                 clearance="raise")  # fmt: skip
                self.cache[key] = None
            except ClearanceError as exc:
                self.clearance_refused += 1
                self.cache[key] = f"{type(exc).__name__}: {exc}"
            except VtestbedError as exc:
                self.cache[key] = f"{type(exc).__name__}: {exc}"
        return self.cache[key]

    def clearance_notes(self, since: dict | None = None) -> dict:
        """Counts of tests refused for clearance (nominal filter, truth world), since ``since``."""
        now = {"clearance_refused_nominal": self.nominal.refused,
               "clearance_refused_truth": self.clearance_refused}  # fmt: skip
        return {k: v - (since or {}).get(k, 0) for k, v in now.items()}


def lab_constraints(options) -> regions.PoseConstraints:
    box = options.box_m
    return regions.PoseConstraints("block", options.min_height_m, tuple(box[:3]), tuple(box[3:]))


def kappa_pool(robot, options, rng: np.random.Generator) -> regions.PoseSet:
    """``options.pool`` poses from the usable regions of the joint 2-3 map (paper's selection)."""
    opt = kappa.optimize(robot, point="wrist", seed=0, q6=np.radians(45.0))
    pmap = regions.joint_plane_map(robot, opt.q, "wrist", step_deg=1.0)
    cons = lab_constraints(options)
    found = regions.restrict(regions.find_regions(pmap, threshold=options.threshold), pmap, robot, cons)
    return regions.sample_poses(robot, pmap, found, options.pool, rng, constraints=cons,
                                wrist_jitter_deg=options.wrist_jitter_deg, threshold=options.threshold)  # fmt: skip


def random_poses(robot, options, rng: np.random.Generator, max_draws: int = 200_000):
    """Uniform poses within the joint limits that meet the lab constraints (a generator)."""
    cons = lab_constraints(options)
    for _ in range(max_draws):
        q = rng.uniform(robot.lower, robot.upper)
        if cons.ok(robot, q)[0]:
            yield q
    raise VtestbedError(
        f"no random pose met the lab constraints in {max_draws} draws: relax campaign.pose_sets"
    )


def hook_and_ring(
    checker: FeasibilityChecker, kin: ArmKinematics, q, index: int, tension: float, max_checks=4
):
    """The rule's (hook, ring) for test ``index`` at pose ``q``, or None (see the module doc).

    At most ``max_checks`` combinations that pass the nominal checks are tried in the truth world.
    """
    lab = checker.lab
    hooks = list(lab.block.hooks)
    hooks = hooks[index % len(hooks) :] + hooks[: index % len(hooks)]
    block = kin.tool_pose(q, lab.block_in_flange)[:3, 3]
    rings = lab.table.anchors
    order = sorted(rings, key=lambda r: (float(np.linalg.norm(rings[r][:2] - block[:2])), r))
    checks = 0
    for hook in hooks:
        for ring in order:
            if checks < max_checks and design.candidate_tests(
                kin.robot, q[None], [hook], [ring], tension, lab, clearance=checker.nominal
            ):
                checks += 1
                if checker.check(q, hook, ring, tension) is None:
                    return hook, ring
    return None


def nested_plan(
    name: str, stream, n: int, checker, kin, tension: float, limit: int | None = None
) -> TestPlan:
    """The first ``n`` poses of ``stream`` that get a feasible hook and ring."""
    q_out, hooks, rings, dropped = [], [], [], 0
    before = checker.clearance_notes()
    for drawn, q in enumerate(stream):
        if limit is not None and drawn >= limit:
            break
        choice = hook_and_ring(checker, kin, q, len(q_out), tension)
        if choice is None:
            dropped += 1
            continue
        q_out.append(q)
        hooks.append(choice[0])
        rings.append(choice[1])
        if len(q_out) == n:
            break
    if len(q_out) < n:
        raise VtestbedError(
            f"pose set {name!r}: only {len(q_out)} of {n} tests are feasible in the truth world "
            f"({dropped} poses dropped); raise campaign.pose_sets.pool or relax the constraints"
        )
    notes = {"poses_dropped": dropped} | checker.clearance_notes(before)
    return TestPlan(name, np.array(q_out), tuple(hooks), tuple(rings), (tension,) * n, notes)


def design_plan(robot, pool_q: np.ndarray, n: int, options, checker, stiffness_prior) -> TestPlan:
    """The ``options.criterion``-optimal ``n`` tests among the pool's feasible candidates."""
    before = checker.clearance_notes()
    cands = list(design.candidate_tests(robot, pool_q, tension=options.tension_N, lab=checker.lab,
                                        clearance=checker.nominal))  # fmt: skip
    excluded: set[int] = set()
    while True:
        avail = [i for i in range(len(cands)) if i not in excluded]
        if len(avail) < n:
            raise VtestbedError(
                f"pose set 'design_optimal': {len(avail)} feasible candidates for {n} tests; "
                "raise campaign.pose_sets.pool"
            )
        sel = design.select_tests([cands[i] for i in avail], n, stiffness_prior, criterion=options.criterion)
        chosen = sorted(avail[i] for i in sel.indices)
        bad = {
            i for i in chosen if checker.check(cands[i].q, cands[i].hook, cands[i].anchor, cands[i].tension)
        }
        if not bad:
            break
        excluded |= bad
    tests = [cands[i] for i in chosen]
    notes = {"candidates": len(cands), "candidates_infeasible": len(excluded), "criterion": options.criterion,
             "criterion_value": {"D": sel.report.d_value, "A": sel.report.a_value, "E": sel.report.e_value,
                                 "minimax": sel.report.minimax_value}[options.criterion]}  # fmt: skip
    notes |= checker.clearance_notes(before)
    return TestPlan("design_optimal", np.array([t.q for t in tests]), tuple(t.hook for t in tests),
                    tuple(t.anchor for t in tests), tuple(t.tension for t in tests), notes)  # fmt: skip


def build_plans(campaign, keys, progress=None) -> dict[str, TestPlan]:
    """The test list of each plan key (``"pose_set:n"``, see :meth:`Campaign.plan_key`)."""
    sc = campaign.scenario
    robot, opts = sc.robot, campaign.pose_sets
    prior = plan_prior(campaign)  # D-optimality does not depend on it
    checker, kin, pools, out = None, None, {}, {}
    for key in sorted(set(keys)):
        name, n = key.split(":")[0], int(key.split(":")[1])
        if progress:
            progress(f"pose set {name} ({n} tests)")
        if name == "scenario":
            plan = TestPlan("scenario", sc.poses, sc.load.hooks, sc.load.anchors, sc.load.tensions).head(n)
            out[key] = plan
            continue
        if checker is None:
            checker, kin = FeasibilityChecker(sc), ArmKinematics(robot, sc.lab.block_in_flange)
        pool_name = opts.design_pool if name == "design_optimal" else name
        if pool_name == "kappa_regions" and "kappa_regions" not in pools:
            pools["kappa_regions"] = kappa_pool(robot, opts, campaign.pose_set_rng("kappa_regions")).q
        if pool_name == "random" and "random" not in pools:
            stream = random_poses(robot, opts, campaign.pose_set_rng("random"))
            pools["random"] = np.array([next(stream) for _ in range(opts.pool)])
        if name == "kappa_regions":
            plan = nested_plan(name, iter(pools[name]), n, checker, kin, opts.tension_N)
        elif name == "random":
            plan = nested_plan(name, random_poses(robot, opts, campaign.pose_set_rng("random")), n, checker, kin,
                               opts.tension_N)  # fmt: skip
        else:
            plan = design_plan(robot, pools[pool_name], n, opts, checker, prior)
        out[key] = plan
    return out


def plan_prior(campaign) -> np.ndarray:
    """(n,) the campaign's stiffness prior [N*m/rad] (``campaign.pose_sets.stiffness_prior``)."""
    value = campaign.pose_sets.stiffness_prior
    return stiffness_prior(value, campaign.scenario.robot.dof, "campaign.pose_sets.stiffness_prior")


def plan_quality(robot, plan: TestPlan, n: int, lab: LabSetup, prior: np.ndarray) -> dict:
    """Design figures of the first ``n`` tests: mean/min criterion at the wrist centre, log det M_rel.

    Nominal geometry only (no truth): :func:`vtestbed.design.optimal.evaluate` with ``prior``
    [N*m/rad] (the D value does not depend on it).
    """
    head = plan.head(n)
    inv_kappa = kappa.inv_kappa_batch(robot, head.q, "wrist")
    a = [design.candidate_tests(robot, q[None], [h], [r], t, lab, check_sensor=False, outward=False,
                                clearance=False)[0].a
         for q, h, r, t in zip(head.q, head.hooks, head.anchors, head.tensions)]  # fmt: skip
    try:
        d_value = design.evaluate(a, prior).d_value
    except VtestbedError:
        d_value = float("-inf")
    return {"inv_kappa_mean": float(inv_kappa.mean()), "inv_kappa_min": float(inv_kappa.min()),
            "d_log_det_rel": float(d_value)}  # fmt: skip
