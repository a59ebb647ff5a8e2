"""Maps of the criterion, high-criterion test regions Z1..Zk, lab constraints and pose sampling.

* :func:`joint_plane_map`: the criterion over the joint 2-3 plane within the limits (Figure 5).
* :func:`cartesian_map`: the same poses binned by the position of the reference point in the
  x-z plane of the base frame (joint 1 at 0, Figure 2); a bin holds the best value reaching it.
* :func:`find_regions`: the basins of the map's local maxima (steepest ascent on the grid)
  above a threshold. Regions are numbered down the columns of the map, theta_2 left to right
  and theta_3 from high to low (peaks less than ``column_gap`` apart in theta_2 share a column).
* :class:`PoseConstraints` removes what the lab cannot do (a point too close to the floor,
  outside a box); :func:`sample_poses` draws test poses from the chosen regions.

Angles are DH angles in rad, positions in m in the robot base frame (floor at z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import OutOfRangeError, UnknownNameError, VtestbedError
from ..robots import RobotDescription
from .kappa import (
    arm_wrist_blocks,
    check_wrist,
    coupling_ratio,
    inv_kappa_batch,
    point_name,
    reference_offset,
    wrist_point,
)


@dataclass(frozen=True)
class JointPlaneMap:
    """The criterion on a grid of (theta_2, theta_3), the other joints at ``q_fixed``."""

    theta2: np.ndarray  # (n2,) rad
    theta3: np.ndarray  # (n3,) rad
    values: np.ndarray  # (n2, n3)
    q_fixed: np.ndarray  # (6,) rad; entries 1 and 2 are ignored
    point: str | tuple  # reference point: a name or a (3,) offset in the flange frame [m]

    def poses(self) -> np.ndarray:
        """(n2 * n3, 6) DH poses of the grid cells (row-major in theta_2)."""
        g2, g3 = np.meshgrid(self.theta2, self.theta3, indexing="ij")
        q = np.tile(self.q_fixed, (g2.size, 1))
        q[:, 1], q[:, 2] = g2.ravel(), g3.ravel()
        return q


def joint_plane_map(robot: RobotDescription, q_fixed, point="wrist", step_deg: float = 0.5) -> JointPlaneMap:
    """The criterion over the joint 2-3 plane at the joint limits' resolution ``step_deg``."""
    check_wrist(robot)
    q_fixed = robot.check_pose(q_fixed, field="q_fixed")
    if not 0.01 <= step_deg <= 10.0:
        raise OutOfRangeError(f"step_deg = {step_deg:g} deg is outside the valid range [0.01, 10] deg")
    axes = [
        np.linspace(
            robot.lower[i],
            robot.upper[i],
            int(round(np.degrees(robot.upper[i] - robot.lower[i]) / step_deg)) + 1,
        )
        for i in (1, 2)
    ]
    spec = point if isinstance(point, str) else tuple(float(v) for v in reference_offset(point))
    pmap = JointPlaneMap(axes[0], axes[1], np.empty(0), q_fixed.copy(), spec)
    values = inv_kappa_batch(robot, pmap.poses(), point).reshape(axes[0].size, axes[1].size)
    return replace(pmap, values=values)


