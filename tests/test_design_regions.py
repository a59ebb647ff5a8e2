"""Criterion maps, high-criterion regions, lab constraints and pose sampling, against the paper's
regions, Pinocchio block positions and maps with known analytic peaks."""

import json

import numpy as np
import pytest

from vtestbed.design import kappa, regions
from vtestbed.researcher.kinematics import ArmKinematics


@pytest.fixture(scope="module")
def plane(robot, optimum):
    return regions.joint_plane_map(robot, optimum.q, step_deg=1.0)


def test_four_regions_at_the_expected_peaks(robot, plane):
    found = regions.find_regions(plane)
    peaks = {r.name: np.degrees(r.peak) for r in found}
    assert list(peaks) == ["Z1", "Z2", "Z3", "Z4"]
    expected = {"Z1": (-121.49, 52.18), "Z2": (-124.21, -193.35), "Z3": (-8.02, 52.18), "Z4": (6.66, -210.0)}
    for name, (t2, t3) in expected.items():  # local optima from Nelder-Mead refinement (mirror pairs)
        np.testing.assert_allclose(peaks[name], (t2, t3), atol=1.01)
    values = {r.name: r.peak_value for r in found}
    assert values["Z1"] == pytest.approx(values["Z3"], abs=1e-3)  # same wrist centre, mirrored elbow


def test_constraints_exclude_the_regions_the_paper_excludes(robot, lab, plane):
    box = regions.PoseConstraints(min_height=0.8, box_min=(0.3, -1, 0), box_max=(2.3, 1, 2.2))
    found = {r.name: r for r in regions.restrict(regions.find_regions(plane), plane, robot, box)}
    assert "lab box" in found["Z2"].excluded  # behind the robot
    assert "below z = 0.8 m" in found["Z3"].excluded  # too close to the floor
    assert found["Z1"].excluded is None and found["Z4"].excluded is None
    draw = [regions.sample_poses(robot, plane, found.values(), 12, np.random.default_rng(9), constraints=box,
                                 wrist_jitter_deg=20, threshold=0.7) for _ in range(2)]  # fmt: skip
    np.testing.assert_array_equal(draw[0].q, draw[1].q)
    assert set(draw[0].regions) == {"Z1", "Z4"} and np.all(box.ok(robot, draw[0].q))
    np.testing.assert_allclose(draw[0].inv_kappa, kappa.inv_kappa_batch(robot, draw[0].q), rtol=1e-12)
    assert draw[0].inv_kappa.min() >= 0.7
    kin = ArmKinematics(robot, lab.block_in_flange)  # independent check of the block positions
    block = np.array([kin.tool_pose(q)[:3, 3] for q in draw[0].q])
    assert block[:, 2].min() >= 0.8 and np.all((block >= (0.3, -1, 0)) & (block <= (2.3, 1, 2.2)))


def test_cartesian_map_holds_the_plane_maximum(robot, optimum, plane):
    cmap = regions.cartesian_map(robot, optimum.q, step_deg=1.0, bin_size=0.05)
    assert np.nanmax(cmap.values) == pytest.approx(plane.values.max(), abs=1e-12)
    assert np.nanmin(cmap.values) >= 0.0


# A synthetic map: Gaussian bumps (theta2, theta3 [deg], height, sigma [deg]) on the joint limits'
# 1-deg grid, combined by their maximum, so each bump's peak and level set are known exactly.
BUMPS = {
    "A": (-100.0, 40.0, 0.95, 12.0),
    "B": (-100.0, -150.0, 0.85, 10.0),
    "C": (0.0, 0.0, 0.90, 15.0),
    "low": (-50.0, -50.0, 0.65, 10.0),  # below the threshold: no region
    "tiny": (20.0, -180.0, 0.705, 2.0),  # above it on a single cell: fewer than min_cells
}


def _bump_values(t2_deg, t3_deg):
    g2, g3 = np.meshgrid(t2_deg, t3_deg, indexing="ij")
    return np.max(
        [h * np.exp(-((g2 - a) ** 2 + (g3 - b) ** 2) / (2 * s**2)) for a, b, h, s in BUMPS.values()], axis=0
    )


