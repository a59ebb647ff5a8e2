"""The target block as a convex polytope: face planes, feature edges, exact signed distance (numpy, SI).

The clearance check (:mod:`vtestbed.clearance`, docs/clearance.md) measures the wire against the
block's faces and edges. The plain box is a polytope of 6 planes and 12 edges; a mesh target
(:mod:`vtestbed.target_mesh`) is taken as the convex hull of its vertices: exact for a convex
target such as the shipped chamfered block (18 planes, 48 edges), and for a non-convex one the
smallest convex body that holds it (the same body MuJoCo's collision functions use for a mesh
geom), so a wire clear of the hull is clear of the target.

A face is a maximal set of coplanar hull triangles; a feature edge lies between two faces that
are not coplanar (the diagonals that triangulate a face are not edges). Planes are
``normals @ x <= offsets`` inside, unit outward normals, in the frame of the points given.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

COPLANAR_COS = 1.0 - 1e-9  # hull triangles whose normals agree this well form one face (4.5e-5 rad)
ON_SURFACE_TOL_M = 1e-6  # a hook this close to a face plane lies on that face
_ON_FACE_TOL_M = 1e-12  # a point projected onto a face plane counts as on the face within this


def point_segment_distance(points, p0, p1) -> np.ndarray:
    """Distance [m] of points (..., 3) from the segment ``p0 -> p1`` (broadcast)."""
    points, p0, p1 = (np.asarray(x, dtype=float) for x in (points, p0, p1))
    d = p1 - p0
    dd = np.sum(d * d, axis=-1)
    t = np.clip(np.sum((points - p0) * d, axis=-1) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(points - p0 - t[..., None] * d, axis=-1)


@dataclass(frozen=True, eq=False)
class Polytope:
    """A convex polytope: ``F`` face planes, ``E`` feature edges and ``V`` vertices [m].

    Attributes
    ----------
    name : str
        The clearance name (``"block"``).
    normals : (F, 3) array
        Unit outward face normals.
    offsets : (F,) array
        Plane offsets [m]: the body is ``normals @ x <= offsets``.
    edge_a, edge_b : (E, 3) arrays
        Start and end points of the feature edges [m].
    edge_faces : (E, 2) int array
        The two faces (rows of ``normals``) each edge bounds.
    vertices : (V, 3) array
        The corners [m].
    """

    name: str
    normals: np.ndarray
    offsets: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    edge_faces: np.ndarray
    vertices: np.ndarray

    @classmethod
    def from_points(cls, points, name: str = "block") -> Polytope:
        """The convex hull of ``points`` (N, 3) [m] (qhull), its coplanar triangles merged into faces."""
        from scipy.spatial import ConvexHull  # here: only mesh targets need it

        pts = np.asarray(points, dtype=float)
        hull = ConvexHull(pts)
        normals = hull.equations[:, :3] / np.linalg.norm(hull.equations[:, :3], axis=1, keepdims=True)
        label = np.arange(len(normals))  # union-find over coplanar neighbours

        def root(i: int) -> int:
            while label[i] != i:
                label[i] = label[label[i]]
                i = label[i]
            return i

        pairs = []  # (triangle, neighbour, shared edge's two vertex ids), each once
        for s, (tri, nbr) in enumerate(zip(hull.simplices, hull.neighbors)):
            for k in range(3):
                t = int(nbr[k])
                if s < t:
                    pairs.append((s, t, np.delete(tri, k)))
                    if normals[s] @ normals[t] > COPLANAR_COS:
                        label[root(s)] = root(t)
        roots = np.array([root(i) for i in range(len(normals))])
        faces, face_of = np.unique(roots, return_inverse=True)
        face_normals = np.array([normals[face_of == f].mean(axis=0) for f in range(len(faces))])
        face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
        corners = pts[hull.vertices]
        offsets = (corners @ face_normals.T).max(axis=0)  # the outermost vertex on each plane
        edges = [(ids, face_of[s], face_of[t]) for s, t, ids in pairs if face_of[s] != face_of[t]]
        return cls(
            name=name,
            normals=face_normals,
            offsets=offsets,
            edge_a=pts[[ids[0] for ids, _, _ in edges]],
            edge_b=pts[[ids[1] for ids, _, _ in edges]],
            edge_faces=np.array([(f, g) for _, f, g in edges], dtype=np.int64),
            vertices=corners,
        )

    def moved(self, pose, name: str | None = None) -> Polytope:
        """The polytope given in a frame, moved by that frame's pose (4, 4) [m]."""
        pose = np.asarray(pose, dtype=float)
        rot, pos = pose[:3, :3], pose[:3, 3]
        normals = self.normals @ rot.T
        return Polytope(
            name=self.name if name is None else name,
            normals=normals,
            offsets=self.offsets + normals @ pos,
            edge_a=self.edge_a @ rot.T + pos,
            edge_b=self.edge_b @ rot.T + pos,
            edge_faces=self.edge_faces,
            vertices=self.vertices @ rot.T + pos,
        )

    def planes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit outward normals (F, 3) and offsets (F,) [m]."""
        return self.normals, self.offsets

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The feature edges as (E, 3) start and end points [m]."""
        return self.edge_a, self.edge_b

    def sdf(self, points) -> np.ndarray:
        """Exact signed distance [m] of points (..., 3) from the surface (outside > 0).

        Inside, the distance to the nearest face plane. Outside, the nearest of the feature edges
        and of the face planes whose foot point lies on the face (satisfies every other plane):
        the closest point of a convex polytope is inside a face, on an edge or at a vertex.
        """
        x = np.asarray(points, dtype=float)
        s = x @ self.normals.T - self.offsets  # (..., F)
        inside = s.max(axis=-1)
        if np.all(inside <= 0.0):
            return inside
        foot = x[..., None, :] - s[..., None] * self.normals  # (..., F, 3): onto each plane
        on_face = np.all(foot @ self.normals.T - self.offsets <= _ON_FACE_TOL_M, axis=-1)
        face = np.where(on_face & (s > 0), s, np.inf).min(axis=-1)
        edge = point_segment_distance(x[..., None, :], self.edge_a, self.edge_b).min(axis=-1)
        return np.where(inside <= 0.0, inside, np.minimum(face, edge))


