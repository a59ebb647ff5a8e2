"""The point-cloud pipeline against MuJoCo's true block pose and the least-squares plane-fit theory."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vtestbed.errors import OutOfRangeError, ScanError
from vtestbed.ply import read_ply, write_ply
from vtestbed.researcher.cloud import (
    FitParams,
    block_displacement,
    displacement_in_scanner,
    fit_block_frame,
    paper_displacement,
)
from vtestbed.transforms import (
    displacement,
    homogeneous,
    invert,
    matrix_from_rotation_vector,
    rotation_vector,
)
from vtestbed.world.rig import Rig
from vtestbed.world.scan_noise import ScanNoise
from vtestbed.world.scanner import BLOCK_GEOM, Scanner

POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)
SIGMA0, GRAZING = 0.010e-3, 1.5
POINT_NOISE = ScanNoise(
    range_std_m=SIGMA0,
    grazing_exponent=GRAZING,
    dropout_start_deg=90.0,
    dropout_full_deg=90.0,
    outlier_fraction=0.0,
    drift_translation_std_m=0.0,
    drift_rotation_std_rad=0.0,
)


@pytest.fixture(scope="module")
def world():
    """Unloaded and loaded scans of the default pose (hook_x -> ring_5, 200 N), noise-free."""
    rig = Rig()
    rig.command(np.radians(POSE_DEG))
    rig.hook("hook_x", "ring_5")
    s0 = rig.solve()
    scanner = Scanner.place(rig.lab, s0.block_pose)
    hits0 = scanner.cast(rig.model, rig.data)
    s1 = rig.tighten(200.0)
    hits1 = scanner.cast(rig.model, rig.data)
    to_s = invert(scanner.pose_world)
    return {
        "rig": rig,
        "scanner": scanner,
        "states": (s0, s1),
        "hits": (hits0, hits1),
        "true": (to_s @ s0.block_pose, to_s @ s1.block_pose),  # B in the scanner frame
        "block_id": rig.model.geom(BLOCK_GEOM).id,
    }


def _frame_error(fitted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """[origin error (m), rotation error (rad)], both in the true block frame's axes."""
    rot = true[:3, :3]
    return np.concatenate([rot.T @ (fitted[:3, 3] - true[:3, 3]), rotation_vector(rot.T @ fitted[:3, :3])])


RANSAC = FitParams(method="ransac")  # today's fallback alone, for comparison


def _rough(pose: np.ndarray) -> np.ndarray:
    """A nominal pose as a lab knows it: 4 mm and 2 deg off."""
    return pose @ homogeneous(
        matrix_from_rotation_vector(np.radians([1.2, -1.0, 1.2])), [0.003, -0.002, 0.0015]
    )


def test_noise_free_frames_and_displacement_match_mujoco(world):
    (h0, h1), (t0, t1) = world["hits"], world["true"]
    f0 = fit_block_frame(h0.points_m, _rough(t0))
    f1 = fit_block_frame(h1.points_m, f0)
    for fit, true in ((f0, t0), (f1, t1)):
        err = _frame_error(fit.pose, true)
        assert np.abs(err[:3]).max() < 1e-12 and np.abs(err[3:]).max() < 1e-12
        assert fit.counts.min() > 14000 and fit.rms_residual_m.max() < 1e-12
        assert (fit.method, fit.fallback_reason) == ("fast", "")
        old = fit_block_frame(h0.points_m if fit is f0 else h1.points_m, _rough(true), RANSAC)
        assert old.method == "ransac" and np.abs(_frame_error(old.pose, true)).max() < 1e-12
    s0, s1 = world["states"]
    true_base = displacement(s0.block_pose, s1.block_pose)
    measured = block_displacement(f0, f1, world["scanner"].pose_world)
    assert np.abs(measured - true_base).max() < 1e-9
    assert np.abs(displacement_in_scanner(f0, f1) - displacement(t0, t1)).max() < 1e-9
    assert np.abs(true_base[:3]).max() > 1e-4  # a real displacement (0.1 mm and more) was measured