@pytest.fixture(scope="module")
def bumps(robot, optimum):
    t2, t3 = np.arange(-135.0, 35.5, 1.0), np.arange(-210.0, 68.5, 1.0)
    return regions.JointPlaneMap(
        np.radians(t2), np.radians(t3), _bump_values(t2, t3), optimum.q.copy(), "wrist"
    )


def _disc_cells(name, threshold=0.7):
    """Grid cells of the bump's level set {h exp(-d^2 / 2 s^2) >= threshold}, counted by hand."""
    a, b, h, s = BUMPS[name]
    g2, g3 = np.meshgrid(np.arange(-135.0, 35.5, 1.0), np.arange(-210.0, 68.5, 1.0), indexing="ij")
    return ((g2 - a) ** 2 + (g3 - b) ** 2) <= 2 * s**2 * np.log(h / threshold)


def test_regions_of_a_map_with_known_peaks(bumps):
    found = regions.find_regions(bumps, threshold=0.7)
    # columns left to right in theta_2, within a column theta_3 from high to low
    assert [r.name for r in found] == ["Z1", "Z2", "Z3"]
    for region, bump in zip(found, ("A", "B", "C")):
        a, b, h, _ = BUMPS[bump]
        np.testing.assert_allclose(np.degrees(region.peak), (a, b), atol=1e-9)
        assert region.peak_value == pytest.approx(h, rel=1e-12)
        disc = _disc_cells(bump)
        assert region.cells == disc.sum() > 100
        assert np.array_equal(region.mask, disc)
        d = region.to_dict(bumps)
        assert d["area_deg2"] == pytest.approx(disc.sum() * 1.0, rel=1e-9)  # 1 deg x 1 deg cells
        r = np.sqrt(2 * BUMPS[bump][3] ** 2 * np.log(h / 0.7))  # the level set's radius [deg]
        assert d["q2_deg_range"] == pytest.approx([a - np.floor(r), a + np.floor(r)], abs=1e-9)
    # a lower threshold lets the low bump in, as the fourth region in its own column
    lower = regions.find_regions(bumps, threshold=0.6)
    assert [np.degrees(r.peak).round(6).tolist() for r in lower][2] == [-50.0, -50.0]
    assert lower[2].cells == _disc_cells("low", 0.6).sum()
    with pytest.raises(regions.OutOfRangeError, match=r"threshold = 1 is outside the valid range \(0, 1\)"):
        regions.find_regions(bumps, threshold=1.0)


def test_restrict_removes_the_cells_below_the_height_pinocchio_gives(robot, lab, bumps):
    found = regions.find_regions(bumps)
    z1 = found[0]
    kin = ArmKinematics(robot, lab.block_in_flange)
    poses = bumps.poses().reshape(*bumps.values.shape, 6)
    cells = np.argwhere(z1.mask)
    z = np.array([kin.tool_pose(poses[i, j])[2, 3] for i, j in cells])
    height = float(np.median(z))
    kept = regions.restrict(found, bumps, robot, regions.PoseConstraints(min_height=height))
    expected = np.zeros_like(z1.mask)
    expected[tuple(cells[z >= height].T)] = True
    assert np.array_equal(kept[0].mask, expected) and kept[0].excluded is None
    assert kept[0].removed.sum() == (z < height).sum() > 0
    # a height above the whole region excludes it, saying why
    gone = regions.restrict(found, bumps, robot, regions.PoseConstraints(min_height=z.max() + 0.01))
    assert gone[0].excluded == f"100.0% of its cells: block below z = {z.max() + 0.01:g} m"


def test_sampled_poses_come_from_their_regions_cells(robot, bumps):
    found = regions.find_regions(bumps)
    draw = regions.sample_poses(robot, bumps, found, 9, np.random.default_rng(2), wrist_jitter_deg=10.0)
    assert draw.regions == ("Z1", "Z2", "Z3") * 3  # the regions take turns
    by_name = {r.name: r for r in found}
    for q, name in zip(draw.q, draw.regions):
        i2 = int(np.round(np.degrees(q[1]) + 135.0))  # nearest cell of the 1-deg grid
        i3 = int(np.round(np.degrees(q[2]) + 210.0))
        assert by_name[name].mask[i2, i3]
        np.testing.assert_array_equal(q[[0, 5]], bumps.q_fixed[[0, 5]])
        assert np.all(np.abs(np.degrees(q[3:5] - bumps.q_fixed[3:5])) <= 10.0)
    np.testing.assert_allclose(draw.inv_kappa, kappa.inv_kappa_batch(robot, draw.q), rtol=1e-12)
    with pytest.raises(regions.UnknownNameError, match="unknown region 'Z9'; valid names: Z1, Z2, Z3"):
        regions.sample_poses(robot, bumps, found, 3, np.random.default_rng(0), select=["Z9"])
    with pytest.raises(regions.OutOfRangeError, match=r"n = 0 poses is outside the valid range \[1, inf\)"):
        regions.sample_poses(robot, bumps, found, 0, np.random.default_rng(0))