def wrist_report(robot: RobotDescription, q, point="wrist") -> dict:
    """How exact the arm-wrist split is at poses ``q`` (N, 6) [rad], for the JSON outputs.

    ``wrist_axis_distances_m_max``: per axis 4, 5, 6, the largest distance of the wrist point
    from it (the non-sphericity; 0 for a spherical wrist); ``coupling_j12_over_j11``: the range
    of ``||J12||_F / ||J11||_F`` at ``point`` (what the criterion neglects; docs/poses.md).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    spherical = check_wrist(robot)
    ratio = coupling_ratio(robot, q, point)
    return {
        "spherical": spherical,
        "wrist_point": "origin of DH frame 5 (axes 4-6 meet)" if spherical
        else "least-squares point of axes 4-6 (offset wrist)",
        "wrist_axis_distances_m_max": wrist_point(robot, q)[1].max(axis=0).tolist(),
        "coupling_j12_over_j11": [float(ratio.min()), float(ratio.max())],
    }  # fmt: skip


@dataclass(frozen=True)
class CartesianMap:
    """Best criterion per (x, z) bin of the reference point, joint 1 at 0 (NaN: unreachable)."""

    x_edges: np.ndarray  # (nx + 1,) m
    z_edges: np.ndarray  # (nz + 1,) m
    values: np.ndarray  # (nx, nz)
    point: str


def cartesian_map(
    robot: RobotDescription, q_fixed, point="wrist", step_deg: float = 0.25, bin_size: float = 0.02
) -> CartesianMap:
    """Bin the joint 2-3 grid (joints 1, 4-6 at ``q_fixed``) by the point's x and z [m]."""
    pmap = joint_plane_map(robot, q_fixed, point, step_deg)
    _, _, pos = arm_wrist_blocks(robot, pmap.poses(), point)
    x, z, v = pos[:, 0], pos[:, 2], pmap.values.ravel()
    x_edges = np.arange(np.floor(x.min() / bin_size) - 1, np.ceil(x.max() / bin_size) + 2) * bin_size
    z_edges = np.arange(np.floor(z.min() / bin_size) - 1, np.ceil(z.max() / bin_size) + 2) * bin_size
    ix, iz = np.digitize(x, x_edges) - 1, np.digitize(z, z_edges) - 1
    best = np.full((x_edges.size - 1, z_edges.size - 1), -np.inf)
    np.maximum.at(best, (ix, iz), v)
    best[np.isinf(best)] = np.nan
    return CartesianMap(x_edges, z_edges, best, point_name(point))


@dataclass(frozen=True)
class Region:
    """A high-criterion region of a :class:`JointPlaneMap`."""

    name: str
    peak: np.ndarray  # (2,) theta_2, theta_3 [rad] of the region's maximum
    peak_value: float
    mask: np.ndarray  # (n2, n3) bool, the cells of the region
    excluded: str | None = None  # why the lab cannot use it (None: usable)
    removed: np.ndarray | None = None  # (n2, n3) bool, cells the constraints took away

    @property
    def cells(self) -> int:
        return int(self.mask.sum())

    def to_dict(self, pmap: JointPlaneMap) -> dict:
        g2, g3 = np.meshgrid(pmap.theta2, pmap.theta3, indexing="ij")
        m = self.mask
        box = [float(np.degrees(g[m].min())) if m.any() else None for g in (g2, g3)]
        box += [float(np.degrees(g[m].max())) if m.any() else None for g in (g2, g3)]
        return {
            "name": self.name,
            "peak_q23_deg": np.degrees(self.peak).tolist(),
            "peak_inv_kappa": self.peak_value,
            "cells": self.cells,
            "cells_removed_by_constraints": 0 if self.removed is None else int(self.removed.sum()),
            "area_deg2": self.cells
            * float(np.degrees(pmap.theta2[1] - pmap.theta2[0]))
            * float(np.degrees(pmap.theta3[1] - pmap.theta3[0])),
            "q2_deg_range": [box[0], box[2]],
            "q3_deg_range": [box[1], box[3]],
            "excluded": self.excluded,
        }


def _ascent_labels(values: np.ndarray) -> np.ndarray:
    """Index (flat) of the local maximum each cell reaches by steepest ascent on the 8-grid."""
    n2, n3 = values.shape
    padded = np.pad(values, 1, constant_values=-np.inf)
    flat = np.arange(values.size).reshape(n2, n3)
    padded_idx = np.pad(flat, 1, constant_values=-1)
    best_val, best_idx = values.copy(), flat.copy()
    for d2 in (-1, 0, 1):
        for d3 in (-1, 0, 1):
            v = padded[1 + d2 : 1 + d2 + n2, 1 + d3 : 1 + d3 + n3]
            better = v > best_val
            best_val = np.where(better, v, best_val)
            best_idx = np.where(better, padded_idx[1 + d2 : 1 + d2 + n2, 1 + d3 : 1 + d3 + n3], best_idx)
    target = best_idx.ravel()
    while True:  # pointer jumping: O(log path length) passes
        nxt = target[target]
        if np.array_equal(nxt, target):
            return target.reshape(n2, n3)
        target = nxt


