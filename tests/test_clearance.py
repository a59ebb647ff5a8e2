"""Clearance (docs/clearance.md): shared distances against MuJoCo's and closed forms, the paper's 20 tests."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
from scipy.optimize import minimize

from vtestbed import clearance as cl
from vtestbed import convex_shapes as shapes
from vtestbed.campaigns.posesets import FeasibilityChecker
from vtestbed.design import optimal as design
from vtestbed.design.clearance import NominalClearance
from vtestbed.errors import UnknownNameError
from vtestbed.scenario import load_scenario
from vtestbed.world.clearance import scene_geoms, truth_clearance
from vtestbed.world.physics import run_test_physics
from vtestbed.world.rig import Rig
from vtestbed.world.scanner import Scanner

PAPER = "tests/data/kr60_paper_unclear.toml"
# Measured with this module (truth world and nominal model agree): 0-based indices of the paper
# scenario's tests that fail. 7, 9, 13, 15, 19 put link 2/3 into the table (Z4, elbow below the
# table top), 7, 9, 15, 19 also run the wire through link 2 or 3; 4 and 10 pass the block's edge
# closer than 5 mm.
PAPER_UNCLEAR = (4, 7, 9, 10, 13, 15, 19)


@pytest.fixture(scope="module")
def paper():
    return load_scenario(PAPER)


@pytest.fixture(scope="module")
def truth_reports(paper):
    rig = Rig(paper.robot, paper.lab)
    out = []
    for i, q in enumerate(paper.poses):
        rig.command(q)
        rig.hook(paper.load.hooks[i], paper.load.anchors[i])
        scanner = Scanner.place(paper.lab, rig.solve().block_pose, distance_m=0.6)
        out.append(truth_clearance(rig, rig.tighten(200.0), scanner.pose_world[:3, 3]))
    return out


@pytest.fixture(scope="module")
def nominal_reports(paper):
    nc = NominalClearance(paper.robot, paper.lab)
    return [nc.check(q, paper.load.hooks[i], paper.load.anchors[i]) for i, q in enumerate(paper.poses)]


def test_segment_distance_matches_a_numerical_minimum():
    """Closed form vs scipy on the convex (s, t) problem, random and parallel/degenerate segments."""
    rng = np.random.default_rng(3)
    cases = [rng.normal(size=(4, 3)) for _ in range(40)]
    cases += [np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [2, 1, 0]], float)]  # parallel, overlapping
    cases += [np.array([[0, 0, 0], [0, 0, 0], [1, 1, 1], [2, 1, 1]], float)]  # a point
    for p0, p1, q0, q1 in cases:

        def gap(x, p0=p0, p1=p1, q0=q0, q1=q1):
            return np.sum((p0 + x[0] * (p1 - p0) - q0 - x[1] * (q1 - q0)) ** 2)

        best = min(
            minimize(gap, x0, bounds=[(0, 1), (0, 1)], tol=1e-14).fun for x0 in ([0.5, 0.5], [0, 1], [1, 0])
        )
        assert shapes.segment_segment_distance(p0, p1, q0, q1) == pytest.approx(np.sqrt(best), abs=1e-6)
    # closed form: perpendicular skew segments 0.3 apart
    assert shapes.segment_segment_distance([-1, 0, 0], [1, 0, 0], [0, -1, 0.3], [0, 1, 0.3]) == pytest.approx(
        0.3
    )


def _shape_model():
    """Mocap geoms: a capsule, a cylinder, a box, a sphere and a plane, to compare with mj_geomDistance."""
    spec = mujoco.MjSpec()
    for name, kind, size in (
        ("cap", mujoco.mjtGeom.mjGEOM_CAPSULE, [0.05, 0.3, 0]),
        ("cyl", mujoco.mjtGeom.mjGEOM_CYLINDER, [0.08, 0.05, 0]),
        ("box", mujoco.mjtGeom.mjGEOM_BOX, [0.2, 0.1, 0.04]),
        ("ball", mujoco.mjtGeom.mjGEOM_SPHERE, [0.07, 0, 0]),
    ):
        spec.worldbody.add_body(name=name, mocap=True).add_geom(name=name, type=kind, size=size)
    spec.worldbody.add_geom(name="plane", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1])
    model = spec.compile()
    return model, mujoco.MjData(model)


def test_capsule_distance_matches_mujoco_geom_distance():
    """The shared capsule-vs-shape distance against MuJoCo's collision distance, 200 random placements."""
    from vtestbed.world.clearance import geom_shape

    m, d = _shape_model()
    rng = np.random.default_rng(7)
    cap = m.geom("cap").id
    compared = 0
    for _ in range(50):
        for name in ("cap", "cyl", "box", "ball"):
            body = m.body(name).mocapid[0]
            d.mocap_pos[body] = rng.uniform(-0.5, 0.5, 3) + [0, 0, 0.6]
            d.mocap_quat[body] = rng.normal(size=4) / np.linalg.norm(rng.normal(size=4))
            d.mocap_quat[body] /= np.linalg.norm(d.mocap_quat[body])
        mujoco.mj_forward(m, d)
        c = geom_shape(m, d, cap, "cap")
        for other in ("cyl", "box", "ball", "plane"):
            g = m.geom(other).id
            ref = mujoco.mj_geomDistance(m, d, cap, g, 10.0, None)
            shape = shapes.Plane("plane") if other == "plane" else geom_shape(m, d, g, other)
            mine = float(shapes.capsule_distance(c.p0, c.p1, c.radius, shape))
            if ref > 0:  # separated: both are the exact gap
                assert mine == pytest.approx(ref, abs=2e-6), other
                compared += 1
            else:  # overlapping: both say so (depth conventions differ)
                assert mine < 1e-6, other
    assert compared > 120


