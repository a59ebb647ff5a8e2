"""Clearance on a mesh target (docs/clearance.md): the block as a convex polytope.

References: the plain box's closed forms (the polytope path gives the Box path's numbers), the
exact distance to the mesh's triangles (trimesh) and the chamfered block's 18 closed-form planes,
MuJoCo's ``mj_geomDistance`` between a capsule and the mesh geom, and the paper's chamfered
scenario simulated in the truth world.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings

import mujoco
import numpy as np
import pytest
import trimesh

from vtestbed import clearance as cl
from vtestbed import convex_shapes as shapes
from vtestbed import target_mesh as tm
from vtestbed.design.clearance import NominalClearance
from vtestbed.errors import ClearanceError
from vtestbed.lab import PAPER_LAB
from vtestbed.scenario import load_scenario
from vtestbed.target_geometry import Polytope, hook_edges, mesh_polytope, point_segment_distance
from vtestbed.world.clearance import geom_shape, scene_geoms, truth_clearance
from vtestbed.world.physics import run_test_physics
from vtestbed.world.rig import Rig
from vtestbed.world.scanner import Scanner

E, C = 0.08, 0.005  # the shipped block: edge and chamfer [m]
CHAMFERED = "scenarios/kr60_chamfered.toml"
HOOK_EDGE_B = np.array([-E + C / 2, -E + C / 2, -E / 2])  # the middle of the -x/-y chamfer


@pytest.fixture(scope="module")
def target():
    return tm.load_mesh_target(tm.CHAMFERED_BLOCK, "mm")


@pytest.fixture(scope="module")
def chamfered():
    return load_scenario(CHAMFERED)


def _box_polytope(box: shapes.Box) -> Polytope:
    signs = np.array(list(itertools.product((-1, 1), repeat=3)), dtype=float)
    return Polytope.from_points(box.center + (signs * box.half) @ box.rotation.T)


def _closed_form_planes(points_b: np.ndarray) -> np.ndarray:
    """The largest signed distance [m] of points (N, 3) in B from the chamfered block's 6 face and
    12 chamfer planes: negative exactly inside (the block is their intersection)."""
    d = np.concatenate([-points_b, E + points_b], axis=1)  # inside each face: near x, y, z; far x, y, z
    planes = [-d]
    for i, j in itertools.combinations(range(3), 2):
        for si, sj in itertools.product((0, 3), repeat=2):
            planes.append(((C - d[:, i + si] - d[:, j + sj]) / np.sqrt(2))[:, None])
    return np.concatenate(planes, axis=1).max(axis=1)


# ------------------------------------------------------------------ the plain box: one path for both
def test_box_as_a_polytope_gives_the_box_numbers():
    """6 planes, 12 edges; the same signed distance and wire clearances as the Box to 1e-12."""
    rng = np.random.default_rng(4)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    box = shapes.Box("block", np.array([0.3, -0.2, 1.1]), rot, np.array([0.04, 0.04, 0.04]))
    poly = _box_polytope(box)
    assert (len(poly.normals), len(poly.edge_a), len(poly.vertices)) == (6, 12, 8)
    probe = box.center + rng.uniform(-0.1, 0.1, (2000, 3))
    np.testing.assert_allclose(poly.sdf(probe), box.sdf(probe), rtol=0, atol=1e-12)
    hooks_b = tm.box_hooks([0.08] * 3)  # in B: the box is [-edge, 0]^3 about its corner
    corner = box.center + rot @ box.half
    anchors = box.center + rng.normal(size=(300, 3)) * 0.5
    compared = 0
    for hook_b in hooks_b.values():
        hook = corner + rot @ np.array(hook_b)
        assert hook_edges(box, hook, 0.006).sum() == hook_edges(poly, hook, 0.006).sum() <= 1
        for old, new in zip(*(cl.wire_clearances_many(hook, anchors, [], s, 0.001) for s in (box, poly))):
            assert [e.second for e in old] == [e.second for e in new]
            for a, b in zip(old, new):
                assert a.distance_m == pytest.approx(b.distance_m, abs=1e-12)
                compared += 1
    assert compared > 1000


def test_paper_tests_nominal_box_and_polytope_agree():
    """The wave-1 list's 20 tests (tests/test_clearance.py's verdicts): the same pairs, to 1e-12."""
    paper = load_scenario("tests/data/kr60_paper_unclear.toml")
    nc = NominalClearance(paper.robot, paper.lab)
    for i, q in enumerate(paper.poses):
        box = nc.check(q, paper.load.hooks[i], paper.load.anchors[i])
        nc.block = _box_polytope(nc.block)  # the block the wire is checked against
        poly = nc.check_many(q, paper.load.hooks[i], [paper.load.anchors[i]])[0]
        nc._pose_key = None
        assert [(e.first, e.second) for e in box.entries] == [(e.first, e.second) for e in poly.entries]
        for a, b in zip(box.entries, poly.entries):
            assert a.distance_m == pytest.approx(b.distance_m, abs=1e-12), (i, a.second)


# ------------------------------------------------------------------ the chamfered block's polytope
def test_chamfered_polytope_is_the_mesh(target):
    poly = mesh_polytope(target)
    assert (len(poly.normals), len(poly.edge_a), len(poly.vertices)) == (18, 48, 32)  # V - E + F = 2
    # every face normal is an axis (6) or a chamfer's (+-1, +-1, 0) / sqrt 2 (12)
    axes = np.sum(np.abs(poly.normals) > 0.5, axis=1)
    assert sorted(np.bincount(axes)[1:].tolist()) == [6, 12]
    # the probe points' exact distance to the 60 triangles (trimesh), signed by the closed-form planes
    rng = np.random.default_rng(9)
    probe = rng.uniform(-E - 0.02, 0.02, (600, 3))
    tri = np.repeat(target.vertices[target.faces][None], len(probe), axis=0).reshape(-1, 3, 3)
    foot = trimesh.triangles.closest_point(tri, np.repeat(probe, len(target.faces), axis=0))
    unsigned = np.linalg.norm(foot - np.repeat(probe, len(target.faces), axis=0), axis=1)
    reference = unsigned.reshape(len(probe), -1).min(axis=1) * np.sign(_closed_form_planes(probe))
    np.testing.assert_allclose(poly.sdf(probe), reference, rtol=0, atol=1e-12)
    assert np.sum(reference > 0) > 100 and np.sum(reference < 0) > 100


def _capsule_and_mesh_model(target):
    spec = mujoco.MjSpec()
    spec.worldbody.add_body(name="cap", mocap=True).add_geom(
        name="cap", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.004, 0.05, 0]
    )
    mesh = spec.add_mesh(name="blk")
    mesh.uservert = (target.vertices + E / 2).ravel().tolist()
    mesh.userface = target.faces.ravel().tolist()
    spec.worldbody.add_body(name="blk", mocap=True).add_geom(
        name="blk", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="blk"
    )
    model = spec.compile()
    return model, mujoco.MjData(model)


def test_capsule_to_mesh_distance_matches_mujoco(target):
    """The shared capsule distance on the mesh geom's hull against mj_geomDistance, 300 placements."""
    m, d = _capsule_and_mesh_model(target)
    cap, blk = m.geom("cap").id, m.geom("blk").id
    rng = np.random.default_rng(5)
    compared = overlapping = 0
    for _ in range(300):
        for name in ("cap", "blk"):
            body = m.body(name).mocapid[0]
            d.mocap_pos[body] = rng.uniform(-0.07, 0.07, 3) if name == "cap" else 0.0
            quat = rng.normal(size=4)
            d.mocap_quat[body] = quat / np.linalg.norm(quat)
        mujoco.mj_forward(m, d)
        c, poly = geom_shape(m, d, cap, "cap"), geom_shape(m, d, blk, "block")
        ref = mujoco.mj_geomDistance(m, d, cap, blk, 1.0, None)
        mine = float(shapes.capsule_distance(c.p0, c.p1, c.radius, poly))
        if ref > 0:
            assert mine == pytest.approx(ref, abs=2e-8)  # measured: 2.6e-9 m (float32 vertices)
            compared += 1
        else:
            assert mine < 1e-9
            overlapping += 1
    assert compared > 100 and overlapping > 100


