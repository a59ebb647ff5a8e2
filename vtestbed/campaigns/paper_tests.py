"""The 20 identification tests of ``scenarios/kr60_paper.toml``, drawn the paper's way, clear only.

How they are drawn (the paper's Section 4, on the joint 2-3 map of the KR60-3):

1. :func:`vtestbed.campaigns.posesets.kappa_pool` with ``numpy.random.default_rng(2023)``: poses
   from the usable high-criterion regions Z1 and Z4 (inv_kappa >= 0.7 at the wrist centre,
   A1 = 0, A6 = 45 deg as in the paper, joints 4-5 jittered +-30 deg, block above 0.8 m), the
   regions taking turns;
2. each pose rounded to 0.01 deg of the controller angles (what the scenario file holds, so the
   checks below are made on the poses that are run);
3. :func:`vtestbed.campaigns.posesets.nested_plan` at 200 N: the hooks take turns, the rings are
   tried nearest first, and a test is kept only if the nominal checks and the truth world accept
   it, clearance included (docs/clearance.md); a pose without such a test is dropped.

``free_a6=True`` draws the same way with the wrist roll free: each pool pose's A6 uniform over a
turn (after the pool's draw, from the same Generator; 80 poses in the pool, where the paper's
draw needs 40), the rest as above; ``free_a1=True`` then draws A1 uniformly within
+-:data:`FREE_A1_DEG` too (the wrist centre's criterion does not depend on either). The paper
holds A6 at 45 deg in every test, and on those tests the block's rotation and the F/T sensor's
are hard to tell apart near their detection limits (docs/discrepancy_benchmark.md, "A forecast
of the first name, and the paper's fixed A6"); ``scenarios/kr60_paper_a6.toml`` holds the 20
tests of the seed-2023 draw with A6 free, ``scenarios/kr60_paper_a6a1.toml`` those of the
seed-2025 draw with A6 and A1 free (the draw ``benchmarks/screen_test_sets.py`` kept of twelve).

Angles are KUKA controller degrees in the file and DH radians inside; tensions are N. Before
clearance was checked, the file held the first 20 pool poses, seven of which a lab cannot run
(kept for the clearance tests in ``tests/data/kr60_paper_unclear.toml``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import OutOfRangeError
from ..researcher.kinematics import ArmKinematics
from ..scenario import Scenario
from .paper_set import rounded_pose, toml_rows, toml_strings
from .posesets import FeasibilityChecker, TestPlan, kappa_pool, nested_plan
from .spec import pose_set_defaults

PAPER_TESTS_SEED = 2023
PAPER_TESTS_COUNT = 20
FREE_A6_POOL = 80  # pool poses drawn with A6 (or A1) free: a turned block rules out more of them
FREE_A1_DEG = 45.0  # A1's range with free_a1 [deg]: a choice; the plan's checks keep what the lab can run


def paper_tests(
    scenario: Scenario,
    n: int = PAPER_TESTS_COUNT,
    seed: int = PAPER_TESTS_SEED,
    free_a6: bool = False,
    free_a1: bool = False,
) -> TestPlan:
    """The first ``n`` clear tests of the paper's kappa-region draw (see the module doc).

    Parameters
    ----------
    scenario : Scenario
        Supplies the robot, its lab and the scanner placement (``scenarios/kr60_paper.toml``).
    n : int
        Number of tests.
    seed : int
        Seed of the pose draw.
    free_a6 : bool
        Draw A6 uniformly over a turn instead of the paper's 45 deg (see the module doc).
    free_a1 : bool
        Draw A1 uniformly within +-FREE_A1_DEG instead of the paper's 0 (with ``free_a6`` only).

    Returns
    -------
    TestPlan
        ``q`` (n, 6) DH [rad] on the 0.01-deg grid of the controller angles, the hooks, rings
        and tensions [N]; ``notes`` counts the dropped poses and the clearance refusals.
    """
    robot = scenario.robot
    options = pose_set_defaults(scenario.lab)  # the paper's 200 N and block zone for the KR60
    if free_a1 and not free_a6:
        raise OutOfRangeError("paper_tests: free_a1 = True needs free_a6 = True (the draws it extends)")
    if free_a6:
        options = dataclasses.replace(options, pool=FREE_A6_POOL)
    rng = np.random.default_rng(seed)
    pool = kappa_pool(robot, options, rng)
    q = pool.q.copy()
    if free_a6:  # theta6 (DH) uniform over a turn: A6 too, whatever its offset and sign
        q[:, 5] = rng.uniform(-np.pi, np.pi, len(q))
    if free_a1:
        q[:, 0] = rng.uniform(-np.radians(FREE_A1_DEG), np.radians(FREE_A1_DEG), len(q))
    rounded = rounded_pose(robot, q)[1]  # the file's 0.01-deg grid, as paper_set draws
    checker = FeasibilityChecker(scenario)
    kin = ArmKinematics(robot, scenario.lab.block_in_flange)
    plan = nested_plan("kappa_regions", iter(rounded), n, checker, kin, options.tension_N)
    drawn = {row.tobytes(): i for i, row in enumerate(rounded)}
    regions = [pool.regions[drawn[q.tobytes()]] for q in plan.q]
    inv_kappa = [float(pool.inv_kappa[drawn[q.tobytes()]]) for q in plan.q]
    return TestPlan(plan.pose_set, plan.q, plan.hooks, plan.anchors, plan.tensions,
                    plan.notes | {"regions": regions, "inv_kappa": inv_kappa})  # fmt: skip


def paper_tests_toml(scenario: Scenario, plan: TestPlan) -> str:
    """The ``[poses]`` and ``[load]`` tables of ``plan`` as the scenario file writes them."""
    controller = np.degrees(scenario.robot.dh_to_controller(plan.q))
    notes = zip(plan.notes["regions"], plan.notes["inv_kappa"], plan.hooks, plan.anchors)
    comments = [f"{region} inv_kappa {ik:.3f} {hook} {ring}" for region, ik, hook, ring in notes]
    lines = [
        "[poses]",
        'convention = "controller"',
        "angles_deg = [",
        toml_rows(controller, comments),
        "]",
        "",
    ]
    lines += [
        "# Per test: the block hook, the table ring (hooks take turns, nearest feasible ring below the",
        "# block) and the wire tension.",
        "[load]",
        f"hook = {toml_strings(plan.hooks)}",
        f"anchor = {toml_strings(plan.anchors)}",
        f"tension_N = {plan.tensions[0]:.1f}",
    ]
    return "\n".join(lines) + "\n"
