"""One test in the truth world: per-test random streams, the fixed draw order of the noisy
readings (restated with numpy alone), and the deterministic physics against closed forms."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vtestbed.world.physics import draw_readings, run_test_physics
from vtestbed.world.physics import test_rng as rng_of_test  # imported as test_rng, pytest would collect it
from vtestbed.world.rig import Rig
from vtestbed.world.scan_noise import ScanGeometry, ScanNoise
from vtestbed.world.sensors import ForceTorqueSensor

POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)


def test_a_tests_draws_do_not_depend_on_which_tests_ran_before():
    alone = rng_of_test(7, "identification", 3).standard_normal(5)
    for i in range(3):  # tests 0-2 run first and consume their own streams
        rng_of_test(7, "identification", i).standard_normal(1000)
    after = rng_of_test(7, "identification", 3).standard_normal(5)
    assert np.array_equal(alone, after)
    # the stream is numpy's SeedSequence(seed, spawn_key=(group, index)), group 0 / 1
    ref = np.random.default_rng(np.random.SeedSequence(7, spawn_key=(0, 3))).standard_normal(5)
    assert np.array_equal(alone, ref)
    val = np.random.default_rng(np.random.SeedSequence(7, spawn_key=(1, 3))).standard_normal(5)
    assert np.array_equal(rng_of_test(7, "validation", 3).standard_normal(5), val)
    assert not np.array_equal(val, ref) and not np.array_equal(
        rng_of_test(8, "identification", 3).standard_normal(5), ref
    )
    with pytest.raises(KeyError):
        rng_of_test(7, "calibration", 0)


def _hits(n=7):
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(n, 3)) + [0, 0, 4]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    normals = np.tile([0.0, 0.0, -1.0], (n, 1))
    return ScanGeometry(0.6 * dirs / dirs[:, 2:3], dirs, normals, np.zeros(n, int), np.arange(n))


def test_readings_are_drawn_scan_ft_scan_ft_in_a_fixed_order():
    h0, h1 = _hits(), _hits(5)
    w0, w1 = np.array([1.0, 2, 3, 0.1, 0.2, 0.3]), np.array([-50.0, 20, 180, 4, -3, 2])
    std = np.array([0.0625] * 3 + [0.0019] * 3)
    noise = ScanNoise(range_std_m=2e-5, grazing_exponent=1.0, outlier_fraction=0.0,
                      drift_translation_std_m=0.0, drift_rotation_std_rad=0.0)  # fmt: skip
    c0, r0, c1, r1 = draw_readings(h0, h1, w0, w1, noise, ForceTorqueSensor(noise_std=tuple(std)),
                                   np.random.default_rng(42))  # fmt: skip
    # restated with numpy: per scan 3 + 3 drift normals, n normals, 3 x n uniforms; then 6 normals
    rng = np.random.default_rng(42)
    expected = []
    for hits, wrench in ((h0, w0), (h1, w1)):
        n = len(hits)
        rng.standard_normal(6)
        g = rng.standard_normal(n)
        rng.random(3 * n)
        cos_i = -np.sum(hits.directions * hits.normals, axis=1)
        expected.append(hits.points_m + (g * 2e-5 / cos_i)[:, None] * hits.directions)
        expected.append(wrench + rng.normal(0.0, 1.0, 6) * std)
    for got, want in zip((c0, r0, c1, r1), expected):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    # a perfect scanner draws nothing: the readings are the F/T draws alone
    c0, r0, c1, r1 = draw_readings(h0, h1, w0, w1, None, ForceTorqueSensor(noise_std=tuple(std)),
                                   np.random.default_rng(42))  # fmt: skip
    rng = np.random.default_rng(42)
    assert np.array_equal(c0, h0.points_m) and np.array_equal(c1, h1.points_m)
    np.testing.assert_allclose(r0, w0 + rng.normal(0.0, 1.0, 6) * std, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r1, w1 + rng.normal(0.0, 1.0, 6) * std, rtol=0, atol=1e-15)


@pytest.fixture(scope="module")
def physics():
    rig = Rig()
    return rig, run_test_physics(rig, np.radians(POSE_DEG), "hook_y", "ring_4", 250.0, 0.7)


def test_true_displacement_is_the_block_motion_in_the_unloaded_block_frame(physics):
    _, phys = physics
    p0, p1 = phys.unloaded.block_pose, phys.loaded.block_pose
    r0 = p0[:3, :3]
    by_hand = np.r_[r0.T @ (p1[:3, 3] - p0[:3, 3]), Rotation.from_matrix(r0.T @ p1[:3, :3]).as_rotvec()]
    np.testing.assert_allclose(phys.displacement_true, by_hand, rtol=0, atol=1e-15)
    assert 1e-5 < np.linalg.norm(by_hand[:3]) < 1e-2  # a real deflection, well below a centimetre


def test_the_test_runs_at_the_asked_load_and_stand_off(physics):
    rig, phys = physics
    assert phys.unloaded.wire_tension == 0.0
    assert phys.loaded.wire_tension == pytest.approx(250.0, abs=1e-3)
    np.testing.assert_array_equal(phys.unloaded.q_cmd, np.radians(POSE_DEG))
    # the scanner looks at the unloaded block's centre from 0.7 m
    e = rig.lab.block.edge
    block = phys.unloaded.block_pose
    centre = block[:3, 3] + block[:3, :3] @ np.full(3, -e / 2)
    assert np.linalg.norm(centre - phys.scanner.pose_world[:3, 3]) == pytest.approx(0.7, abs=1e-12)
    # both casts see the block; the geometry is deterministic
    assert len(phys.hits_unloaded) > 10000 and len(phys.hits_loaded) > 10000
    again = run_test_physics(rig, np.radians(POSE_DEG), "hook_y", "ring_4", 250.0, 0.7)
    assert np.array_equal(again.hits_loaded.points_m, phys.hits_loaded.points_m)
    assert np.array_equal(again.displacement_true, phys.displacement_true)


def test_an_overloaded_sensor_states_the_largest_tension_its_test_allows():
    """The paper's second test (hook_edge to ring_2) overloads Fx at 500 N. The tension the error
    states as the largest is measured by the truth world itself (no overload), within 2 % of the
    sensor's limit on the binding axis, and 2 % more overloads it: the estimate from the unloaded
    and the overloaded wrench is safe and close, whatever the arm's deflection adds."""
    from conftest import paper_scenario_data

    from vtestbed.errors import SensorOverloadError
    from vtestbed.scenario import parse_scenario
    from vtestbed.world.truth import load_truth

    s = parse_scenario(paper_scenario_data(2, 1, "overload", 1))
    rig = Rig(s.robot, s.lab, truth=load_truth(s.robot_name))
    q, hook, anchor = s.poses[1], s.load.hooks[1], s.load.anchors[1]

    def physics(tension):
        return run_test_physics(rig, q, hook, anchor, tension, s.scanner.distance, clearance="off")

    with pytest.raises(
        SensorOverloadError, match=r"Fx = .* outside the measuring range \[-330, 330\] N"
    ) as exc:
        physics(500.0)
    top = exc.value.max_tension
    assert 300.0 < top < 500.0
    used = np.abs(physics(top).loaded.sensor_wrench) / s.lab.sensor.wrench_range
    assert 0.98 <= used.max() <= 1.0 and int(np.argmax(used)) == 0  # Fx binds, as at 500 N
    with pytest.raises(SensorOverloadError, match="Fx"):
        physics(1.02 * top)