def test_cartesian_bins_hold_the_best_value_reaching_them(robot, optimum):
    cmap = regions.cartesian_map(robot, optimum.q, step_deg=5.0, bin_size=0.1)
    pmap = regions.joint_plane_map(robot, optimum.q, step_deg=5.0)
    kin = ArmKinematics(robot)
    best = {}
    for q, v in zip(pmap.poses(), pmap.values.ravel()):
        w = kin.joint_poses(q)[4][:3, 3]  # the wrist centre, by Pinocchio
        key = (int(np.floor((w[0] - cmap.x_edges[0]) / 0.1)), int(np.floor((w[2] - cmap.z_edges[0]) / 0.1)))
        best[key] = max(best.get(key, -1.0), v)
    np.testing.assert_allclose(np.diff(cmap.x_edges), 0.1, rtol=1e-9)
    np.testing.assert_allclose(np.diff(cmap.z_edges), 0.1, rtol=1e-9)
    expected = np.full(cmap.values.shape, np.nan)
    for (ix, iz), v in best.items():
        expected[ix, iz] = v
    np.testing.assert_allclose(cmap.values, expected, rtol=1e-12)
    assert len(best) > 50


def test_bad_constraints_and_steps_are_refused(robot, optimum):
    with pytest.raises(regions.OutOfRangeError, match="box_min and box_max must be given together"):
        regions.PoseConstraints(box_min=(0, 0, 0))
    with pytest.raises(
        regions.OutOfRangeError,
        match=r"box_min \[0, 2, 0\] must be below box_max \[1, 1, 1\] on every axis \[m\]",
    ):
        regions.PoseConstraints(box_min=(0, 2, 0), box_max=(1, 1, 1))
    with pytest.raises(
        regions.OutOfRangeError, match=r"step_deg = 20 deg is outside the valid range \[0.01, 10\] deg"
    ):
        regions.joint_plane_map(robot, optimum.q, step_deg=20.0)


def test_cli_runs_regions_and_design_on_the_offset_wrist_ur10(tmp_path, capsys):
    from vtestbed.cli.main import main
    from vtestbed.robots import load_robot

    ur10 = load_robot("ur10")
    base = ["--robot", "ur10", "--step-deg", "2", "--n", "30"]  # the UR10 lab's block zone
    assert main(["poses", "regions", *base, "--out", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)
    q = np.radians(out["poses"]["q_deg"])
    assert np.all((q >= ur10.lower) & (q <= ur10.upper))
    np.testing.assert_allclose(out["poses"]["inv_kappa"], kappa.inv_kappa_batch(ur10, q), rtol=1e-12)
    assert min(out["poses"]["inv_kappa"]) >= 0.7 and not out["wrist"]["spherical"]
    d5 = ur10.joints[4].d  # the least-squares point lies halfway between axes 4 and 6 on axis 5
    np.testing.assert_allclose(out["wrist"]["wrist_axis_distances_m_max"], [d5 / 2, 0, d5 / 2], atol=1e-12)
    prior = ["--stiffness-prior", "1.32e8,1.32e8,6e7,2.16e7,2.16e7,2.16e7", "--tests", "6"]
    poses = ["--robot", "ur10", "--poses", str(tmp_path / "poses.json")]
    for clearance in ([], ["--no-clearance"]):  # link 1 stands on the base: not checked against the floor
        assert main(["poses", "design", *poses, *prior, *clearance]) == 0
        std = json.loads(capsys.readouterr().out)["selection"]["relative_std_percent"]
        assert len(std) == 6 and all(np.isfinite(std)) and min(std) > 0
