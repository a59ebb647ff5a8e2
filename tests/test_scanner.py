"""The synthetic scanner against independent references: analytic ray-box geometry, the noise
model's own formulas drawn out by statistics, and the datasheet's limits."""

from __future__ import annotations

import numpy as np
import pytest

from vtestbed.errors import DatasetError, OutOfRangeError, ScanError
from vtestbed.ply import read_ply, write_ply
from vtestbed.transforms import homogeneous, invert, rotation_vector
from vtestbed.world.rig import Rig
from vtestbed.world.scan_noise import ScanNoise
from vtestbed.world.scanner import BLOCK_GEOM, Scanner

POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)


@pytest.fixture(scope="module")
def scene():
    """The default pose, unloaded: rig, true block pose, a placed scanner and its noise-free hits."""
    rig = Rig()
    rig.command(np.radians(POSE_DEG))
    rig.hook("hook_x", "ring_5")
    state = rig.solve()
    scanner = Scanner.place(rig.lab, state.block_pose)
    hits = scanner.cast(rig.model, rig.data)
    return rig, state, scanner, hits


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
        match=r"distance_m \(scanner stand-off\) = 1.3 m is outside the valid range \[0.1, 1.25\]",
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


def test_range_noise_has_the_documented_size(scene):
    _, _, _, hits = scene
    noise = ScanNoise(outlier_fraction=0.0, drift_translation_std_m=0.0, drift_rotation_std_rad=0.0)
    scan = noise.sample(hits, np.random.default_rng(3))
    ref = hits.take(scan.hit_index)
    offset = np.einsum("ij,ij->i", scan.points_m - ref.points_m, ref.directions)
    cos_i = -np.einsum("ij,ij->i", ref.directions, ref.normals)
    expected = 0.010e-3 / cos_i**1.5  # the docstring's law, restated
    z = offset / expected
    assert abs(z.std() - 1.0) < 0.02 and abs(z.mean()) < 0.02
    perp = scan.points_m - ref.points_m - offset[:, None] * ref.directions
    assert np.abs(perp).max() < 1e-15  # the error is along the ray only


def test_dropouts_and_outliers_have_the_set_rates(scene):
    _, _, _, hits = scene
    noise = ScanNoise(
        dropout_start_deg=50.0, dropout_full_deg=62.0, outlier_fraction=0.01, outlier_range_m=2e-3
    )
    scan = noise.sample(hits, np.random.default_rng(4))
    theta = np.degrees(np.arccos(-np.einsum("ij,ij->i", hits.directions, hits.normals)))
    p_drop = np.clip((theta - 50.0) / 12.0, 0.0, 1.0)
    expected, var = np.sum(1 - p_drop), np.sum(p_drop * (1 - p_drop))
    assert abs(len(scan.points_m) - expected) < 4 * np.sqrt(var)
    # outliers: 1 % of the kept points, uniform in +-2 mm along the ray
    n, k = len(scan.points_m), scan.outlier.sum()
    assert abs(k - 0.01 * n) < 4 * np.sqrt(0.01 * 0.99 * n)
    ref = hits.take(scan.hit_index[scan.outlier])
    off = np.einsum("ij,ij->i", scan.points_m[scan.outlier] - ref.points_m, ref.directions)
    assert np.abs(off).max() <= 2e-3 + 1e-6 and abs(np.abs(off).mean() - 1e-3) < 0.1e-3


def test_drift_moves_the_whole_scan_rigidly_with_the_set_spread(scene):
    _, _, _, hits = scene
    noise = ScanNoise(
        range_std_m=0.0, outlier_fraction=0.0, drift_translation_std_m=4e-6, drift_rotation_std_rad=7e-6
    )
    scan = noise.sample(hits, np.random.default_rng(5))
    ref = hits.points_m[scan.hit_index]
    np.testing.assert_allclose(scan.points_m, ref @ scan.drift[:3, :3].T + scan.drift[:3, 3], atol=1e-15)
    few = hits.take(np.arange(10))
    drifts = [noise.sample(few, np.random.default_rng(s)).drift for s in range(2000)]
    rot = np.array([rotation_vector(d[:3, :3]) for d in drifts])
    trans = np.array([d[:3, 3] for d in drifts])
    np.testing.assert_allclose(rot.std(axis=0), 7e-6, rtol=0.08)
    np.testing.assert_allclose(trans.std(axis=0), 4e-6, rtol=0.08)


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


def test_ply_round_trip(scene, tmp_path):
    _, _, _, hits = scene
    pts = ScanNoise().apply(hits, np.random.default_rng(0))
    assert np.array_equal(read_ply(write_ply(tmp_path / "a.ply", pts)), pts)
    np.testing.assert_allclose(
        read_ply(write_ply(tmp_path / "b.ply", pts, "mm"), "mm"), pts, rtol=0, atol=1e-15
    )
    raw = read_ply(tmp_path / "b.ply")  # the same file read as metres is 1000x larger
    np.testing.assert_allclose(raw, pts * 1e3, rtol=1e-15)
    with pytest.raises(DatasetError, match="not found"):
        read_ply(tmp_path / "missing.ply")
    with pytest.raises(OutOfRangeError, match="length_unit = 'inch'"):
        read_ply(tmp_path / "a.ply", "inch")


def test_scan_command_writes_clouds_and_matching_displacements(tmp_path, capsys):
    from vtestbed.cli.main import main
    from vtestbed.transforms import displacement

    assert main(["scan", "--out", str(tmp_path), "--noise-free"]) == 0
    import json

    result = json.loads((tmp_path / "scan.json").read_text())
    measured, true = np.array(result["displacement_measured"]), np.array(result["displacement_true"])
    assert measured.shape == (6,) and np.abs(measured - true).max() < 1e-9
    # the truth restated from an independent rig run
    rig = Rig()
    rig.command(np.radians(POSE_DEG))
    rig.hook("hook_x", "ring_5")
    s0, s1 = rig.solve(), rig.tighten(200.0)
    np.testing.assert_allclose(true, displacement(s0.block_pose, s1.block_pose), atol=1e-12)
    points = read_ply(tmp_path / "loaded.ply")
    assert len(points) == result["clouds"]["points"][1] > 40000
    assert "measured" in capsys.readouterr().out
    assert main(["scan", "--out", str(tmp_path), "--view", "1,1"]) == 2
    assert "--view must be 3 finite numbers" in capsys.readouterr().err
