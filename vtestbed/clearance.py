"""Clearance of a test at its pose: links against the table and the floor, the wire, the scanner's view.

The geometry both sides share (numpy only, SI): simple convex shapes (capsules, cylinders, boxes;
a mesh target's block is a :class:`~vtestbed.target_geometry.Polytope`, its convex hull), their
distance to a segment, the scene's shapes as the truth world draws them, and the rules of
:doc:`docs/clearance.md <clearance>` (which pairs, which margins). The truth world measures the
same pairs with MuJoCo's own collision distance (:mod:`vtestbed.world.clearance`); the design tools
measure them on the nominal kinematics (:mod:`vtestbed.design.clearance`).

Distances are signed surface distances [m]: positive = a gap, negative = the shapes overlap by
that much. A pair fails when its distance is below its margin.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .convex_shapes import Box, Capsule, Cylinder, Plane, capsule_distance, segment_segment_distance
from .errors import ClearanceError, UnknownNameError
from .lab import DEFAULT_VIEW_DIRECTION, LabSetup
from .target_geometry import Polytope, hook_edges, hook_faces, mesh_polytope

LINK_MARGIN_M = 0.010  # links, sensor and block against the table top and the floor
WIRE_MARGIN_M = 0.005  # the wire against the links, the sensor and the block's edges
SIGHT_MARGIN_M = 0.005  # a sight line from the scanner to a scanned face against any obstacle
# Radii [m] of the link shells the truth world draws (world/mjcf.py imports them): link i is a
# capsule from DH frame i's origin to frame i+1's, the last one a sphere at the flange; the KR60-3's
# sizes, used for every robot (a robot.toml has no link radii yet).
LINK_RADII = (0.16, 0.11, 0.10, 0.075, 0.065, 0.05)
BASE_RADIUS_M, BASE_HEIGHT_M = 0.25, 0.30  # the base drum, standing on the floor
STEM_RADIUS_M = 0.015
TABLE_THICKNESS_M = 0.04
FACE_INSET = 0.1  # sight points sit this fraction of an edge inside a face's corners
SCANNED_FACES = ("+x", "+y", "+z")


class ClearanceWarning(UserWarning):
    """A scenario's test that fails the clearance check (scenario files are warned, not refused)."""


# ---------------------------------------------------------------------- the scene's shapes
def arm_shapes(frame_origins) -> list[Capsule]:
    """The link shells ``link1``..``link6`` from the DH frame origins (n, 3) [m] in the world."""
    o = np.asarray(frame_origins, dtype=float)
    ends = list(o[1:]) + [o[-1]]  # the last link is a sphere at its own origin
    return [Capsule(f"link{i + 1}", o[i], ends[i], r) for i, r in enumerate(LINK_RADII[: len(o)])]


def base_shape() -> Cylinder:
    return Cylinder("base", np.array([0.0, 0.0, BASE_HEIGHT_M / 2]), np.array([0.0, 0.0, 1.0]),
                    BASE_RADIUS_M, BASE_HEIGHT_M / 2)  # fmt: skip


def tool_shapes(flange_pose, lab: LabSetup) -> list:
    """Force sensor (mount and tool halves), stem and block at ``flange_pose`` (4, 4), as in world/mjcf.py."""
    f = np.asarray(flange_pose, dtype=float)
    rot, axis = f[:3, :3], f[:3, 2]
    sensor, block = lab.sensor, lab.block
    top = sensor.origin_in_flange[2]  # the sensor's tool face, on the flange axis

    def along(z0: float, z1: float, radius: float, name: str) -> Cylinder:
        return Cylinder(name, f[:3, 3] + axis * (z0 + z1) / 2, axis, radius, (z1 - z0) / 2)

    mount_top = sensor.adapter_thickness + sensor.height / 2
    block_origin = f @ lab.block_in_flange
    if block.mesh is None:
        solid = Box("block", block_origin[:3, 3] + rot @ np.full(3, -block.edge / 2), rot,
                    np.full(3, block.edge / 2))  # fmt: skip
    else:  # a mesh target: its convex hull, given in B (vtestbed.target_geometry)
        solid = mesh_polytope(block.mesh).moved(block_origin)
    return [
        along(0.0, mount_top, sensor.diameter / 2, "ft_mount"),
        along(top - sensor.height / 2, top, sensor.diameter / 2, "ft_sensor"),
        along(top, top + block.standoff, STEM_RADIUS_M, "stem"),
        solid,
    ]


def table_shape(lab: LabSetup) -> Box:
    t = lab.table
    center = np.array([t.center[0], t.center[1], t.height - TABLE_THICKNESS_M / 2])
    return Box(
        "table_top", center, np.eye(3), np.array([t.size[0] / 2, t.size[1] / 2, TABLE_THICKNESS_M / 2])
    )


