"""The synthetic scanner against independent references: analytic ray-box geometry, the
placement's closed forms and the datasheet's limits (the noise model: test_world_scan_noise.py)."""

from __future__ import annotations

import numpy as np
import pytest

from vtestbed.errors import OutOfRangeError, ScanError
from vtestbed.transforms import homogeneous, invert
from vtestbed.world.scan_noise import ScanNoise
from vtestbed.world.scanner import BLOCK_GEOM, Scanner


def _block_id(rig):
    return rig.model.geom(BLOCK_GEOM).id


def _ray_box(origin, dirs, lo, hi):
    """Slab-method entry distance of rays into the box [lo, hi]^3 (inf: no hit). Written for the test."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / dirs, (hi - origin) / dirs
    t_near = np.max(np.minimum(t1, t2), axis=1)
    t_far = np.min(np.maximum(t1, t2), axis=1)
    return np.where((t_far >= t_near) & (t_near > 0), t_near, np.inf)


def test_noise_free_points_lie_on_the_true_block_faces(scene):
    rig, state, scanner, hits = scene
    block = hits.take(hits.geom_ids == _block_id(rig))
    world = block.points_m @ scanner.pose_world[:3, :3].T + scanner.pose_world[:3, 3]
    q = (world - state.block_pose[:3, 3]) @ state.block_pose[:3, :3]  # in B: the block is [-e, 0]^3
    e = rig.lab.block.edge
    # on one of the faces x = 0, y = 0, z = 0 of B, and inside the face's square
    assert np.abs(q.max(axis=1)).max() < 1e-9
    assert q.min() > -e - 1e-9
    # seen along the diagonal, the three scanned faces share the points about equally
    share = np.bincount(np.argmax(q, axis=1), minlength=3) / len(q)
    np.testing.assert_allclose(share, 1 / 3, atol=0.03)


def test_no_block_point_is_hidden_where_it_should_be_visible(scene):
    rig, state, scanner, hits = scene
    e = rig.lab.block.edge
    block_s = invert(scanner.pose_world) @ state.block_pose
    rot, org = block_s[:3, :3], block_s[:3, 3]
    dirs_b = scanner.ray_directions @ rot  # rays in B, from the optical centre
    t = _ray_box(-org @ rot, dirs_b, -e, 0.0)
    expected = np.flatnonzero(np.isfinite(t))
    ranges = np.linalg.norm(hits.points_m, axis=1)
    is_block = hits.geom_ids == _block_id(rig)
    seen = hits.ray_index[is_block]
    assert set(seen) <= set(expected)
    assert np.abs(ranges[is_block] - t[seen]).max() < 1e-9
    # every block ray MuJoCo did not report on the block hit something nearer (an occluder)
    missing = np.setdiff1d(expected, seen)
    row = {r: i for i, r in enumerate(hits.ray_index)}
    assert all(r in row and ranges[row[r]] < t[r] - 1e-6 for r in missing)
    assert len(seen) > 40000 and len(missing) < 0.01 * len(seen)


def test_placement_looks_at_the_block_centre_with_three_equal_faces(scene):
    rig, state, scanner, _ = scene
    e = rig.lab.block.edge
    centre = state.block_pose[:3, 3] + state.block_pose[:3, :3] @ np.full(3, -e / 2)
    c_s = scanner.to_scanner(centre[None])[0]
    assert np.hypot(c_s[0], c_s[1]) < 1e-12 and c_s[2] == pytest.approx(0.6, abs=1e-12)
    axis_w = scanner.pose_world[:3, 2]
    cos_faces = -(axis_w @ state.block_pose[:3, :3])  # incidence on the +x, +y, +z faces
    np.testing.assert_allclose(cos_faces, 1 / np.sqrt(3), atol=1e-12)
    assert scanner.pose_world[2, 3] > rig.lab.table.height  # above the table


def test_point_spacing_is_the_configured_one_at_the_standoff(scene):
    _, _, scanner, _ = scene
    d = scanner.ray_directions
    on_plane = d / d[:, 2:3] * scanner.standoff_m  # intersections with the plane z = standoff
    step = np.diff(np.unique(np.round(on_plane[:, 0], 12)))
    np.testing.assert_allclose(step, scanner.point_spacing_m, rtol=1e-9)


def test_block_outside_the_measuring_volume_is_refused(scene):
    rig, state, scanner, _ = scene
    shift = homogeneous(np.eye(3), [0.06, 0.0, 0.0])  # 60 mm sideways, in the scanner frame
    small = dict(area_m=(0.15, 0.114), standoff_m=0.6)
    partly = Scanner(pose_world=scanner.pose_world @ shift, **small)
    with pytest.raises(ScanError, match="partly outside the measuring volume.*field of view"):
        partly.cast(rig.model, rig.data)
    away = Scanner(pose_world=scanner.pose_world @ homogeneous(np.eye(3), [0.5, 0.0, 0.0]), **small)
    with pytest.raises(ScanError, match="wholly outside"):
        away.cast(rig.model, rig.data)
    shallow = Scanner(pose_world=scanner.pose_world, standoff_m=0.6, depth_m=0.05)
    with pytest.raises(ScanError, match="closer than the near limit.*beyond the far limit"):
        shallow.cast(rig.model, rig.data)
    with pytest.raises(
        OutOfRangeError,
        match=r"distance_m \(scanner stand-off\) = 1.3 m is outside the valid range \[0.17, 1.18\] m",
    ):
        Scanner.place(rig.lab, state.block_pose, distance_m=1.3)


def test_fewer_than_three_faces_is_refused(scene):
    rig, state, _, _ = scene
    with pytest.raises(ScanError, match=r"fewer than three block faces visible.*\+z"):
        Scanner.place(rig.lab, state.block_pose, view_direction_block=(1.0, 1.0, 0.1))
    # allowed by a permissive operator, the scan itself then finds the +z face edge-on
    edge_on = Scanner.place(
        rig.lab, state.block_pose, view_direction_block=(1.0, 1.0, 0.01), max_incidence_deg=90
    )
    with pytest.raises(ScanError, match="fewer than three block faces visible in the scan"):
        edge_on.cast(rig.model, rig.data)


def test_datasheet_limits_are_enforced(scene):
    _, _, scanner, hits = scene
    pose = scanner.pose_world
    with pytest.raises(OutOfRangeError, match="point_spacing_m .* finer than one camera pixel"):
        Scanner(pose_world=pose, point_spacing_m=0.05e-3)  # 450 mm / 2592 px = 0.17 mm
    with pytest.raises(OutOfRangeError, match=r"area_m \(width\) = 0.5 m .*\[0.05, 0.45\]"):
        Scanner(pose_world=pose, area_m=(0.5, 0.3))
    with pytest.raises(OutOfRangeError, match="pose_world"):
        Scanner(pose_world=np.eye(3))
    with pytest.raises(OutOfRangeError, match="outlier_fraction"):
        ScanNoise(outlier_fraction=0.9)
    with pytest.raises(OutOfRangeError, match="rng must be a numpy.random.Generator, got int"):
        ScanNoise().apply(hits, 42)


def test_same_seed_same_cloud(scene):
    rig, _, scanner, hits = scene
    noise = ScanNoise()
    a = scanner.scan(rig.model, rig.data, np.random.default_rng(11), noise)
    b = noise.apply(hits, np.random.default_rng(11))
    c = noise.apply(hits, np.random.default_rng(12))
    assert np.array_equal(a, b)
    assert len(c) != len(a) or not np.array_equal(a, c)
    perfect = scanner.scan(rig.model, rig.data, np.random.default_rng(1), ScanNoise.perfect())
    assert np.array_equal(perfect, hits.points_m)


@pytest.mark.parametrize("edge, view", [(0.08, (1.0, 1.0, 1.0)), (0.12, (1.0, 1.5, 0.8))])
def test_the_stand_off_range_is_where_every_corner_lies_in_the_measuring_volume(edge, view):
    """The range the scenario and ``place`` state (D11): at its ends the placed scanner takes all
    eight corners; 2 mm beyond them the scanner's own volume check refuses them, at the near or
    the far limit, although the stand-off is still inside the datasheet's 0.1-1.25 m."""
    from dataclasses import replace

    from vtestbed.lab import PAPER_LAB

    lab = replace(PAPER_LAB, block=replace(PAPER_LAB.block, edge=edge))
    low, high = lab.scanner_distance_range_m(view)
    # closed form: the corner farthest along the unit view lies edge/2 * |v|_1 / |v|_2 from the centre
    half = edge / 2 * sum(view) / np.linalg.norm(view)
    assert low == pytest.approx(0.1 + half, abs=1e-3) and high == pytest.approx(1.25 - half, abs=1e-3)
    assert 0.1 + half <= low and high <= 1.25 - half  # rounded inward
    block = homogeneous(np.eye(3), [-3.0, 0.0, 3.0])  # in the air, away from the table
    corners = np.array([[x, y, z] for x in (0, -edge) for y in (0, -edge) for z in (0, -edge)])
    for d in (low, high):
        Scanner.place(lab, block, distance_m=d, view_direction_block=view)  # its own corner check passes
    middle = Scanner.place(lab, block, distance_m=0.6, view_direction_block=view, roi_margin_m=None)
    for d, limit in ((low - 2e-3, "closer than the near limit"), (high + 2e-3, "beyond the far limit")):
        assert 0.1 < d < 1.25
        moved = Scanner(
            pose_world=middle.pose_world @ homogeneous(np.eye(3), [0.0, 0.0, 0.6 - d]), standoff_m=d
        )
        with pytest.raises(ScanError, match=limit):
            moved.check_in_volume(moved.to_scanner(block[:3, 3] + corners), "block")
        with pytest.raises(
            OutOfRangeError, match=rf"= {d:g} m is outside the valid range \[{low:g}, {high:g}\] m"
        ):
            Scanner.place(lab, block, distance_m=d, view_direction_block=view)
