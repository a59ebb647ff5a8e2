"""Beyond a finite pool: grow the pool around the design's poses, choose again, repeat.

A random pool samples the feasible test space coarsely (400 poses in six joints), so the minimax
design sits within about 1 % of the best *that pool* allows (the relaxation's bound) but not of the
best the lab allows: a five times larger pool lowers the worst std by 7-12 %. The optimum's tests
lie near a few good poses, so the pool is grown where it matters: each round draws poses around
the current design's poses and the relaxation's support (normal perturbations of every joint,
standard deviations :data:`SCALES_DEG`, clipped to :data:`LIMIT_MARGIN_DEG` inside the joint limits,
kept in the lab's zone), passes
them through the same nominal checks as the pool (:func:`~vtestbed.design.pool.candidate_pool`:
singularity, scanner placement, clearance, wire direction, F/T range, at every hook, ring and
tension level), appends them, and chooses again. Every round's exchange also starts from the
previous round's choice, which stays in the pool, so the worst std never rises. It stops after
``rounds`` rounds or when a round gains less than ``min_gain``.

The relaxation's bound is then the bound of the grown pool: the chosen set is certified against
every design from it, not against the continuum. Units: poses in DH radians, tensions in N, stds
relative (std(k)/k).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError
from ..lab import PAPER_LAB, LabSetup
from ..robots import RobotDescription
from .minimax import MinimaxDesign, design
from .optimal import SIGMA_P, SIGMA_R
from .pool import NoFeasibleTestError, TestPool, candidate_pool, zone_constraints

SCALES_DEG = (2.0, 6.0, 15.0)  # perturbation std per joint [deg]: fine, middle, coarse
DRAWS_PER_SCALE = 10  # poses drawn per centre and scale
MAX_ROUNDS = 20
# New poses keep this far inside each joint limit [deg]. Clipping to the limit itself piles draws
# onto it (the information often grows towards a limit, so the design would sit there), and a lab
# does not command a pose onto its software limit: the loaded sag and the next jog would cross it.
LIMIT_MARGIN_DEG = 1.0


@dataclass(frozen=True)
class RefinedDesign:
    """The design from the grown pool, the pool, and each round's record.

    ``history[r]``: ``worst_relative_std_percent``, ``lower_bound_worst_relative_std_percent`` (of
    that round's pool), ``candidates``, ``new_poses`` (drawn for the next round) and ``new_tests``.
    """

    result: MinimaxDesign
    pool: TestPool
    history: tuple[dict, ...]

    def to_dict(self) -> dict:
        return {"rounds": len(self.history) - 1, "scales_deg": list(SCALES_DEG),
                "draws_per_scale": DRAWS_PER_SCALE, "history": list(self.history)}  # fmt: skip


def merged(first: TestPool, second: TestPool) -> TestPool:
    """One pool of both pools' tests (``first``'s first, so its indices stay valid)."""
    if first.tensions != second.tensions:
        raise OutOfRangeError(
            f"pools with different tension levels cannot merge: {first.tensions} and {second.tensions}"
        )
    refused = {
        key: first.refused.get(key, 0) + second.refused.get(key, 0) for key in first.refused | second.refused
    }
    return TestPool(first.tests + second.tests, np.concatenate([first.a, second.a]),
                    first.n_poses + second.n_poses, first.tensions, refused, first.options)  # fmt: skip


def neighbour_poses(
    robot: RobotDescription, lab: LabSetup, centres: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """(P, dof) DH poses [rad] drawn around each centre at every scale, :data:`LIMIT_MARGIN_DEG` inside
    the joint limits, with the block in the lab's zone."""
    if not isinstance(rng, np.random.Generator):
        raise OutOfRangeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    centres = np.atleast_2d(centres)
    margin = np.minimum(np.radians(LIMIT_MARGIN_DEG), (robot.upper - robot.lower) / 4)
    low, high = robot.lower + margin, robot.upper - margin
    draws = [np.clip(c + rng.normal(0.0, np.radians(s), size=(DRAWS_PER_SCALE, robot.dof)), low, high)
             for c in centres for s in SCALES_DEG]  # fmt: skip
    poses = np.vstack(draws)
    return poses[zone_constraints(lab).ok(robot, poses)]