def find_regions(
    pmap: JointPlaneMap, threshold: float = 0.7, min_cells: int = 20, column_gap_deg: float = 30.0
) -> tuple[Region, ...]:
    """High-criterion regions: basins of local maxima, restricted to ``values >= threshold``."""
    if not 0.0 < threshold < 1.0:
        raise OutOfRangeError(f"threshold = {threshold:g} is outside the valid range (0, 1)")
    labels = _ascent_labels(pmap.values)
    above = pmap.values >= threshold
    found = []
    for peak in np.unique(labels[above]):
        mask = above & (labels == peak)
        if mask.sum() >= min_cells:
            i2, i3 = np.unravel_index(peak, pmap.values.shape)
            found.append((np.array([pmap.theta2[i2], pmap.theta3[i3]]), float(pmap.values.flat[peak]), mask))
    found.sort(key=lambda r: r[0][0])
    columns, last = [], None
    for r in found:
        if last is None or np.degrees(r[0][0] - last) > column_gap_deg:
            columns.append([])
        columns[-1].append(r)
        last = r[0][0]
    ordered = [r for col in columns for r in sorted(col, key=lambda r: -r[0][1])]
    return tuple(Region(f"Z{k + 1}", p, v, m) for k, (p, v, m) in enumerate(ordered))


@dataclass(frozen=True)
class PoseConstraints:
    """What the lab allows, checked on the position of ``point`` (base frame, floor at z = 0).

    ``min_height`` [m]: lowest z; ``box_min``/``box_max`` (3,) [m]: a box the point must stay in.
    """

    point: str = "block"
    min_height: float | None = None
    box_min: tuple[float, float, float] | None = None
    box_max: tuple[float, float, float] | None = None

    def __post_init__(self):
        if (self.box_min is None) != (self.box_max is None):
            raise OutOfRangeError("box_min and box_max must be given together (3 numbers each, m)")
        if self.box_min is not None and not np.all(np.asarray(self.box_min) < np.asarray(self.box_max)):
            raise OutOfRangeError(
                f"box_min {np.asarray(self.box_min).tolist()} must be below box_max"
                f" {np.asarray(self.box_max).tolist()} on every axis [m]"
            )

    def failures(self, robot: RobotDescription, q: np.ndarray) -> dict[str, np.ndarray]:
        """Per constraint, a (N,) bool array: True where the pose breaks it."""
        _, _, pos = arm_wrist_blocks(robot, np.atleast_2d(q), self.point)
        out = {}
        if self.min_height is not None:
            out[f"{self.point} below z = {self.min_height:g} m"] = pos[:, 2] < self.min_height
        if self.box_min is not None:
            lo, hi = np.asarray(self.box_min), np.asarray(self.box_max)
            box = f"{[float(v) for v in lo]}..{[float(v) for v in hi]}"
            out[f"{self.point} outside the lab box {box} m"] = np.any((pos < lo) | (pos > hi), axis=1)
        return out

    def ok(self, robot: RobotDescription, q: np.ndarray) -> np.ndarray:
        fails = self.failures(robot, q)
        return ~np.any(list(fails.values()), axis=0) if fails else np.ones(np.atleast_2d(q).shape[0], bool)