def scanner_position(block_pose, edge: float, distance_m: float, view_direction_block=DEFAULT_VIEW_DIRECTION):
    """The scanner's optical centre [m] as :meth:`vtestbed.world.scanner.Scanner.place` puts it."""
    b = np.asarray(block_pose, dtype=float)
    view = np.asarray(view_direction_block, dtype=float)
    centre = b[:3, 3] + b[:3, :3] @ np.full(3, -edge / 2)
    return centre + distance_m * (b[:3, :3] @ (view / np.linalg.norm(view)))


def face_points(block_pose, edge: float) -> dict[str, np.ndarray]:
    """Sight targets on the scanned faces (+x, +y, +z of B): the centre and four inset corners, (5, 3)."""
    b = np.asarray(block_pose, dtype=float)
    lo, hi, mid = -edge * (1 - FACE_INSET), -edge * FACE_INSET, -edge / 2
    out = {}
    for axis, label in enumerate(SCANNED_FACES):
        others = [k for k in range(3) if k != axis]
        pts = np.zeros((5, 3))
        pts[:, others[0]] = (mid, lo, lo, hi, hi)
        pts[:, others[1]] = (mid, lo, hi, lo, hi)
        out[label] = b[:3, 3] + pts @ b[:3, :3].T
    return out


# ---------------------------------------------------------------------- results
@dataclass(frozen=True)
class Clearance:
    """One checked pair: its signed surface distance and margin [m]."""

    first: str
    second: str
    distance_m: float
    margin_m: float

    @property
    def ok(self) -> bool:
        return bool(self.distance_m >= self.margin_m)

    def describe(self) -> str:
        return (f"{self.first} vs {self.second}: {self.distance_m * 1e3:.1f} mm "
                f"(margin {self.margin_m * 1e3:g} mm)")  # fmt: skip


@dataclass(frozen=True)
class ClearanceReport:
    """Every checked pair of one test; ``failures`` are the pairs below their margin, closest first."""

    entries: tuple[Clearance, ...]

    @property
    def failures(self) -> tuple[Clearance, ...]:
        return tuple(sorted((e for e in self.entries if not e.ok), key=lambda e: e.distance_m - e.margin_m))

    @property
    def ok(self) -> bool:
        return not self.failures

    def worst(self) -> Clearance:
        """The pair with the least room over its margin."""
        return min(self.entries, key=lambda e: e.distance_m - e.margin_m)

    def message(self, label: str, limit: int = 4) -> str:
        bad = self.failures
        more = f"; and {len(bad) - limit} more" if len(bad) > limit else ""
        return f"{label} is not physically possible: " + "; ".join(e.describe() for e in bad[:limit]) + more

    def enforce(self, label: str, policy: str = "raise") -> None:
        """``policy`` "raise" (:class:`ClearanceError`), "warn" (:class:`ClearanceWarning`) or "off"."""
        if policy not in CLEARANCE_POLICIES:
            raise UnknownNameError("clearance policy", str(policy), CLEARANCE_POLICIES)
        if self.ok or policy == "off":
            return
        if policy == "raise":
            raise ClearanceError(self.message(label))
        warnings.warn(self.message(label), ClearanceWarning, stacklevel=3)


CLEARANCE_POLICIES = ("raise", "warn", "off")
# Link 1 turns about the vertical axis of the base it stands on: it cannot move towards the floor,
# and a robot whose first link starts at floor level (an imported UR10) would otherwise touch it
# at every pose.
FIXED_TO_FLOOR = {("link1", "floor")}


def pose_clearances(links: list, tool: list, table: Box, floor: Plane) -> list[Clearance]:
    """Links (capsules), sensor, stem and block against the table top and the floor."""
    p0, p1 = np.array([c.p0 for c in links]), np.array([c.p1 for c in links])
    radii = np.array([c.radius for c in links])
    out = []
    for ground in (table, floor):  # all links in one search
        dist = capsule_distance(p0, p1, radii, ground)
        out += [Clearance(c.name, ground.name, float(x), LINK_MARGIN_M) for c, x in zip(links, dist)
                if (c.name, ground.name) not in FIXED_TO_FLOOR]  # fmt: skip
    return out + [Clearance(part.name, ground.name, _solid_distance(part, ground), LINK_MARGIN_M)
                  for part in tool for ground in (table, floor)]  # fmt: skip


