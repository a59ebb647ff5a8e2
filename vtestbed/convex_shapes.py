"""Convex shapes and their distances, for the clearance checks (:mod:`vtestbed.clearance`).

Numpy only, SI: capsules, cylinders, boxes and the floor's half-space, each with a signed distance
function ``sdf(points)`` [m] (positive outside), and the distance of a capsule (a segment swept by
a ball) to any of them. Signed surface distances: positive = a gap, negative = an overlap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .target_geometry import point_segment_distance

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
_CORNER_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
_EDGE_PAIRS = [(i, j) for i in range(8) for j in range(i + 1, 8)
               if np.sum(_CORNER_SIGNS[i] != _CORNER_SIGNS[j]) == 1]  # fmt: skip
# the box's face k (+x, +y, +z) or 3 + k (-x, -y, -z) for the two axes an edge's corners share
_EDGE_FACES = np.array([[k if _CORNER_SIGNS[i, k] > 0 else 3 + k for k in range(3)
                         if _CORNER_SIGNS[i, k] == _CORNER_SIGNS[j, k]] for i, j in _EDGE_PAIRS])  # fmt: skip


@dataclass(frozen=True)
class Capsule:
    """A segment ``p0 -> p1`` [m] swept by a ball of ``radius`` [m] (a sphere when p0 = p1)."""

    name: str
    p0: np.ndarray
    p1: np.ndarray
    radius: float

    def sdf(self, points: np.ndarray) -> np.ndarray:
        return point_segment_distance(points, self.p0, self.p1) - self.radius


@dataclass(frozen=True)
class Cylinder:
    """A solid cylinder: ``center`` [m], unit ``axis``, ``radius`` and ``half_height`` [m]."""

    name: str
    center: np.ndarray
    axis: np.ndarray
    radius: float
    half_height: float

    def sdf(self, points: np.ndarray) -> np.ndarray:
        rel = np.asarray(points, dtype=float) - self.center
        h = rel @ self.axis
        rho = np.linalg.norm(rel - h[..., None] * self.axis, axis=-1)
        dx, dz = rho - self.radius, np.abs(h) - self.half_height
        return np.minimum(np.maximum(dx, dz), 0.0) + np.hypot(np.maximum(dx, 0.0), np.maximum(dz, 0.0))


@dataclass(frozen=True)
class Box:
    """A solid box: ``center`` [m], ``rotation`` (3, 3) (columns = box axes), ``half`` sizes [m]."""

    name: str
    center: np.ndarray
    rotation: np.ndarray
    half: np.ndarray

    def sdf(self, points: np.ndarray) -> np.ndarray:
        q = np.abs((np.asarray(points, dtype=float) - self.center) @ self.rotation) - self.half
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    def corners(self) -> np.ndarray:
        """The 8 corners (8, 3) [m]."""
        return self.center + (_CORNER_SIGNS * self.half) @ self.rotation.T

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The 12 edges as (12, 3) start and end points [m]."""
        corners = self.corners()
        return corners[[i for i, _ in _EDGE_PAIRS]], corners[[j for _, j in _EDGE_PAIRS]]

    def planes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit outward normals (6, 3) (+x, +y, +z, -x, -y, -z of the box) and offsets (6,) [m]."""
        normals = np.concatenate([self.rotation.T, -self.rotation.T])
        return normals, normals @ self.center + np.tile(self.half, 2)

    @property
    def edge_faces(self) -> np.ndarray:
        """(12, 2): the two faces (rows of :meth:`planes`) each edge of :meth:`edges` bounds."""
        return _EDGE_FACES


@dataclass(frozen=True)
class Plane:
    """The half-space below ``height`` [m] (the floor)."""

    name: str
    height: float = 0.0

    def sdf(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=float)[..., 2] - self.height


def segment_segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Shortest distance [m] between segments ``p0 -> p1`` and ``q0 -> q1`` (broadcast over ``...``).

    Closed form (Ericson, *Real-Time Collision Detection*, 5.1.9), degenerate segments included.
    """
    p0, p1, q0, q1 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (p0, p1, q0, q1)))
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e = np.sum(d1 * d1, -1), np.sum(d2 * d2, -1)
    b, c, f = np.sum(d1 * d2, -1), np.sum(d1 * r, -1), np.sum(d2 * r, -1)
    eps = 1e-24
    safe_a, safe_e = np.where(a > eps, a, 1.0), np.where(e > eps, e, 1.0)
    denom = a * e - b * b
    # parallel (or degenerate) segments: any s works, take 0
    s = np.where(
        denom > 1e-12 * np.maximum(a * e, eps), (b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0
    )
    s = np.clip(s, 0.0, 1.0)
    t = (b * s + f) / safe_e
    s = np.where(
        t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s)
    )
    t = np.clip(t, 0.0, 1.0)
    # p degenerate: s = 0, t from f; q degenerate: t = 0, s from c
    s = np.where(a <= eps, 0.0, np.where(e <= eps, np.clip(-c / safe_a, 0.0, 1.0), s))
    t = np.where(a <= eps, np.clip(f / safe_e, 0.0, 1.0), np.where(e <= eps, 0.0, t))
    return np.linalg.norm(p0 + s[..., None] * d1 - q0 - t[..., None] * d2, axis=-1)


def capsule_distance(p0, p1, radius, shape, grid: int = 33, iterations: int = 24) -> np.ndarray:
    """Signed surface distance [m] between capsules ``p0 -> p1`` (broadcast, (..., 3)) and ``shape``.

    A capsule or a plane is closed form. For the others ``t -> shape.sdf(p0 + t (p1 - p0))`` is
    convex (the signed distance of a convex set is convex): its minimum lies within one grid step
    of the best of ``grid`` samples, and a golden-section search there narrows it to
    ``2 / (grid - 1) * 0.618^iterations`` of the segment (1e-6 by default: a micrometre on a metre).
    """
    p0, p1 = np.broadcast_arrays(np.asarray(p0, dtype=float), np.asarray(p1, dtype=float))
    if isinstance(shape, Capsule):
        return segment_segment_distance(p0, p1, shape.p0, shape.p1) - shape.radius - radius
    if isinstance(shape, Plane):  # linear along the segment: an end is nearest
        return np.minimum(shape.sdf(p0), shape.sdf(p1)) - radius
    d = p1 - p0
    ts = np.linspace(0.0, 1.0, grid)
    samples = shape.sdf(p0[..., None, :] + ts[:, None] * d[..., None, :])
    best = np.argmin(samples, axis=-1)
    lo, hi = ts[np.maximum(best - 1, 0)], ts[np.minimum(best + 1, grid - 1)]
    x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    f1, f2 = shape.sdf(p0 + x1[..., None] * d), shape.sdf(p0 + x2[..., None] * d)
    for _ in range(iterations):
        left = f1 <= f2  # the minimum is in [lo, x2]
        hi, lo = np.where(left, x2, hi), np.where(left, lo, x1)
        x2, x1 = np.where(left, x1, lo + _GOLDEN * (hi - lo)), np.where(left, hi - _GOLDEN * (hi - lo), x2)
        fm = shape.sdf(p0 + np.where(left, x1, x2)[..., None] * d)
        f2, f1 = np.where(left, f1, fm), np.where(left, fm, f2)
    return np.minimum(np.minimum(f1, f2), samples.min(axis=-1)) - radius
