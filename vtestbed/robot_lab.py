"""The lab around a given robot: the paper's lab scaled to its reach, and the checks that a lab fits it.

:func:`lab_for_robot` moves and scales the paper's table, rings, block zone and scanner stand-off
(:data:`vtestbed.lab.PAPER_LAB`, the KR60-3's) about joint 2's axis point by the robot's reach;
:func:`check_lab` refuses a scenario's ``[lab]`` that the robot cannot use, naming the field
(docs/lab.md). SI units; positions in the world frame (the robot base on the floor).
"""

from __future__ import annotations

import dataclasses
import math
from functools import cache

import numpy as np

from .lab import (
    DEFAULT_SCANNER_DISTANCE_M,
    FLOOR_HEIGHT_M,
    PAPER_LAB,
    PAPER_REACH_M,
    PAPER_SHOULDER_M,
    BlockZone,
    LabSetup,
    TableSpec,
)
from .schema import Fields


@cache
def robot_reach(robot) -> float:
    """The largest distance [m] of the flange from joint 2's axis over joints 3..n in their limits
    (joints 1 and 2 only turn the arm about that axis); a bounded search from fixed starts."""

    def minus_distance(q):
        pose = np.eye(4)
        for i, angle in enumerate(q, start=2):
            pose = pose @ robot.link_transform(i, angle)
        return -math.hypot(*(pose @ robot.flange_transform)[:2, 3])

    from scipy.optimize import minimize  # here: the CLI and campaigns start without scipy

    low, high = robot.lower[2:], robot.upper[2:]
    starts = np.random.default_rng(0).uniform(low, high, (8, len(low)))
    return -min(minimize(minus_distance, x, bounds=list(zip(low, high))).fun for x in starts)


def shoulder_distance(robot, points) -> np.ndarray:
    """Distance [m] of ``points`` (..., 3) from the circle that joint 2's axis point (DH frame 2's
    origin) sweeps about joint 1's axis: the reach check's centre."""
    frames = robot.frame_poses(np.zeros(robot.dof))
    origin, axis = frames[0][:3, 3], frames[0][:3, 2]

    def split(p):  # axial and radial coordinates about joint 1's axis
        v = np.asarray(p, dtype=float) - origin
        return v @ axis, np.linalg.norm(v - (v @ axis)[..., None] * axis, axis=-1)

    (a_s, r_s), (a_p, r_p) = split(frames[1][:3, 3]), split(points)
    return np.hypot(r_p - r_s, a_p - a_s)


@cache
def lab_for_robot(robot) -> LabSetup:
    """The paper's lab scaled to ``robot``: table, rings, block zone and scanner stand-off.

    Positions scale by ``robot_reach / PAPER_REACH_M`` about joint 2's axis point and move with
    it; heights stop at the floor, the stand-off at the range in which the scanner's measuring
    depth holds the paper's block (:meth:`LabSetup.scanner_distance_range_m`). Scale and
    shift are rounded to 1e-9 so that the KR60 gets :data:`PAPER_LAB` exactly. The rated payload
    is the description's ``rated_payload_kg`` (None: no cap from the robot).
    """
    scale = round(robot_reach(robot) / PAPER_REACH_M, 9)
    shoulder = robot.frame_poses(np.zeros(robot.dof))[1][:3, 3]
    shift = [round(float(a) - b, 9) for a, b in zip(shoulder, PAPER_SHOULDER_M)]

    def at(value, axis, floor=False):  # exactly ``value`` for scale 1 and shift 0
        moved = value + shift[axis] + (scale - 1.0) * (value - PAPER_SHOULDER_M[axis])
        return max(FLOOR_HEIGHT_M, moved) if floor else moved

    t, z, (low, high) = PAPER_LAB.table, PAPER_LAB.zone, PAPER_LAB.scanner_distance_range_m()
    table = TableSpec((at(t.center[0], 0), at(t.center[1], 1)), (t.size[0] * scale, t.size[1] * scale),
                      at(t.height, 2, True), tuple(at(x, 0) for x in t.ring_x), tuple(at(y, 1) for y in t.ring_y))  # fmt: skip
    zone = BlockZone(at(z.min_height, 2, True), tuple(at(v, i % 3, i % 3 == 2) for i, v in enumerate(z.box)))
    kg = robot.rated_payload_kg
    return dataclasses.replace(PAPER_LAB, table=table, zone=zone, rated_payload_kg=kg,
                               scanner_distance=min(high, max(low, DEFAULT_SCANNER_DISTANCE_M * scale)))  # fmt: skip


def check_lab(lab: LabSetup, robot, fields: Fields | None = None) -> LabSetup:
    """Return ``lab`` if ``robot`` can use it, else raise a ScenarioError naming the ``[lab]`` field.

    The flange must reach a point above the table top with the block hanging below it; every ring
    must lie on the table top and within the wire's reach (the robot's reach plus the farthest
    hook's distance from the flange, so that a held block can come over it); the block zone's box
    must not be empty. The table's height range keeps every ring above the floor.
    """
    f, reach, t, name = fields or Fields(), robot_reach(robot), lab.table, robot.display_name
    lo, hi = np.subtract(t.center, np.divide(t.size, 2)), np.add(t.center, np.divide(t.size, 2))
    grid = np.meshgrid(np.linspace(lo[0], hi[0], 61), np.linspace(lo[1], hi[1], 61))
    hang = lab.block_in_flange[2, 3]  # the block hanging straight down from the flange
    nearest = shoulder_distance(robot, np.stack([*grid, np.full_like(grid[0], t.height + hang)], -1)).min()
    if nearest > reach:
        raise f.error("lab.table", f"out of reach: with the block hanging above the table top the flange is at "
                      f"least {nearest:.3f} m from the shoulder (joint 2's axis); valid: at most the {name}'s reach "
                      f"{reach:.3f} m (move center_m, size_m or height_m)")  # fmt: skip
    for key, values, axis in (("ring_x_m", t.ring_x, 0), ("ring_y_m", t.ring_y, 1)):
        for i, v in enumerate(values):
            if not lo[axis] <= v <= hi[axis]:
                raise f.error(f"lab.table.{key}[{i}]", f"= {v:g} is off the table top; valid range "
                              f"[{lo[axis]:g}, {hi[axis]:g}] (center_m +- size_m / 2)")  # fmt: skip
    hook = max(np.linalg.norm((lab.block_in_flange @ [*h, 1.0])[:3]) for h in lab.block.hooks.values())
    for k, (ring, point) in enumerate(t.anchors.items()):
        if (d := shoulder_distance(robot, point)) > reach + hook:
            i, j = divmod(k, len(t.ring_y))
            raise f.error(f"lab.table.ring_x_m[{i}], ring_y_m[{j}]", f"{ring} at {np.round(point, 3).tolist()} m "
                          f"is {d:.3f} m from the shoulder (joint 2's axis), beyond the wire's reach; valid: at most "
                          f"{reach + hook:.3f} m (the {name}'s reach {reach:.3f} m plus the farthest hook's "
                          f"{hook:.3f} m from the flange)")  # fmt: skip
    for i, axis in enumerate("xyz"):
        if not lab.zone.box[i] < lab.zone.box[i + 3]:
            raise f.error("lab.zone.box_m", f"{axis}_min = {lab.zone.box[i]:g} must be below {axis}_max = "
                          f"{lab.zone.box[i + 3]:g}")  # fmt: skip
    return lab