def _solid_distance(solid, ground) -> float:
    """Signed distance of a cylinder or box from the table top or the floor.

    The solid's vertices (a cylinder's rims as 72-gons, within r (1 - cos 2.5 deg) = 0.04 mm of
    the rim) in the ground's signed distance, and the ground's edges against the solid: together
    they hold every feature pair that can carry the closest points of two convex solids.
    """
    if isinstance(solid, Box):
        pts = solid.corners()
    elif isinstance(solid, Polytope):
        pts = solid.vertices
    else:
        ref = np.array([1.0, 0.0, 0.0]) if abs(solid.axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(solid.axis, ref)
        u /= np.linalg.norm(u)
        v = np.cross(solid.axis, u)
        ang = np.linspace(0.0, 2 * np.pi, 72, endpoint=False)
        ring = solid.radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
        pts = np.concatenate(
            [solid.center + sign * solid.half_height * solid.axis + ring for sign in (-1, 1)]
        )
    dist = float(ground.sdf(pts).min())
    if isinstance(ground, Box):
        a, b = ground.edges()
        dist = min(dist, float(capsule_distance(a, b, 0.0, solid).min()))
    return dist


def wire_clearances(hook_point, anchor, obstacles: list, block, wire_radius: float) -> list[Clearance]:
    """The wire (hook -> ring) against ``obstacles`` (links, base, sensor, stem) and the block.

    ``block`` is a :class:`Box` or a :class:`Polytope` (a mesh target's convex hull). Its edges
    count except the hook's seat (:func:`hook_edges`); edge distances are from the wire's surface
    to the edge. A wire that leaves the hook into the block adds a ``block (cuts into it)`` pair
    with its depth.
    """
    return wire_clearances_many(hook_point, np.asarray(anchor, dtype=float)[None], obstacles, block,
                                wire_radius)[0]  # fmt: skip


def wire_clearances_many(hook_point, anchors, obstacles: list, block, wire_radius: float):
    """:func:`wire_clearances` for one hook and (k, 3) ring points at once: k lists of pairs.

    The wire cuts into the (convex) block when it leaves the hook inside the tangent cone of the
    faces the hook lies on (pointing into every one of them); its depth is the block's least
    signed distance along the wire beyond 0.1 mm from the hook. A hook on no face (inside a
    non-convex target's hull) cuts in when that depth is negative.
    """
    anchors = np.asarray(anchors, dtype=float)
    hook = np.broadcast_to(np.asarray(hook_point, dtype=float), anchors.shape)
    dist = {s.name: capsule_distance(hook, anchors, wire_radius, s) for s in obstacles}
    a, b = block.edges()
    free = ~hook_edges(block, hook[0], WIRE_MARGIN_M + wire_radius)
    edge = segment_segment_distance(hook[:, None], anchors[:, None], a[free], b[free]).min(axis=1)
    u = (anchors - hook) / np.linalg.norm(anchors - hook, axis=1, keepdims=True)
    on = hook_faces(block, hook[0])
    if on.any():  # leaving outward, a wire never re-enters a convex body: the depth only if it cuts
        cuts = (u @ block.planes()[0][on].T).max(axis=1) < 0.0
        depth = np.zeros(len(anchors))
        depth[cuts] = capsule_distance(hook[cuts] + 1e-4 * u[cuts], anchors[cuts], 0.0, block)
        short = cuts & (depth >= 0.0)  # it leaves again within 0.1 mm (a hook by a vertex)
        depth[short] = capsule_distance(hook[short], anchors[short], 0.0, block)
    else:
        depth = capsule_distance(hook + 1e-4 * u, anchors, 0.0, block)
        cuts = depth < 0.0
    out = []
    for k in range(len(anchors)):
        entries = [Clearance("wire", name, float(x[k]), WIRE_MARGIN_M) for name, x in dist.items()]
        entries.append(Clearance("wire", "block edges", float(edge[k] - wire_radius), WIRE_MARGIN_M))
        if cuts[k]:
            entries.append(Clearance("wire", "block (cuts into it)", float(depth[k]), 0.0))
        out.append(entries)
    return out


def sight_clearances(scanner, targets: dict[str, np.ndarray], obstacles: list) -> list[Clearance]:
    """Sight lines from the scanner's optical centre ``scanner`` (3,) to each face's points against
    ``obstacles`` (one entry per face and obstacle: the closest of that face's sight lines)."""
    faces = list(targets)
    pts = np.stack([targets[f] for f in faces])  # (faces, points, 3): one search per obstacle
    start = np.broadcast_to(np.asarray(scanner, dtype=float), pts.shape)
    dist = {s.name: capsule_distance(start, pts, 0.0, s).min(axis=1) for s in obstacles}
    return [Clearance(f"scanner sight to face {face}", name, float(d[k]), SIGHT_MARGIN_M)
            for k, face in enumerate(faces) for name, d in dist.items()]  # fmt: skip