def test_paper_form_is_euler_xyz_of_o1_o0inv_and_not_the_block_motion(world):
    t0, t1 = world["true"]
    f0, f1 = fit_block_frame(world["hits"][0].points_m, t0), fit_block_frame(world["hits"][1].points_m, t1)
    paper = paper_displacement(f0, f1)
    rel = t1 @ invert(t0)
    np.testing.assert_allclose(paper[3:], Rotation.from_matrix(rel[:3, :3]).as_euler("xyz"), atol=1e-12)
    np.testing.assert_allclose(paper[:3], t1[:3, 3] - rel[:3, :3] @ t0[:3, 3], atol=1e-12)
    # the pitfall: o1 - R o0 differs from the block's own motion o1 - o0 by (R - I) o0
    block = displacement_in_scanner(f0, f1)[:3]
    gap = np.linalg.norm(paper[:3] - block)
    assert gap == pytest.approx(np.linalg.norm((rel[:3, :3] - np.eye(3)) @ t0[:3, 3]), rel=1e-6)
    assert gap > 0.3 * np.linalg.norm(block)


def _analytic_frame_covariance(hits, block_id, true):
    """Covariance (6, 6) of [origin error, rotation error] in B from three least-squares plane fits.

    Face k (normal e_k, in-plane axes a < b): a point's error along e_k is s_i = sigma0 *
    cos_i^(1 - g) (the along-ray std sigma0 / cos_i^g projected on the normal). The plane
    z = h + u (x_a - xbar_a) + w (x_b - xbar_b) fitted by least squares has
        Cov[h, u, w] = (A^T A)^-1 A^T diag(s^2) A (A^T A)^-1,  A_i = [1, x_ia - xbar_a, x_ib - xbar_b].
    The fitted normal is n_k = e_k - u e_a - w e_b, so dN_jk = e_j . dn_k; the frame's rotation is
    the polar factor of [n_x n_y n_z], to first order omega = vee((dN - dN^T) / 2). The three planes
    meet where each is at height zero: do_k = h - u xbar_a - w xbar_b.
    """
    rot, org = true[:3, :3], true[:3, 3]
    block = hits.take(hits.geom_ids == block_id)
    q = (block.points_m - org) @ rot
    s = SIGMA0 * np.clip(-np.einsum("ij,ij->i", block.directions, block.normals), 0, 1) ** (1 - GRAZING)
    face = np.argmax(q, axis=1)
    cov9, jac = np.zeros((9, 9)), np.zeros((6, 9))
    for k in range(3):
        a, b = [j for j in range(3) if j != k]
        pts, sk = q[face == k], s[face == k]
        xbar = pts.mean(axis=0)
        design = np.column_stack([np.ones(len(pts)), pts[:, a] - xbar[a], pts[:, b] - xbar[b]])
        inv = np.linalg.inv(design.T @ design)
        cov9[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = inv @ (design.T * sk**2) @ design @ inv
        jac[k, 3 * k : 3 * k + 3] = (1.0, -xbar[a], -xbar[b])
        for col, axis in ((1, a), (2, b)):
            dn = np.zeros((3, 3))
            dn[axis, k] = -1.0  # d n_k / d(u or w) = -e_axis
            w = (dn - dn.T) / 2
            jac[3:, 3 * k + col] = (w[2, 1], w[0, 2], w[1, 0])
    return jac @ cov9 @ jac.T


def test_noise_only_scatter_matches_the_least_squares_plane_fit(world):
    hits, true = world["hits"][0], world["true"][0]
    errors = []
    for seed in range(50):
        rng = np.random.default_rng(seed)
        errors.append(_frame_error(fit_block_frame(POINT_NOISE.apply(hits, rng), true, rng=rng).pose, true))
    observed = np.sqrt(np.mean(np.square(errors), axis=0))
    predicted = np.sqrt(np.diag(_analytic_frame_covariance(hits, world["block_id"], true)))
    ratio = observed / predicted
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (observed, predicted)
    assert 1e-7 < predicted[:3].max() < 1e-6 and 1e-6 < predicted[3:].max() < 1e-5  # sub-um, a few urad


def test_outliers_and_clutter_cost_at_most_twice_the_clean_error(world):
    hits, true, block_id = world["hits"][1], world["true"][1], world["block_id"]
    names = {world["rig"].model.geom(int(g)).name for g in np.unique(hits.geom_ids)}
    assert "wire_geom" in names and np.sum(hits.geom_ids != block_id) > 5000  # wire and wrist in view
    clean_hits = hits.take(hits.geom_ids == block_id)
    dirty = ScanNoise(**{**POINT_NOISE.__dict__, "outlier_fraction": 0.01})
    clean_err, dirty_err = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        clean_err.append(
            _frame_error(fit_block_frame(POINT_NOISE.apply(clean_hits, rng), true, rng=rng).pose, true)
        )
        rng = np.random.default_rng(seed)
        dirty_err.append(_frame_error(fit_block_frame(dirty.apply(hits, rng), true, rng=rng).pose, true))
    clean_err, dirty_err = np.array(clean_err), np.array(dirty_err)
    for part in (slice(0, 3), slice(3, 6)):
        rms_clean = np.sqrt(np.mean(np.sum(clean_err[:, part] ** 2, axis=1)))
        rms_dirty = np.sqrt(np.mean(np.sum(dirty_err[:, part] ** 2, axis=1)))
        assert rms_dirty <= 2 * rms_clean, (rms_dirty, rms_clean)


def test_drift_shows_in_the_displacement_with_the_set_magnitude(world):
    (h0, h1), (t0, t1) = world["hits"], world["true"]
    sig_t, sig_r = 5e-6, 8e-6
    noise = ScanNoise(**{**POINT_NOISE.__dict__, "range_std_m": 0.0})
    noise = ScanNoise(**{**noise.__dict__, "drift_translation_std_m": sig_t, "drift_rotation_std_rad": sig_r})
    scan = noise.sample(h0, np.random.default_rng(0))
    np.testing.assert_allclose(fit_block_frame(scan.points_m, t0).pose, scan.drift @ t0, atol=1e-12)
    truth = displacement(t0, t1)
    errors = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        f0 = fit_block_frame(noise.apply(h0, rng), t0)
        f1 = fit_block_frame(noise.apply(h1, rng), f0)
        errors.append(displacement_in_scanner(f0, f1) - truth)
    observed = np.sqrt(np.mean(np.square(errors), axis=0))
    # two independent drifts (t, omega): error = (t1 - t0) + (omega1 - omega0) x o
    o = t0[:3, 3]
    cross = np.array([[0, -o[2], o[1]], [o[2], 0, -o[0]], [-o[1], o[0], 0]])
    cov_t = 2 * (sig_t**2 * np.eye(3) + sig_r**2 * cross @ cross.T)
    predicted = np.concatenate([np.sqrt(np.diag(cov_t)), np.full(3, np.sqrt(2) * sig_r)])
    np.testing.assert_allclose(observed, predicted, rtol=0.35)


def test_missing_or_cut_faces_are_named(world):
    hits, true = world["hits"][0], world["true"][0]
    q = (hits.points_m - true[:3, 3]) @ true[:3, :3]
    on_z = np.abs(q[:, 2]) < 1e-9
    with pytest.raises(ScanError, match=r"fewer than three block faces found: face \+z has \d+ points"):
        fit_block_frame(hits.points_m[~on_z], true)
    cut = (np.abs(q[:, 0]) < 1e-9) & (q[:, 1] < -0.03)  # most of the +x face out of view
    with pytest.raises(ScanError, match=r"face \+x spans only .* mm of the 80 mm block edge.*partly outside"):
        fit_block_frame(hits.points_m[~cut], true)
    with pytest.raises(ScanError, match="block not found: only 0 of"):
        fit_block_frame(hits.points_m, true @ homogeneous(np.eye(3), [0.3, 0.0, 0.0]))
    with pytest.raises(OutOfRangeError, match=r"points must be an \(N, 3\) array"):
        fit_block_frame(hits.points_m[:, :2], true)
    with pytest.raises(OutOfRangeError, match="crop_margin_m"):
        FitParams(crop_margin_m=0.05)


def test_same_seed_same_frame_also_through_ply(world, tmp_path):
    hits, true = world["hits"][0], world["true"][0]
    noise = ScanNoise(outlier_fraction=0.01)
    poses = []
    for seed in (7, 7, 8):
        rng = np.random.default_rng(seed)
        poses.append(fit_block_frame(noise.apply(hits, rng), _rough(true), rng=rng).pose)
    assert np.array_equal(poses[0], poses[1]) and not np.array_equal(poses[0], poses[2])
    # open3d draws RANSAC samples in parallel threads; the refined frame must not depend on them
    points = noise.apply(hits, np.random.default_rng(7))
    others = [fit_block_frame(points, _rough(true), RANSAC, np.random.default_rng(s)).pose for s in range(10)]
    assert all(np.array_equal(p, others[0]) for p in others)
    # nor on the rounding of the nominal pose (e.g. a scanner pose stored as a rotation vector)
    nudged = _rough(true) @ homogeneous(matrix_from_rotation_vector([1e-12, -2e-12, 1e-12]), [1e-13, 0, 0])
    assert np.array_equal(fit_block_frame(points, nudged, RANSAC).pose, others[0])
    assert np.array_equal(fit_block_frame(points, nudged).pose, fit_block_frame(points, _rough(true)).pose)
    rng = np.random.default_rng(7)
    path = write_ply(tmp_path / "scan.ply", noise.apply(hits, rng))
    assert np.array_equal(fit_block_frame(read_ply(path), _rough(true), rng=rng).pose, poses[0])


def _rms(errors: np.ndarray) -> tuple[float, float]:
    """RMS length of the origin error [m] and of the rotation error [rad] over rows of (n, 6)."""
    return tuple(
        float(np.sqrt(np.mean(np.sum(errors[:, s] ** 2, axis=1)))) for s in (slice(0, 3), slice(3, 6))
    )


def test_fast_path_is_as_accurate_as_ransac_against_the_truth(world):
    """Default scanner noise without the drift (which moves both fits alike): outliers, dropouts,
    grazing growth, the wrist and the wire in view; both paths on the same clouds."""
    noise = ScanNoise(drift_translation_std_m=0.0, drift_rotation_std_rad=0.0)
    errors = {"fast": [], "ransac": []}
    for seed in range(12):
        for k in range(2):
            hits, true = world["hits"][k], world["true"][k]
            points = noise.apply(hits, np.random.default_rng(100 * k + seed))
            for params in (FitParams(), RANSAC):
                fit = fit_block_frame(points, _rough(true), params, np.random.default_rng(seed))
                errors[fit.method].append(_frame_error(fit.pose, true))
    assert len(errors["fast"]) == len(errors["ransac"]) == 24
    fast, old = _rms(np.array(errors["fast"])), _rms(np.array(errors["ransac"]))
    assert fast[0] <= 1.05 * old[0] and fast[1] <= 1.05 * old[1], (fast, old)
    assert fast[0] < 1e-6 and fast[1] < 1e-5  # sub-um, a few urad (per-point noise only)


def _turned(pose: np.ndarray, deg: float, axis=(1.0, 1.0, 1.0), about_centre: bool = False) -> np.ndarray:
    """``pose`` turned by ``deg`` about ``axis`` (B's axes) through B's corner or the block centre."""
    turn = homogeneous(
        matrix_from_rotation_vector(np.radians(deg) * np.asarray(axis) / np.linalg.norm(axis)), np.zeros(3)
    )
    centre = homogeneous(np.eye(3), np.full(3, -0.04)) if about_centre else np.eye(4)
    return pose @ centre @ turn @ invert(centre)


@pytest.mark.parametrize(
    ("deg", "axis", "about_centre", "reason"),
    [
        (30.0, (1, 1, 1), False, r"robust plane residual .*RANSAC search, 30\.0 deg from the nominal"),
        (30.0, (1, -1, 0), True, r"RANSAC search, 30\.0 deg from the nominal"),
        (5.0, (0, 0, 1), False, r"^the nominal pose is 5\.00 deg and 0\.00 mm from the fitted frame"),
    ],
)
def test_a_nominal_pose_far_off_falls_back_to_ransac_and_still_fits(world, deg, axis, about_centre, reason):
    hits, true = world["hits"][0], world["true"][0]
    nominal = _turned(true, deg, axis, about_centre)
    angle = np.degrees(np.linalg.norm(rotation_vector(true[:3, :3].T @ nominal[:3, :3])))
    assert angle == pytest.approx(deg, abs=1e-9)
    fit = fit_block_frame(hits.points_m, nominal)  # noise-free: the exact frame, whichever path
    assert fit.method == "ransac" and re.search(reason, fit.fallback_reason), fit.fallback_reason
    assert np.abs(_frame_error(fit.pose, true)).max() < 1e-12
    points = ScanNoise(drift_translation_std_m=0.0, drift_rotation_std_rad=0.0).apply(
        hits, np.random.default_rng(3)
    )
    fast = fit_block_frame(points, true)
    assert fast.method == "fast"
    noisy = fit_block_frame(points, nominal, rng=np.random.default_rng(3))
    assert noisy.method == "ransac"
    err = _frame_error(noisy.pose, true)  # a few sigma of the noise-only scatter (0.3 um, 3.5 urad)
    assert np.abs(err[:3]).max() < 2e-6 and np.abs(err[3:]).max() < 2e-5
    with pytest.raises(ScanError):  # the fast path alone refuses
        fit_block_frame(points, nominal, FitParams(method="fast"))


def test_a_rough_face_falls_back_to_ransac(world):
    """A face rougher than fast_max_sigma_m (0.1 mm): the fast path hands over, RANSAC fits it."""
    hits, true = world["hits"][0], world["true"][0]
    q = (hits.points_m - true[:3, 3]) @ true[:3, :3]
    on_z = np.abs(q[:, 2]) < 1e-9
    bumps = np.random.default_rng(5).normal(0.0, 0.2e-3, on_z.sum())
    points = hits.points_m.copy()
    points[on_z] += bumps[:, None] * true[:3, 2]  # 0.2 mm along the face normal
    fit = fit_block_frame(points, _rough(true))
    assert fit.method == "ransac" and "face +z: robust plane residual" in fit.fallback_reason
    # least squares on about 15 000 points of 0.2 mm scatter: the +z normal to ~1e-4 rad
    err = _frame_error(fit.pose, true)
    assert np.abs(err[:3]).max() < 2e-5 and np.abs(err[3:]).max() < 2e-4
    assert fit.rms_residual_m[2] == pytest.approx(0.2e-3, rel=0.1)


def test_fit_methods_are_checked():
    with pytest.raises(OutOfRangeError, match=r"method = 'svd' is not one of auto, fast, ransac"):
        FitParams(method="svd")
    with pytest.raises(
        OutOfRangeError, match=r"fast_max_offset_m = 0.2 m is outside the valid range \[0, 0.08\]"
    ):
        FitParams(fast_max_offset_m=0.2)


_WORKER = """
import json, sys
import numpy as np
from vtestbed.researcher.cloud import fit_block_frame
points, nominal = np.load(sys.argv[1]), np.load(sys.argv[2])
fit = fit_block_frame(points, nominal)
print(json.dumps({"method": fit.method, "open3d": "open3d" in sys.modules, "pose": fit.pose.tolist()}))
"""


def test_the_fast_path_does_not_import_open3d(world, tmp_path):
    """A fresh worker that fits with the fast path never loads open3d; one that falls back does."""
    hits, true = world["hits"][0], world["true"][0]
    points = ScanNoise().apply(hits, np.random.default_rng(0))
    np.save(tmp_path / "points.npy", points)
    runs = {}
    for name, nominal in (("good", _rough(true)), ("far", _turned(true, 30.0))):
        np.save(tmp_path / f"{name}.npy", nominal)
        out = subprocess.run([sys.executable, "-c", _WORKER, str(tmp_path / "points.npy"), str(tmp_path / f"{name}.npy")],
                             capture_output=True, text=True, check=True, timeout=300)  # fmt: skip
        runs[name] = json.loads(out.stdout.strip().splitlines()[-1])
    assert (runs["good"]["method"], runs["good"]["open3d"]) == ("fast", False)
    assert (runs["far"]["method"], runs["far"]["open3d"]) == ("ransac", True)
    expected = fit_block_frame(points, _rough(true)).pose  # the same numbers in this process
    assert np.array_equal(np.array(runs["good"]["pose"]), expected)
    assert np.abs(np.array(runs["far"]["pose"]) - expected).max() < 1e-6
