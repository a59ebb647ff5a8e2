import re

import numpy as np
import pytest

from vtestbed.errors import (
    ConvergenceError,
    JointLimitError,
    OutOfRangeError,
    SensorOverloadError,
    UnknownNameError,
)
from vtestbed.lab import LabSetup
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.robots import available_robots, load_robot
from vtestbed.transforms import displacement
from vtestbed.world.rig import Rig
from vtestbed.world.truth import load_truth

POSE = np.radians([5, -60, -20, 30, 50, 45])


@pytest.fixture(scope="module")
def rig():
    rig = Rig()
    rig.command(POSE)
    return rig


@pytest.fixture(scope="module")
def rig_no_gravity():
    return Rig(gravity=False)


def _compliance_prediction(robot, lab, q, wrench):
    """delta_d = J K^-1 J^T F at the block origin, base frame (the paper's model)."""
    jac = ArmKinematics(robot, lab.block_in_flange).jacobian(q)
    return jac @ ((jac.T @ wrench) / load_truth(robot.name).stiffness_true)


def test_small_wrench_displacement_matches_linear_compliance_model(rig_no_gravity, robot, lab):
    rig = rig_no_gravity
    rig.command(POSE)
    rig.slacken_wire()
    rig.apply_external_wrench(None)
    rest = rig.solve()
    np.testing.assert_allclose(rest.q, POSE, atol=1e-15)  # no load, no gravity: no deflection
    wrench = np.array([6.0, -8.0, 4.0, 0.3, -0.2, 0.25])
    rel = {}
    for scale in (1.0, 10.0, 100.0):
        rig.apply_external_wrench(scale * wrench[:3], scale * wrench[3:])
        loaded = rig.solve()
        measured = displacement(rest.block_pose, loaded.block_pose)
        predicted = _compliance_prediction(robot, lab, POSE, scale * wrench)
        rel[scale] = np.linalg.norm(measured - predicted) / np.linalg.norm(predicted)
    rig.apply_external_wrench(None)
    print(f"\nload-dependent Jacobian effect (relative deviation from J K^-1 J^T F): {rel}")
    assert rel[1.0] < 1e-4
    # The deviation is the neglected complementary stiffness: it grows linearly with the load.
    assert 5.0 < rel[10.0] / rel[1.0] < 20.0
    assert 5.0 < rel[100.0] / rel[10.0] < 20.0


def test_static_solver_residual_and_dynamic_settle_agree(rig):
    rig.hook("hook_x", "ring_5")
    state = rig.tighten(250.0)
    # the solver's own test: every residual component within its round-off tolerance
    assert np.all(np.abs(rig.generalized_force(state.qpos_all)) <= rig.residual_tolerance(state.qpos_all))
    assert state.residual < 1e-7  # N*m: about 1e-14 rad of the stiff joints
    settled = rig.settle(duration=3.0)  # from the commanded pose, mj_step with damping
    assert np.abs(settled.qpos_all - state.qpos_all).max() < 1e-8
    assert abs(settled.wire_tension - state.wire_tension) < 1e-3


@pytest.mark.parametrize(
    "anchor,hook,tension",
    [
        ("ring_5", "hook_x", 50.0),
        ("ring_1", "hook_y", 180.0),
        ("ring_9", "hook_edge", 120.0),
        ("ring_3", "hook_x", 300.0),
    ],
)
def test_tighten_reaches_target_tension(rig, anchor, hook, tension):
    rig.hook(hook, anchor)
    state = rig.tighten(tension)
    assert abs(state.wire_tension - tension) < 1e-8  # the tension is held, then the rest length set
    # independent: tension from Hooke's law on the wire's geometric length (MuJoCo site positions)
    anchor_pos = rig.lab.table.anchor(anchor)
    length = np.linalg.norm(anchor_pos - state.hook_position)
    ea = rig.lab.wire.axial_rigidity
    assert abs(ea * (length - state.wire_rest_length) / state.wire_rest_length - tension) < 0.1


def test_tighten_from_the_unloaded_tangent_lands_where_an_exact_tangent_does(rig):
    """A test tightens from its unloaded equilibrium's tangent and inverse (no tangent call); the
    same tighten from a cold start with MuJoCo's exact tangent at the unloaded equilibrium is the
    reference: same equilibrium to round-off, in fewer residual calls than the wire's ~85 of
    wave 1."""
    rig.hook("hook_x", "ring_5")
    unloaded = rig.solve()
    tangents0, calls0 = rig.tangent_calls, rig.residual_calls
    warm = rig.tighten(200.0)
    assert rig.tangent_calls == tangents0  # the unloaded tangent served
    assert rig.residual_calls - calls0 <= 8
    rig.slacken_wire()  # forgets the tangent
    rig._q_guess = unloaded.qpos_all.copy()
    rig._tangent_guess = (rig.tangent_stiffness(unloaded.qpos_all), None)  # exact, mjd_inverseFD
    exact = rig.tighten(200.0)
    np.testing.assert_allclose(warm.qpos_all, exact.qpos_all, rtol=0, atol=1e-12)
    np.testing.assert_allclose(warm.sensor_wrench, exact.sensor_wrench, rtol=1e-10, atol=1e-9)
    assert abs(warm.wire_tension - 200.0) < 1e-8 and abs(exact.wire_tension - 200.0) < 1e-8


