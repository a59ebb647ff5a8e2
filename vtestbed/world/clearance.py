"""Clearance of a test in the truth world, at its loaded equilibrium (rules: :mod:`vtestbed.clearance`).

The scene runs without contacts (a statics rig), so nothing stops a link from sinking into the
table or the wire from running through a link: this module measures it. Solid pairs (links,
sensor, stem and block against the table top and the floor; the wire's stand-in capsule against
the base, the links, the sensor and the stem) use MuJoCo's own collision distance
(``mj_geomDistance``) on the scene's geoms; the wire against the block's edges and the scanner's
sight lines use the shared segment geometry on shapes read from the same geoms, so they follow
the true (sagged, possibly offset) poses; a mesh target is the convex hull of the mesh geom's
vertices (:mod:`vtestbed.target_geometry`).
"""

from __future__ import annotations

from functools import lru_cache

import mujoco
import numpy as np

from ..clearance import (
    FIXED_TO_FLOOR,
    LINK_MARGIN_M,
    WIRE_MARGIN_M,
    Clearance,
    ClearanceReport,
    face_points,
    sight_clearances,
    wire_clearances,
)
from ..convex_shapes import Box, Capsule, Cylinder
from ..target_geometry import Polytope
from . import mjcf
from .rig import Rig
from .rig_state import RigState

_DISTMAX = 10.0  # m: mj_geomDistance reports at most this; every pair of the scene is closer


def scene_geoms(model: mujoco.MjModel) -> dict[str, int]:
    """Geom ids by clearance name: base, link1..link6, ft_mount, ft_sensor, stem, block, table_top,
    floor, wire (the scene's link and tool geoms are unnamed; their bodies and sizes tell them apart)."""
    out = {"table_top": model.geom("table_top").id, "floor": model.geom("floor").id,
           "wire": model.geom("wire_geom").id, "block": model.geom("target_block").id}  # fmt: skip
    tool = []
    for g in range(model.ngeom):
        if model.geom_group[g] != mjcf.SCANNABLE_GROUP or model.geom(g).name:
            continue
        body = model.body(model.geom_bodyid[g]).name
        if body == mjcf.TOOL_BODY:
            tool.append(g)
        elif body in ("base", "ft_mount") or body.startswith("link"):
            out[body] = g
    tool.sort(key=lambda g: model.geom_size[g, 0])  # the thin stem, then the sensor's tool half
    out.update(zip(("stem", "ft_sensor"), tool))
    return out


def geom_shape(model: mujoco.MjModel, data: mujoco.MjData, geom: int, name: str):
    """The shared-geometry shape of a capsule, sphere, cylinder, box or mesh geom at its current pose.

    A mesh is the convex hull of MuJoCo's own (float32) vertices, the body its collision
    functions (``mj_geomDistance``) use: a :class:`~vtestbed.target_geometry.Polytope`.
    """
    pos, rot, size = (
        data.geom_xpos[geom].copy(),
        data.geom_xmat[geom].reshape(3, 3).copy(),
        model.geom_size[geom],
    )
    kind = model.geom_type[geom]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return Capsule(name, pos - size[1] * rot[:, 2], pos + size[1] * rot[:, 2], float(size[0]))
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return Capsule(name, pos, pos, float(size[0]))
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return Cylinder(name, pos, rot[:, 2], float(size[0]), float(size[1]))
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return Box(name, pos, rot, size[:3].copy())
    if kind == mujoco.mjtGeom.mjGEOM_MESH:  # a mesh target: its convex hull (docs/clearance.md)
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        local = _hull(model.mesh_vert[start : start + count].astype(float).tobytes())
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot, pos
        return local.moved(pose, name)
    raise ValueError(f"geom {name!r}: type {kind} has no clearance shape")  # the scene has none


@lru_cache(maxsize=8)
def _hull(vertices: bytes) -> Polytope:
    """The convex hull of a mesh's vertices (float64 bytes, the geom's frame), cached per mesh."""
    return Polytope.from_points(np.frombuffer(vertices).reshape(-1, 3))


def geom_distance(model: mujoco.MjModel, data: mujoco.MjData, g1: int, g2: int) -> float:
    """MuJoCo's signed distance [m] between two geoms (negative: penetration depth)."""
    return float(mujoco.mj_geomDistance(model, data, g1, g2, _DISTMAX, None))


TOOL_GEOMS = ("ft_mount", "ft_sensor", "stem")


def _links(rig: Rig, ids: dict) -> list[str]:
    return [f"link{i + 1}" for i in range(rig.robot.dof) if f"link{i + 1}" in ids]


def ground_clearance(rig: Rig) -> ClearanceReport:
    """The arm's links, the sensor, its stem and the block against the table top and the floor, at
    the kinematics MuJoCo's data holds (a state just solved or tightened): the part of
    :func:`truth_clearance` that needs no wire and no scanner (``vtestbed load``)."""
    m, d = rig.model, rig.data
    ids = scene_geoms(m)
    return ClearanceReport(tuple(
        Clearance(part, ground, geom_distance(m, d, ids[part], ids[ground]), LINK_MARGIN_M)
        for part in [*_links(rig, ids), *TOOL_GEOMS, "block"] for ground in ("table_top", "floor")
        if (part, ground) not in FIXED_TO_FLOOR
    ))  # fmt: skip


def truth_clearance(rig: Rig, state: RigState, scanner_position) -> ClearanceReport:
    """Every clearance pair of the test in ``rig`` at ``state`` (the loaded equilibrium, wire placed).

    ``scanner_position`` (3,) [m] is the scanner's optical centre (``Scanner.pose_world[:3, 3]``).
    MuJoCo's data must hold ``state``'s kinematics, as it does right after :meth:`Rig.tighten`
    (or a scan of that state).
    """
    m, d = rig.model, rig.data
    ids = scene_geoms(m)
    links, tool = _links(rig, ids), list(TOOL_GEOMS)
    out = list(ground_clearance(rig).entries)
    out += [Clearance("wire", part, geom_distance(m, d, ids["wire"], ids[part]), WIRE_MARGIN_M)
            for part in ["base"] + links + tool]  # fmt: skip
    block = geom_shape(m, d, ids["block"], "block")
    anchor = d.site(mjcf.WIRE_ANCHOR_SITE).xpos.copy()
    wire_radius = rig.lab.wire.diameter / 2
    # obstacles=[]: the solids are measured by MuJoCo above; the edges and the block here
    out += wire_clearances(state.hook_position, anchor, [], block, wire_radius)
    obstacles = [geom_shape(m, d, ids[n], n) for n in links + tool + ["wire"]]
    targets = face_points(state.block_pose, rig.lab.block.edge)
    out += sight_clearances(np.asarray(scanner_position, dtype=float), targets, obstacles)
    return ClearanceReport(tuple(out))


def describe_test(q, hook: str, anchor: str) -> str:
    """A test's name when the caller gives none: its DH pose [deg], hook and ring."""
    return f"test at q = {np.round(np.degrees(q), 2).tolist()} deg (DH), {hook} -> {anchor}"
