"""The feasible test space as a candidate pool: random poses x every hook x every ring x tension levels.

A test's ``A_t`` is linear in the wire tension (the wrench is ``tension * direction``), so one pass
of the nominal checks at the top tension gives every level: the clearance and the wire's outward
direction do not depend on the tension, the F/T sensor's load scales with it. Poses are drawn
uniformly within the joint limits (all six joints free) with a seeded ``numpy.random.Generator``
and kept when the block stays in the lab's zone (:attr:`vtestbed.lab.LabSetup.zone`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..clearance import scanner_position
from ..errors import OutOfRangeError, VtestbedError
from ..lab import G_N_PER_KG, PAPER_LAB, LabSetup
from ..researcher.kinematics import ArmKinematics
from ..robots import NEAR_SINGULAR, RobotDescription
from .clearance import NominalClearance
from .optimal import CandidateTest, candidate_tests, sensor_load
from .regions import PoseConstraints


class NoFeasibleTestError(VtestbedError):
    """Every candidate test was refused (limits of the lab, the sensor or the clearance): the one
    case where other poses, hooks, rings or dropping the clearance check can help."""


def zone_constraints(lab: LabSetup) -> PoseConstraints:
    """The lab's block zone (lowest height, box) as pose constraints on the block origin."""
    box = lab.zone.box
    return PoseConstraints("block", lab.zone.min_height, tuple(box[:3]), tuple(box[3:]))


def random_poses(
    robot: RobotDescription, lab: LabSetup, n: int, rng: np.random.Generator, max_draws: int = 2_000_000
) -> np.ndarray:
    """(n, dof) DH poses [rad] uniform within the joint limits whose block stays in the lab's zone.

    Vectorised: batches of draws, kept in draw order (the same seed gives the same poses).
    """
    if not isinstance(rng, np.random.Generator):
        raise OutOfRangeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    cons, out, drawn = zone_constraints(lab), [], 0
    while sum(len(b) for b in out) < n:
        if drawn >= max_draws:
            raise VtestbedError(
                f"only {sum(len(b) for b in out)} of {n} random poses kept the block in the lab's zone in "
                f"{max_draws} draws: relax lab.zone"
            )
        q = rng.uniform(robot.lower, robot.upper, size=(max(4 * n, 256), robot.dof))
        drawn += len(q)
        out.append(q[cons.ok(robot, q)])
    return np.concatenate(out)[:n]


SENSOR_USE = 0.98  # of the F/T range: the loaded pose's sag turns the wire by a fraction of a degree


def _tool_mass(lab: LabSetup) -> float:
    """Mass [kg] below the sensor's measurement: its tool side, the stem and the block."""
    return lab.sensor.mass_tool_side + lab.block.stem_mass + lab.block.mass


def _tool_weight(kin: ArmKinematics, lab: LabSetup, q) -> np.ndarray:
    """(3,) the tool's weight [N] in the sensor's axes at pose ``q`` (it adds to the wire's pull)."""
    sensor = kin.flange_pose(q) @ lab.sensor_in_flange
    return sensor[:3, :3].T @ np.array([0.0, 0.0, -_tool_mass(lab) * G_N_PER_KG])


def _tool_torque_bound(lab: LabSetup) -> float:
    """A bound [N*m] on the tool weight's torque about the sensor: all its mass at the block's farthest corner."""
    corners = np.array([[x, y, z] for x in (0, -1) for y in (0, -1) for z in (0, -1)]) * lab.block.edge
    b, s = lab.block_in_flange, lab.sensor_in_flange
    far = max(np.linalg.norm(b[:3, :3] @ c + b[:3, 3] - s[:3, 3]) for c in corners)
    return _tool_mass(lab) * G_N_PER_KG * far


SCANNER_MARGIN_M = 0.01  # the unloaded block sags a few mm below its commanded pose


def scanner_placeable(
    robot: RobotDescription, lab: LabSetup, q, distance_m: float, view=(1.0, 1.0, 1.0)
) -> bool:
    """Whether ``Scanner.place`` can stand the scanner at pose ``q`` [rad]: its optical centre at least
    :data:`SCANNER_MARGIN_M` above the table top (when over the table) or the floor."""
    block = ArmKinematics(robot, lab.block_in_flange).tool_pose(q, lab.block_in_flange)
    pos = scanner_position(block, lab.block.edge, distance_m, view)
    table = lab.table
    over = all(abs(pos[i] - table.center[i]) <= table.size[i] / 2 + SCANNER_MARGIN_M for i in (0, 1))
    return bool(pos[2] > (table.height if over else 0.0) + SCANNER_MARGIN_M)