def test_cold_solve_estimate_lands_where_newton_with_the_exact_tangent_does(rig):
    """A cold solve starts from the springs' tangent (no geometric terms, no tangent call); the
    reference is Newton with MuJoCo's exact tangent (mjd_inverseFD) from the same start. Same
    equilibrium to round-off, taut and slack, and the estimate is within 1 % of the exact
    tangent (``||K_est^-1 K - I||``, about 2e-3 here)."""
    from vtestbed.world import statics

    rig.hook("hook_y", "ring_2")
    rig.solve()
    rig.tighten(300.0)
    for taut in (True, False):
        if not taut:
            rig.slacken_wire()
        start = rig.model.qpos_spring.copy()
        rig._q_guess = start.copy()
        tangents0 = rig.tangent_calls
        state = rig.solve()
        assert rig.tangent_calls == tangents0  # the estimate served
        exact = statics.newton(rig._residual, rig.tangent_stiffness, rig._tolerance, start)
        np.testing.assert_allclose(state.qpos_all, exact.qpos, rtol=0, atol=1e-13)
        rig._residual(state.qpos_all)
        estimate = rig._tangent_estimate(state.qpos_all)
        error = np.linalg.solve(estimate, rig.tangent_stiffness(state.qpos_all)) - np.eye(6)
        assert np.linalg.norm(error, 2) < 1e-2
        if taut:  # the wire's axial term is in: without it the estimate is far off
            off = np.linalg.solve(rig._spring_tangent, rig.tangent_stiffness(state.qpos_all))
            assert np.linalg.norm(off - np.eye(6), 2) > 0.1


def _tool_side_load_by_hand(lab, flange_pose, tension, hook_world, anchor_world, gravity=9.81):
    """Weight of what hangs below the sensor plus the wire force, in the sensor frame."""
    sensor, block = lab.sensor, lab.block
    # masses and centres of mass in the sensor frame (geometry of vtestbed.lab, by hand)
    parts = [
        (sensor.mass_tool_side, np.array([0, 0, -sensor.height / 4])),
        (block.stem_mass, np.array([0, 0, block.standoff / 2])),
        (block.mass, np.array([0, 0, block.standoff + block.edge / 2])),
    ]
    mass = sum(m for m, _ in parts)
    com = sum(m * c for m, c in parts) / mass
    sensor_pose = flange_pose @ lab.sensor_in_flange
    rot, origin = sensor_pose[:3, :3], sensor_pose[:3, 3]
    weight_world = np.array([0.0, 0.0, -mass * gravity])
    wire_world = tension * (anchor_world - hook_world) / np.linalg.norm(anchor_world - hook_world)
    force_world = weight_world + wire_world
    torque_world = np.cross(rot @ com, weight_world) + np.cross(hook_world - origin, wire_world)
    return np.concatenate([rot.T @ force_world, rot.T @ torque_world])


def test_force_sensor_reads_wire_force_plus_weight(rig, lab):
    rig.hook("hook_y", "ring_2")
    slack = rig.solve()
    assert slack.wire_tension == 0.0
    expected_slack = _tool_side_load_by_hand(
        lab, slack.flange_pose, 0.0, slack.hook_position, lab.table.anchor("ring_2")
    )
    np.testing.assert_allclose(slack.sensor_wrench, expected_slack, atol=1e-9)
    loaded = rig.tighten(220.0)
    expected = _tool_side_load_by_hand(
        lab, loaded.flange_pose, loaded.wire_tension, loaded.hook_position, lab.table.anchor("ring_2")
    )
    np.testing.assert_allclose(loaded.sensor_wrench, expected, atol=1e-6)


def test_slack_wire_applies_nothing(rig):
    rig.hook("hook_x", "ring_5")
    rig.slacken_wire()
    slack = rig.solve()
    # pull the anchor far away with the wire slack: nothing changes
    rig.hook(anchor="ring_9")
    again = rig.solve()
    assert slack.wire_tension == again.wire_tension == 0.0
    np.testing.assert_allclose(again.q, slack.q, atol=1e-14)


def test_bad_inputs_get_clear_errors(rig):
    with pytest.raises(JointLimitError, match=r"joint2 = 40\.000 deg .*\[-135\.0, 35\.0\]"):
        rig.command(np.radians([0, 40, 0, 0, 0, 0]))
    with pytest.raises(UnknownNameError, match="ring_1, ring_2"):
        rig.hook(anchor="ring_42")
    with pytest.raises(UnknownNameError, match="hook_edge, hook_x, hook_y"):
        rig.hook(hook="eye")
    with pytest.raises(
        UnknownNameError,
        match=re.escape(f"unknown robot 'kuka_kr6'; valid names: {', '.join(available_robots())}"),
    ):
        load_robot("kuka_kr6")
    for tension in (-5.0, 0.0, 0.5, 600.0, float("nan")):  # the lab's one tension rule
        with pytest.raises(OutOfRangeError, match=r"wire tension .* \[1, 588\.6\] N .*rated payload"):
            rig.tighten(tension)
    heavy = Rig(lab=LabSetup(rated_payload_kg=None))  # no payload limit: the sensor's range binds
    heavy.command(POSE)
    heavy.hook("hook_edge", "ring_9")
    with pytest.raises(
        SensorOverloadError, match=r"T[xyz] = .* outside the measuring range \[-30, 30\] N\*m"
    ):
        heavy.tighten(900.0)
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    rig.slacken_wire()
    with pytest.raises(ConvergenceError, match="did not converge in 1 iterations"):
        Rig().solve(max_iterations=1, tol=1e-14)