def restrict(
    regions,
    pmap: JointPlaneMap,
    robot: RobotDescription,
    constraints: PoseConstraints,
    min_fraction: float = 0.05,
) -> tuple[Region, ...]:
    """Remove the cells the lab cannot use; a region keeping < ``min_fraction`` is excluded."""
    fails = {k: v.reshape(pmap.values.shape) for k, v in constraints.failures(robot, pmap.poses()).items()}
    out = []
    for r in regions:
        bad = np.zeros_like(r.mask)
        for f in fails.values():
            bad |= f
        mask = r.mask & ~bad
        reason = None
        if mask.sum() < min_fraction * r.cells:
            worst = max(fails, key=lambda k: (fails[k] & r.mask).sum())
            reason = f"{100 * (fails[worst] & r.mask).sum() / r.cells:.1f}% of its cells: {worst}"
        out.append(replace(r, mask=mask, excluded=reason, removed=r.mask & bad))
    return tuple(out)


@dataclass(frozen=True)
class PoseSet:
    """Test poses drawn from regions."""

    q: np.ndarray  # (n, 6) DH rad
    regions: tuple[str, ...]  # (n,) region of each pose
    inv_kappa: np.ndarray  # (n,)

    def to_dict(self) -> dict:
        return {
            "q_deg": np.degrees(self.q).tolist(),
            "regions": list(self.regions),
            "inv_kappa": self.inv_kappa.tolist(),
        }


def sample_poses(
    robot: RobotDescription,
    pmap: JointPlaneMap,
    regions,
    n: int,
    rng: np.random.Generator,
    select=None,
    constraints: PoseConstraints | None = None,
    wrist_jitter_deg: float = 0.0,
    threshold: float = 0.0,
    max_tries: int = 10000,
) -> PoseSet:
    """Draw ``n`` poses, the regions taking turns, uniform over each region's cells.

    theta_2, theta_3 are jittered within the cell; joints 4 and 5 are ``pmap.q_fixed`` plus a
    uniform jitter of +-``wrist_jitter_deg``. A pose is kept if it is inside the limits, meets
    ``constraints`` and has a criterion ``>= threshold``.
    """
    check_wrist(robot)
    if n < 1:
        raise OutOfRangeError(f"n = {n} poses is outside the valid range [1, inf)")
    by_name = {r.name: r for r in regions}
    names = [r.name for r in regions if r.excluded is None] if select is None else list(select)
    for name in names:
        if name not in by_name:
            raise UnknownNameError("region", name, by_name)
        if not by_name[name].mask.any():
            raise VtestbedError(f"region {name} has no usable cells ({by_name[name].excluded})")
    if not names:
        raise VtestbedError("no region to sample from: every region is excluded by the constraints")
    h2, h3 = (pmap.theta2[1] - pmap.theta2[0]) / 2, (pmap.theta3[1] - pmap.theta3[0]) / 2
    jitter = np.radians(wrist_jitter_deg)
    q_out, r_out, v_out = [], [], []
    tries = 0
    while len(q_out) < n:
        name = names[len(q_out) % len(names)]
        cells = np.flatnonzero(by_name[name].mask)
        i2, i3 = np.unravel_index(cells[rng.integers(cells.size)], pmap.values.shape)
        q = pmap.q_fixed.copy()
        q[1] = pmap.theta2[i2] + rng.uniform(-h2, h2)
        q[2] = pmap.theta3[i3] + rng.uniform(-h3, h3)
        q[3:5] += rng.uniform(-jitter, jitter, 2)
        tries += 1
        if tries > max_tries:
            raise VtestbedError(
                f"drew only {len(q_out)} of {n} poses in {max_tries} tries; relax the constraints"
            )
        if np.any(q < robot.lower) or np.any(q > robot.upper):
            continue
        if constraints is not None and not constraints.ok(robot, q)[0]:
            continue
        value = float(inv_kappa_batch(robot, q[None], pmap.point)[0])
        if value < threshold:
            continue
        q_out.append(q)
        r_out.append(name)
        v_out.append(value)
    return PoseSet(np.array(q_out), tuple(r_out), np.array(v_out))