def test_truth_and_nominal_block_shapes_agree(chamfered):
    """The hull of MuJoCo's float32 mesh vertices (truth) and of the target's (nominal): gravity off."""
    rig = Rig(chamfered.robot, chamfered.lab, gravity=False)
    q = chamfered.poses[1]
    rig.command(q)
    rig.solve()
    truth = geom_shape(rig.model, rig.data, scene_geoms(rig.model)["block"], "block")
    nc = NominalClearance(chamfered.robot, chamfered.lab)
    nc._at(q)
    probe = nc.block.vertices.mean(axis=0) + np.random.default_rng(0).uniform(-0.1, 0.1, (500, 3))
    np.testing.assert_allclose(truth.sdf(probe), nc.block.sdf(probe), rtol=0, atol=1e-7)


# ------------------------------------------------------------------ the wire on the chamfer
def test_hook_edge_on_the_chamfer_seat_and_cuts(target):
    poly = mesh_polytope(target)
    hook = np.array(target.hooks["hook_edge"])
    np.testing.assert_allclose(hook, HOOK_EDGE_B, atol=1e-12)
    seat = hook_edges(poly, hook, cl.WIRE_MARGIN_M + 0.001)
    np.testing.assert_allclose(  # the chamfer's two long edges, 3.54 mm from the hook
        point_segment_distance(hook, poly.edge_a[seat], poly.edge_b[seat]),
        [C / np.sqrt(2)] * 2,
        atol=1e-12,
    )
    # into the block through its centre: 40 mm deep (the centre's distance to every face)
    (*_, cut) = cl.wire_clearances(hook, hook + 0.5 * np.array([1.0, 1.0, 0.0]), [], poly, 0.001)
    assert cut.second == "block (cuts into it)" and cut.distance_m == pytest.approx(-E / 2, abs=1e-6)
    # random directions: "cuts into it" exactly when the wire's points lie inside the closed-form planes
    rng = np.random.default_rng(2)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u = u[np.abs(u @ [-1.0, -1.0, 0.0]) > 0.02]  # not sliding along the chamfer
    entries = cl.wire_clearances_many(hook, hook + 0.3 * u, [], poly, 0.001)
    s = np.linspace(1e-5, 0.3, 30001)  # 1e-5 m apart: the planes' maximum moves at most that much
    for k, pairs in enumerate(entries):
        inside = _closed_form_planes(hook + s[:, None] * u[k]).min()
        cuts = [e.distance_m for e in pairs if e.second == "block (cuts into it)"]
        assert bool(cuts) == (inside < 0), k
        if cuts:
            assert cuts[0] == pytest.approx(inside, abs=1e-5)