def _centres(cands: TestPool, result: MinimaxDesign) -> np.ndarray:
    """The chosen tests' poses and the poses of the relaxation's 2N largest weights, each once."""
    idx = list(result.selection.indices)
    if result.relaxation is not None:
        w = result.relaxation.weights
        idx += [
            int(i) for i in np.argsort(-w, kind="stable")[: 2 * len(result.selection.indices)] if w[i] > 1e-6
        ]
    return np.unique(np.array([cands.tests[i].q for i in idx]), axis=0)


def _record(result: MinimaxDesign, cands: TestPool) -> dict:
    out = {
        "worst_relative_std_percent": result.selection.report.minimax_value * 100,
        "candidates": len(cands),
    }
    if result.relaxation is not None:
        out["lower_bound_worst_relative_std_percent"] = float(np.sqrt(result.relaxation.bound)) * 100
    return out


def refine_design(
    robot: RobotDescription,
    cands: TestPool,
    n: int,
    stiffness_prior,
    rng: np.random.Generator,
    lab: LabSetup = PAPER_LAB,
    rounds: int = 4,
    min_gain: float = 0.005,
    sigma_p: float = SIGMA_P,
    sigma_r: float = SIGMA_R,
) -> RefinedDesign:
    """Minimax design of ``n`` tests from ``cands``, grown ``rounds`` times around its poses.

    Parameters
    ----------
    robot, lab : the nominal robot and the lab ``cands`` was built for.
    cands : TestPool
        The starting pool, from :func:`~vtestbed.design.pool.candidate_pool`: the new poses get
        the tests and checks it records (``cands.options``: tension levels, hooks, rings, clearance).
    n : int
        Tests to choose.
    stiffness_prior : (dof,) [N*m/rad] or a StiffnessPrior.
    rng : numpy.random.Generator
        Seeded generator for the new poses.
    rounds : int
        At most this many rounds of growth, in [0, MAX_ROUNDS]; 0 is the plain design.
    min_gain : float
        Stop when a round lowers the worst relative std by less than this fraction.

    Returns
    -------
    RefinedDesign
        ``result.selection.indices`` index ``pool.tests``.
    """
    if isinstance(rounds, bool) or not isinstance(rounds, int | np.integer) or not 0 <= rounds <= MAX_ROUNDS:
        raise OutOfRangeError(
            f"refine rounds = {rounds!r} is outside the valid range [0, {MAX_ROUNDS}] (an integer)"
        )
    if not 0.0 <= min_gain < 1.0:
        raise OutOfRangeError(f"min_gain = {min_gain!r} is outside the valid range [0, 1)")
    built = cands.options
    if built is None:
        raise OutOfRangeError(
            "refine_design needs a pool from candidate_pool (cands.options records its tension levels, "
            "hooks, rings and clearance check); this one was assembled by hand"
        )
    result = design(cands.a, n, stiffness_prior, "minimax", sigma_p, sigma_r)
    history = [_record(result, cands)]
    for _ in range(rounds):
        new = neighbour_poses(robot, lab, _centres(cands, result), rng)
        if not len(new):  # every draw left the lab's zone: nothing to add
            history[-1] |= {"new_poses": 0, "new_tests": 0}
            break
        try:
            extra = candidate_pool(robot, lab, poses=new, max_tension=built.max_tension, levels=built.levels,
                                   hooks=built.hooks, anchors=built.anchors,
                                   clearance=built.clearance or False)  # fmt: skip
        except NoFeasibleTestError:
            history[-1] |= {"new_poses": len(new), "new_tests": 0}
            break
        history[-1] |= {"new_poses": len(new), "new_tests": len(extra)}
        cands = merged(cands, extra)
        before = result.selection.report.minimax_value
        result = design(cands.a, n, stiffness_prior, "minimax", sigma_p, sigma_r,
                        starts={"previous round": result.selection.indices})  # fmt: skip
        gain = 1.0 - result.selection.report.minimax_value / before
        history.append(_record(result, cands))
        if gain < min_gain:
            break
    return RefinedDesign(result, cands, tuple(history))