def test_solid_distance_matches_mujoco_for_cylinders_and_boxes_on_a_table():
    from vtestbed.world.clearance import geom_shape

    m, d = _shape_model()
    rng = np.random.default_rng(11)
    box = m.geom("box").id
    d.mocap_pos[m.body("box").mocapid[0]] = [0, 0, 0.3]
    checked = 0
    for _ in range(60):
        for name in ("cyl", "cap", "ball"):
            body = m.body(name).mocapid[0]
            d.mocap_pos[body] = rng.uniform([-0.4, -0.3, 0.3], [0.4, 0.3, 0.7])
            quat = rng.normal(size=4)
            d.mocap_quat[body] = quat / np.linalg.norm(quat)
        mujoco.mj_forward(m, d)
        table = geom_shape(m, d, box, "box")
        cyl = geom_shape(m, d, m.geom("cyl").id, "cyl")
        ref = mujoco.mj_geomDistance(m, d, m.geom("cyl").id, box, 10.0, None)
        if ref > 1e-3:
            # the rims as 72-gons: within r (1 - cos 2.5 deg) = 0.08 mm of the exact gap, never above
            assert cl._solid_distance(cyl, table) == pytest.approx(ref, abs=1e-4)
            assert cl._solid_distance(cyl, table) >= ref - 1e-6
            checked += 1
    assert checked > 20


def test_link_radii_and_scene_shapes_match_the_truth_world(paper):
    """LINK_RADII and the nominal tool shapes are the scene's geoms (gravity off: no sag)."""
    rig = Rig(paper.robot, paper.lab, gravity=False)
    m, d = rig.model, rig.data
    ids = scene_geoms(m)
    assert [m.geom_size[ids[f"link{i + 1}"], 0] for i in range(6)] == pytest.approx(cl.LINK_RADII, abs=0)
    q = paper.poses[0]
    rig.command(q)
    rig.solve()
    nc = NominalClearance(paper.robot, paper.lab)
    nc._at(q)
    from vtestbed.world.clearance import geom_shape

    for shape in nc.links + nc.tool:
        truth = geom_shape(m, d, ids[shape.name], shape.name)
        probe = np.random.default_rng(0).uniform(-1.5, 1.5, (200, 3)) + [1, 0, 1]
        np.testing.assert_allclose(shape.sdf(probe), truth.sdf(probe), atol=1e-9, err_msg=shape.name)


def test_scanner_position_is_where_the_scanner_is_placed(paper):
    nc = NominalClearance(paper.robot, paper.lab)
    nc._at(paper.poses[3])
    placed = Scanner.place(paper.lab, nc.block_pose, distance_m=0.6)
    np.testing.assert_allclose(nc.scanner, placed.pose_world[:3, 3], atol=1e-12)


def test_sight_line_blocked_by_a_crossing_wire_closed_form():
    """A wire of radius 1 mm crossing the sight line 3 mm off it: clearance 2 mm, below the 5 mm margin."""
    targets = {"+x": np.array([[1.0, 0.0, 0.0]])}
    wire = shapes.Capsule("wire", np.array([0.5, -1.0, 0.003]), np.array([0.5, 1.0, 0.003]), 0.001)
    (entry,) = cl.sight_clearances(np.zeros(3), targets, [wire])
    assert entry.distance_m == pytest.approx(0.002, abs=1e-12)
    assert not entry.ok and entry.second == "wire"