def test_chamfered_scenario_hook_edge_tests_are_clear_when_simulated(chamfered):
    """The six hook_edge tests warned "cuts into it -2.4 mm" on the bounding box; now none warns."""
    rig = Rig(chamfered.robot, chamfered.lab)
    edge_tests = [i for i, h in enumerate(chamfered.load.hooks) if h == "hook_edge"]
    assert edge_tests == [1, 2, 5, 8, 14, 19]
    for i in edge_tests:
        with warnings.catch_warnings():
            warnings.simplefilter("error", cl.ClearanceWarning)
            phys = run_test_physics(rig, chamfered.poses[i], "hook_edge", chamfered.load.anchors[i], 200.0, 0.6,
                                    label=f"poses.angles_deg[{i}]")  # fmt: skip
        gap = {e.second: e.distance_m for e in phys.clearance.entries if e.first == "wire"}
        assert "block (cuts into it)" not in gap and gap["block edges"] > 0.025, i


def test_chamfered_scenario_truth_and_nominal(chamfered):
    """All 20 tests: truth = nominal within 3 mm, and all clear; kr60_paper's ring for test 13 is not.

    Test 13 with kr60_paper's ring_5 (hook_y) leaves the -y face 9 deg off its plane and passes the flat face's +x
    border 4.8 mm off: 5.7 mm on the plain box, whose edge lies 5 mm farther from the hook.
    """
    rig = Rig(chamfered.robot, chamfered.lab)
    nc = NominalClearance(chamfered.robot, chamfered.lab)
    unclear = {}
    for i, q in enumerate(chamfered.poses):
        hook, ring = chamfered.load.hooks[i], chamfered.load.anchors[i]
        rig.command(q)
        rig.hook(hook, ring)
        scanner = Scanner.place(chamfered.lab, rig.solve().block_pose, distance_m=0.6)
        t = truth_clearance(rig, rig.tighten(200.0), scanner.pose_world[:3, 3])
        n = nc.check(q, hook, ring)
        assert t.ok == n.ok, i
        tn = {(e.first, e.second): e.distance_m for e in n.entries}
        for e in t.entries:
            if e.distance_m < 0.3 and (e.first, e.second) in tn:
                assert tn[(e.first, e.second)] == pytest.approx(e.distance_m, abs=3e-3), (i, e.second)
        if not t.ok:
            unclear[i] = t.failures
    assert not unclear, "docs/clearance.md's table of kr60_chamfered's verdicts (update both)"
    # with kr60_paper's ring_5, test 13's wire passes the flat -y face's border 4.8 mm off (margin 5)
    hook, q = chamfered.load.hooks[13], chamfered.poses[13]
    (only,) = nc.check(q, hook, "ring_5").failures
    assert only.second == "block edges" and only.distance_m == pytest.approx(0.0048, abs=2e-4)


