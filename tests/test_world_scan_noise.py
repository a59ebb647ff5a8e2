"""The scanner's noise model against its own documented laws, drawn out by statistics."""

from __future__ import annotations

import numpy as np

from vtestbed.transforms import rotation_vector
from vtestbed.world.scan_noise import ScanNoise


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