@lru_cache(maxsize=8)
def mesh_polytope(mesh) -> Polytope:
    """A :class:`~vtestbed.target_mesh.MeshTarget`'s convex hull in its block frame B (cached)."""
    return Polytope.from_points(mesh.vertices, "block")


def hook_faces(block, hook_point) -> np.ndarray:
    """(F,) bool: the faces of ``block`` (a clearance ``Box`` or a :class:`Polytope`) the hook lies on."""
    normals, offsets = block.planes()
    return np.abs(normals @ np.asarray(hook_point, dtype=float) - offsets) < ON_SURFACE_TOL_M


def hook_edges(block, hook_point, reach: float) -> np.ndarray:
    """(E,) bool: the edges of the hook's seat, which the wire's edge check leaves out.

    They are the edges of the faces the hook lies on that come closer to it than ``reach`` [m]
    (the wire's margin plus its radius): no wire leaving the hook can pass them by that much, and
    one leaving outward never touches them (the block is convex). On the plain box: the edge
    through ``hook_edge``; on the chamfered block: the two long edges of the chamfer ``hook_edge``
    sits on, 3.54 mm from it. Edges farther away (a face hook's own face edges, 40 mm off) are
    checked: a wire leaving its face at a grazing angle passes close to them.
    """
    a, b = block.edges()
    hook = np.asarray(hook_point, dtype=float)
    near = point_segment_distance(hook, a, b) < reach
    return near & hook_faces(block, hook)[block.edge_faces].any(axis=1)