def test_a_wire_into_the_mesh_block_is_refused(chamfered):
    """Pose 13 with hook_x and ring_5: the wire runs through the chamfered block (33 mm deep)."""
    q = chamfered.poses[13]
    report = NominalClearance(chamfered.robot, chamfered.lab).check(q, "hook_x", "ring_5")
    (cut,) = [e for e in report.failures if e.second == "block (cuts into it)"]
    assert cut.distance_m < -0.02
    with pytest.raises(ClearanceError, match=r"wire vs block \(cuts into it\): -3\d\.\d mm"):
        run_test_physics(
            Rig(chamfered.robot, chamfered.lab), q, "hook_x", "ring_5", 200.0, 0.6, clearance="raise"
        )


def test_a_non_convex_target_is_taken_as_its_convex_hull(target):
    """An L-shaped block (a cube with a notch): the polytope is the hull of its corners (qhull
    against scipy's Delaunay), and a hook on the notch's floor, inside the hull, cuts in."""
    from scipy.spatial import Delaunay

    cube = np.array(list(itertools.product((0.0, E), repeat=3)))
    notch = np.array(list(itertools.product((E / 2, E), (E / 2, E), (E / 2, E))))
    corners = np.concatenate([cube, notch])
    corners = corners[np.any(corners < 3 * E / 4, axis=1)]  # bar the cut-off corner (E, E, E)
    poly = Polytope.from_points(corners)
    assert len(poly.vertices) == 7 + 3  # the cube's corners bar the cut one, the notch's outer three
    probe = np.random.default_rng(1).uniform(-0.01, E + 0.01, (2000, 3))
    inside = Delaunay(corners).find_simplex(probe) >= 0
    assert np.array_equal(poly.sdf(probe) <= 0, inside)
    hook = np.array([0.75 * E, 0.75 * E, E / 2])  # the notch's floor, inside the hull
    assert poly.sdf(hook) < -0.005
    pairs = cl.wire_clearances(hook, hook + [0.0, 0.0, 1.0], [], poly, 0.001)
    assert any(e.second == "block (cuts into it)" and e.distance_m < 0 for e in pairs)
    lab = dataclasses.replace(
        PAPER_LAB, block=dataclasses.replace(PAPER_LAB.block, mesh=target, edge=target.edge)
    )
    assert isinstance(cl.tool_shapes(np.eye(4), lab)[-1], Polytope)