def tension_levels(lab: LabSetup, max_tension: float | None = None, levels: int = 4) -> tuple[float, ...]:
    """``levels`` tensions evenly up to ``max_tension`` [N] (default: the lab's limit), each checked."""
    top = lab.max_tension[0] if max_tension is None else max_tension
    top = lab.check_tension(top, "max_tension_N")
    if isinstance(levels, bool) or not isinstance(levels, int | np.integer) or not 1 <= levels <= 100:
        raise OutOfRangeError(f"tension levels = {levels!r} is outside the valid range [1, 100] (an integer)")
    low = lab.tension_range_N[0]
    values = sorted({round(max(low, top * (i + 1) / levels), 6) for i in range(levels)})
    return tuple(lab.check_tension(float(t), "tension level") for t in values)


@dataclass(frozen=True, eq=False)
class PoolOptions:
    """How :func:`candidate_pool` built a pool: what further poses need to get the same tests and
    checks (:func:`vtestbed.design.refine.refine_design` grows a pool with them)."""

    max_tension: float  # N, the top tension level
    levels: int
    hooks: tuple[str, ...] | None  # None: every hook of the block
    anchors: tuple[str, ...] | None  # None: every ring of the table
    clearance: NominalClearance | None  # None: no clearance check


@dataclass(frozen=True, eq=False)
class TestPool:
    """Candidate tests and their stacked ``A`` matrices.

    ``a`` (T, 6, n) [m/(rad/(N*m)) | rad/(rad/(N*m))], row t the ``A`` of ``tests[t]``.
    """

    __test__ = False  # a data class, not a pytest test class

    tests: tuple[CandidateTest, ...]
    a: np.ndarray
    n_poses: int  # poses drawn
    tensions: tuple[float, ...]  # N, the levels offered
    refused: dict  # counts: "near singularity", "pose clearance", "test clearance", "sensor range"
    options: PoolOptions | None = None  # how it was built (None: assembled by hand)

    def __len__(self) -> int:
        return len(self.tests)

    def to_dict(self) -> dict:
        return {"candidates": len(self), "poses": self.n_poses, "tension_levels_N": list(self.tensions),
                "refused": dict(self.refused)}  # fmt: skip