def test_wire_edges_exclude_the_hook_edge_and_catch_a_wire_into_the_block():
    box = shapes.Box("block", np.zeros(3), np.eye(3), np.full(3, 0.04))
    hook = np.array([-0.04, -0.04, 0.0])  # on the -x/-y edge
    out = {e.second: e for e in cl.wire_clearances(hook, [-1.0, -1.0, -1.0], [], box, 0.001)}
    assert "block (cuts into it)" not in out
    # leaving diagonally outward: the nearest other edges are the -x/-y face's end edges at z = -0.04 ...
    assert out["block edges"].distance_m > 0.02
    into = {e.second: e for e in cl.wire_clearances(hook, [1.0, 1.0, 0.0], [], box, 0.001)}
    assert into["block (cuts into it)"].distance_m < -0.01


def test_paper_scenario_unclear_tests_truth_and_nominal_agree(paper, truth_reports, nominal_reports):
    """Which of the paper's 20 tests fail, in the truth world (MuJoCo) and on the nominal model."""
    lines = []
    for i, (t, n) in enumerate(zip(truth_reports, nominal_reports)):
        lines.append(f"poses.angles_deg[{i}] {'clear' if t.ok else 'UNCLEAR: ' + t.message('test')}")
        assert t.ok == n.ok, i
        # clear tests: nominal (commanded pose) vs truth (sagged: up to 1.7 mm at the elbow) within 3 mm
        tn = {(e.first, e.second): e.distance_m for e in n.entries}
        for e in t.entries:
            key = (e.first, e.second)
            if t.ok and key in tn and e.distance_m < 0.3:
                assert tn[key] == pytest.approx(e.distance_m, abs=3e-3), (i, key)
    print("\n".join(lines))
    assert tuple(i for i, t in enumerate(truth_reports) if not t.ok) == PAPER_UNCLEAR
    link_table = {i for i, t in enumerate(truth_reports) for e in t.failures if e.second == "table_top"}
    assert link_table == {7, 9, 13, 15, 19}
    worst = truth_reports[9].worst()  # the elbow below the table top: link 2 about 100 mm into it
    assert worst.first in ("link2", "link3") and worst.second == "table_top" and worst.distance_m < -0.08


def test_scenario_tests_warn_and_generated_tests_are_refused(paper):
    rig = Rig(paper.robot, paper.lab)
    q, hook, ring = paper.poses[9], paper.load.hooks[9], paper.load.anchors[9]
    with pytest.warns(
        cl.ClearanceWarning,
        match=r"poses.angles_deg\[9\] is not physically possible: link2 vs table_top: -1\d\d\.\d mm",
    ):
        phys = run_test_physics(rig, q, hook, ring, 200.0, 0.6, label="poses.angles_deg[9]")
    assert not phys.clearance.ok
    with pytest.raises(cl.ClearanceError, match=r"link2 vs table_top"):
        run_test_physics(rig, q, hook, ring, 200.0, 0.6, clearance="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert run_test_physics(
            rig, paper.poses[0], paper.load.hooks[0], paper.load.anchors[0], 200.0, 0.6
        ).clearance.ok
    with pytest.raises(
        UnknownNameError, match="unknown clearance policy 'loud'; valid names: off, raise, warn"
    ):
        phys.clearance.enforce("x", "loud")
    checker = FeasibilityChecker(paper)
    why = checker.check(q, hook, ring, 200.0)
    assert why.startswith("ClearanceError") and "table_top" in why and checker.clearance_refused == 1
    assert checker.check(paper.poses[0], paper.load.hooks[0], paper.load.anchors[0], 200.0) is None


def test_candidate_tests_filter_on_the_nominal_model(paper):
    nc = NominalClearance(paper.robot, paper.lab)
    poses = paper.poses[[0, 9, 13]]
    kept = design.candidate_tests(paper.robot, poses, lab=paper.lab, clearance=nc)
    every = design.candidate_tests(paper.robot, poses, lab=paper.lab, clearance=False)
    assert len(kept) + nc.refused == len(every) and nc.refused > 0
    assert all(NominalClearance(paper.robot, paper.lab).check(c.q, c.hook, c.anchor).ok for c in kept)
    assert not any(np.array_equal(c.q, paper.poses[9]) or np.array_equal(c.q, paper.poses[13]) for c in kept)
