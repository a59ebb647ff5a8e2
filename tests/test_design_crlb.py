"""The Cramer-Rao bound of the block frame and the stiffnesses against closed forms (one plane
fit), a Monte Carlo of the researcher's own frame fit on noisy clouds, the truth world's ray cast,
finite differences and the design module's covariance."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vtestbed.design import crlb
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.errors import OutOfRangeError
from vtestbed.researcher.cloud import fit_block_frame
from vtestbed.transforms import invert

K = PAPER_TABLE5.stiffness
NOISE = SimpleNamespace(range_std_m=10e-6, grazing_exponent=1.5, dropout_start_deg=70.0, dropout_full_deg=85.0,
                        outlier_fraction=0.0, drift_translation_std_m=3e-6, drift_rotation_std_rad=5e-6)  # fmt: skip


def _plane(n_side=40, spacing=1e-3, sigma=10e-6, cos=1.0, g=1.5):
    """A grid on the +z face, rays at incidence acos(cos) in the x-z plane."""
    x, y = np.meshgrid(np.arange(n_side) * -spacing, np.arange(n_side) * -spacing)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    direction = np.array([np.sqrt(1 - cos**2), 0.0, -cos])
    scan = crlb.ScanPoints(pts, np.tile(direction, (len(pts), 1)), np.full(len(pts), 2), np.eye(4))
    noise = SimpleNamespace(**{**vars(NOISE), "range_std_m": sigma, "grazing_exponent": g})
    return scan, noise


@pytest.mark.parametrize("cos", [1.0, 0.6])
def test_single_plane_offset_and_tilt_information_match_the_closed_form(cos):
    scan, noise = _plane(cos=cos)
    info = crlb.frame_information(scan, noise)
    sigma_n = 10e-6 * cos ** (1 - 1.5)  # the along-ray std projected on the normal
    n = len(scan.points)
    assert info[2, 2] == pytest.approx(n / sigma_n**2, rel=1e-12)  # normal offset: n / sigma^2
    # least-squares plane fit: var(height at the centroid) = sigma^2/n, var(slope) = sigma^2/sum (x - xbar)^2
    sub = np.linalg.inv(info[np.ix_([2, 3, 4], [2, 3, 4])])  # (do_z, omega_x, omega_y); slope_y = omega_x
    xbar, ybar = scan.points[:, 0].mean(), scan.points[:, 1].mean()
    grad = np.array([1.0, ybar, -xbar])  # height at the centroid: do_z + omega_x ybar - omega_y xbar
    assert grad @ sub @ grad == pytest.approx(sigma_n**2 / n, rel=1e-9)
    assert sub[1, 1] == pytest.approx(sigma_n**2 / np.sum((scan.points[:, 1] - ybar) ** 2), rel=1e-9)
    assert np.all(
        info[[0, 1, 5]] == 0
    )  # a plane says nothing about sliding in it or turning about its normal


def test_nominal_scan_matches_the_truth_world_ray_cast(lab):
    """The analytic cast against MuJoCo's (the block's hits; the wrist and the wire occlude a few)."""
    from vtestbed.world.rig import Rig
    from vtestbed.world.scanner import BLOCK_GEOM, Scanner

    rig = Rig()
    rig.command(np.radians([0.0, -60.0, -20.0, 30.0, 50.0, 45.0]))
    rig.hook("hook_x", "ring_5")
    block = rig.solve().block_pose
    scanner = Scanner.place(rig.lab, block)
    hits = scanner.cast(rig.model, rig.data)
    hits = hits.take(hits.geom_ids == rig.model.geom(BLOCK_GEOM).id)
    to_b = invert(block) @ scanner.pose_world
    pts_b = hits.points_m @ to_b[:3, :3].T + to_b[:3, 3]
    world = crlb.ScanPoints(pts_b, hits.directions @ to_b[:3, :3].T, np.argmax(pts_b, axis=1), to_b)
    ours = crlb.nominal_scan(rig.lab.block.edge, up_block=block[:3, :3].T @ [0, 0, 1])
    np.testing.assert_allclose(ours.scanner, to_b, atol=1e-9)
    assert abs(len(ours.points) / len(world.points) - 1) < 0.03
    j_world, j_ours = (np.linalg.inv(crlb.frame_information(s, NOISE)) for s in (world, ours))
    np.testing.assert_allclose(np.sqrt(np.diag(j_ours)), np.sqrt(np.diag(j_world)), rtol=0.03)


def _frame_error(fitted: np.ndarray, true: np.ndarray) -> np.ndarray:
    rel = invert(true) @ fitted
    return np.r_[rel[:3, 3], Rotation.from_matrix(rel[:3, :3]).as_rotvec()]


@pytest.mark.parametrize("drift", [False, True])
def test_monte_carlo_of_the_frame_fit_against_the_bound(lab, drift):
    """The researcher's own fit (fast path) on 150 noisy clouds; the bound lies below its scatter."""
    noise = NOISE if drift else SimpleNamespace(**{**vars(NOISE), "drift_translation_std_m": 0.0,
                                                   "drift_rotation_std_rad": 0.0})  # fmt: skip
    scan = crlb.nominal_scan(lab.block.edge)
    true = invert(scan.scanner)  # B in the scanner frame S
    pts_s = scan.points @ true[:3, :3].T + true[:3, 3]
    dirs_s = scan.directions @ true[:3, :3].T
    std = noise.range_std_m / scan.cos_incidence**noise.grazing_exponent
    rng = np.random.default_rng(7)
    errors = []
    for _ in range(150):
        cloud = pts_s + (rng.standard_normal(len(std)) * std)[:, None] * dirs_s
        rot = Rotation.from_rotvec(rng.standard_normal(3) * noise.drift_rotation_std_rad).as_matrix()
        cloud = cloud @ rot.T + rng.standard_normal(3) * noise.drift_translation_std_m
        errors.append(_frame_error(fit_block_frame(cloud, true).pose, true))
    observed = np.sqrt(np.mean(np.square(errors), axis=0))
    bound = np.sqrt(np.diag(crlb.frame_covariance(scan, noise)))
    ratio = observed / bound
    print("frame MC / CRLB (do_x..z, omega_x..z):", np.round(ratio, 3))
    assert np.all(ratio > 0.85), ratio  # a bound: no estimator beats it (150 draws: +-6 % scatter)
    if drift:  # the drift dominates: the fit is efficient
        assert np.all(ratio < 1.15), ratio
    else:  # three free planes, not the rigid block: the origin costs up to 1.6x, the rotation ~1x
        assert np.all(ratio[3:] < 1.2) and np.all(ratio[:3] < 1.8), ratio