def candidate_pool(
    robot: RobotDescription,
    lab: LabSetup = PAPER_LAB,
    n_poses: int = 400,
    rng: np.random.Generator | None = None,
    poses=None,
    max_tension: float | None = None,
    levels: int = 4,
    hooks=None,
    anchors=None,
    clearance: bool | NominalClearance = True,
) -> TestPool:
    """Every feasible (pose, hook, ring, tension) test on ``n_poses`` random poses (or ``poses``).

    Parameters
    ----------
    robot, lab : the nominal robot and the lab.
    n_poses : int
        Random poses to draw (ignored when ``poses`` (P, dof) [rad] is given).
    rng : numpy.random.Generator
        Seeded generator for the poses (required without ``poses``).
    max_tension : float or None
        Top tension [N] (default: the lab's ``max_tension``); ``levels`` evenly spaced levels up to it.
    hooks, anchors : list of names or None (all).
    clearance : True, False or a NominalClearance (docs/clearance.md).

    Returns
    -------
    TestPool
        Dropped, and counted in ``refused``: poses near a singularity (the Jacobian at the block
        below :data:`vtestbed.robots.NEAR_SINGULAR`, which a scenario refuses), poses where the
        scanner would stand below the table top or the floor (:func:`scanner_placeable`), poses and
        tests that fail the clearance check, and tension levels beyond the F/T sensor's range.
    """
    tensions = tension_levels(lab, max_tension, levels)
    if poses is None:
        if rng is None:
            raise OutOfRangeError("candidate_pool needs rng (a seeded numpy.random.Generator) or poses")
        poses = random_poses(robot, lab, n_poses, rng)
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    drawn = len(poses)
    nominal = NominalClearance(robot, lab, lab.scanner_distance) if clearance is True else clearance or None
    refused = {"near singularity": 0, "scanner placement": 0, "pose clearance": 0, "test clearance": 0,
               "sensor range": 0}  # fmt: skip
    # a scenario refuses a pose whose Jacobian at the block is near-singular (robots.NEAR_SINGULAR)
    regular = np.array(
        [robot.jacobian_conditioning(q, lab.block_in_flange[:3, 3]) >= NEAR_SINGULAR for q in poses]
    )
    refused["near singularity"] = int(np.sum(~regular))
    poses = poses[regular]
    distance = nominal.distance_m if nominal is not None else lab.scanner_distance
    view = nominal.view if nominal is not None else (1.0, 1.0, 1.0)
    placeable = np.array([scanner_placeable(robot, lab, q, distance, view) for q in poses], dtype=bool)
    refused["scanner placement"] = int(np.sum(~placeable))
    poses = poses[placeable.reshape(-1)] if len(poses) else poses
    if nominal is not None:  # the pose-only pairs first: a pose with a link in the table needs no wire checks
        keep = [nominal.pose_report(q).ok for q in poses]
        refused["pose clearance"] = int(len(poses) - sum(keep))
        kept_poses = poses[np.asarray(keep, dtype=bool)]
        before = nominal.refused
    else:
        kept_poses = poses
    top = tensions[-1]
    base = candidate_tests(
        robot, kept_poses, hooks, anchors, top, lab, check_sensor=False, clearance=nominal or False
    )
    if nominal is not None:
        refused["test clearance"] = nominal.refused - before
    kin = ArmKinematics(robot, lab.block_in_flange)
    limit = np.asarray(lab.sensor.wrench_range)
    loads = np.array([sensor_load(kin, lab, t.q, t.wrench) for t in base]).reshape(-1, 6)  # wire, at the top
    weight = np.array([_tool_weight(kin, lab, t.q) for t in base]).reshape(-1, 3)  # sensor axes [N]
    torque_margin = _tool_torque_bound(lab)
    tests, blocks = [], []
    a_top = np.array([t.a for t in base]).reshape(len(base), 6, robot.dof)
    for level in tensions:
        f = level / top
        force = np.abs(loads[:, :3] * f + weight) <= SENSOR_USE * limit[:3]
        torque = np.abs(loads[:, 3:] * f) + torque_margin <= SENSOR_USE * limit[3:]
        ok = np.all(force, axis=1) & np.all(torque, axis=1)
        refused["sensor range"] += int(np.sum(~ok))
        tests += [CandidateTest(t.q, t.hook, t.anchor, level, t.jacobian, t.wrench * f)
                  for t, o in zip(base, ok) if o]  # fmt: skip
        blocks.append(a_top[ok] * f)
    if not tests:
        raise NoFeasibleTestError(
            f"no feasible test among {drawn} poses x hooks x rings x {len(tensions)} tensions "
            f"(refused: {refused}); draw more poses or relax the lab (docs/clearance.md)"
        )
    options = PoolOptions(tensions[-1], levels, None if hooks is None else tuple(hooks),
                          None if anchors is None else tuple(anchors), nominal)  # fmt: skip
    return TestPool(tuple(tests), np.concatenate(blocks), drawn, tensions, refused, options)


def kappa_selection(
    robot: RobotDescription,
    region_poses,
    n: int,
    tension: float,
    lab: LabSetup = PAPER_LAB,
    clearance: bool | NominalClearance = True,
) -> list[CandidateTest]:
    """The paper's selection: one test per region pose in draw order, at one tension [N].

    The hooks take turns (test i starts at hook i mod 3), the rings are tried nearest first
    (horizontal distance to the block), and the first that passes the nominal checks is used, as
    the campaigns' ``kappa_regions`` pose set does; a pose with none is skipped.
    """
    kin = ArmKinematics(robot, lab.block_in_flange)
    hooks, rings, out = list(lab.block.hooks), lab.table.anchors, []
    nominal = NominalClearance(robot, lab, lab.scanner_distance) if clearance is True else clearance
    for pose in np.atleast_2d(region_poses):
        turn = len(out) % len(hooks)
        block = kin.tool_pose(pose, lab.block_in_flange)[:3, 3]
        order = sorted(rings, key=lambda r: (float(np.linalg.norm(rings[r][:2] - block[:2])), r))
        found = next((c for h in hooks[turn:] + hooks[:turn] for r in order
                      for c in candidate_tests(robot, pose[None], [h], [r], tension, lab, clearance=nominal)), None)  # fmt: skip
        if found is not None:
            out.append(found)
        if len(out) == n:
            return out
    raise VtestbedError(
        f"the paper's kappa selection found only {len(out)} feasible tests among {len(region_poses)} region "
        f"poses for {n} tests: draw more poses"
    )