def test_stiffness_bound_by_finite_differences_and_against_the_design_formula(robot, lab):
    q = np.radians([[0, -60, -20, 30, 50, 45], [20, -40, -30, -40, 60, 45], [-20, -70, 0, 60, 40, 0]])
    tests = design.candidate_tests(robot, q, lab=lab, clearance=False)[::5]
    a = np.array([t.a for t in tests])
    cov = crlb.pose_covariances(robot, [t.q for t in tests], NOISE, lab)
    bound = crlb.stiffness_bound(a, cov, K)
    # finite differences of the mean displacement d(k) = A (1/k): Fisher information in k directly
    h = 1e-6 * K
    grad = np.stack([(np.einsum("tkj,j->tk", a, 1 / (K + h * e)) - np.einsum("tkj,j->tk", a, 1 / (K - h * e)))
                     / (2 * h[i]) for i, e in enumerate(np.eye(6))], axis=-1)  # fmt: skip
    fisher = np.einsum("tki,tkl,tlj->ij", grad, np.linalg.inv(cov), grad)
    np.testing.assert_allclose(bound.stiffness_std, np.sqrt(np.diag(np.linalg.inv(fisher))), rtol=1e-6)
    # with the diagonal covariance of the design module, the design's predicted std
    sp, sr = 5.3e-6, 8.5e-6
    diag = np.diag([sp**2] * 3 + [sr**2] * 3)
    np.testing.assert_allclose(crlb.stiffness_bound(a, diag, K).stiffness_std,
                               design.evaluate(tests, K, sp, sr).stiffness_std, rtol=1e-9)  # fmt: skip
    # the per-frame bound sits at the measured displacement noise (5.3 um, 8.5 urad) of the pipeline
    rms_t = np.sqrt(np.mean(bound.displacement_std[:, :3] ** 2))
    rms_r = np.sqrt(np.mean(bound.displacement_std[:, 3:] ** 2))
    assert 4.5e-6 < rms_t <= 5.3e-6 * 1.05 and 7.5e-6 < rms_r <= 8.5e-6 * 1.05


def test_bad_input_names_the_field(lab):
    scan = crlb.nominal_scan(lab.block.edge)
    with pytest.raises(OutOfRangeError, match="noise needs the ScanNoise fields drift_rotation_std_rad"):
        crlb.frame_information(
            scan, SimpleNamespace(**{k: v for k, v in vars(NOISE).items() if "rotation" not in k})
        )
    with pytest.raises(OutOfRangeError, match="view_direction_block must have three positive components"):
        crlb.nominal_scan(lab.block.edge, view_direction_block=(1, 1, 0))
    with pytest.raises(OutOfRangeError, match=r"stiffness must be 6 positive values"):
        crlb.stiffness_bound(np.ones((2, 6, 6)), np.eye(6), -K)
