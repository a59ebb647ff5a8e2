"""The static solver (vtestbed.world.statics; Rig.solve, Rig.tighten) against independent references.

References: central differences of the generalized force (the tangent stiffness), a second
solver written here (Newton on a central-difference Jacobian, run to its own floor), Hooke's law
on MuJoCo's site geometry (the held tension), and the KR60 with its stiffness scaled by 1e-2 and
1e3 (the round-off test must scale with the robot: a fixed 1e-9 N*m is below the stiff one's floor).
"""

import dataclasses

import numpy as np
import pytest

from vtestbed.errors import ConvergenceError, OutOfRangeError, SensorOverloadError
from vtestbed.lab import LabSetup
from vtestbed.world import mjcf
from vtestbed.world.effects import (
    BaseCompliance,
    BlockOffset,
    GeometricError,
    GravityCompensator,
    JointCoupling,
    LinkCompliance,
    NonlinearJoint,
)
from vtestbed.world.rig import Rig

POSE = np.radians([10.0, -50.0, -30.0, 40.0, 60.0, 30.0])
ALL_EFFECTS = (
    LinkCompliance(),
    JointCoupling(),
    NonlinearJoint(),
    GravityCompensator(),
    BaseCompliance(),
    GeometricError(),
    BlockOffset(),
)


def _fd_tangent(rig: Rig, q: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """-d(generalized force)/dq by central differences [N*m/rad]."""
    out = np.empty((q.size, q.size))
    for k in range(q.size):
        dq = np.zeros(q.size)
        dq[k] = step
        out[:, k] = -(rig.generalized_force(q + dq) - rig.generalized_force(q - dq)) / (2 * step)
    return out


def _reference_equilibrium(rig: Rig, q: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, float]:
    """A second solver: plain Newton on a central-difference Jacobian; the best point seen and its
    max |residual| [N*m] (no tolerance: it runs to its own round-off floor)."""
    best_q, best_r = q.copy(), np.inf
    for _ in range(iterations):
        r = rig.generalized_force(q)
        if np.abs(r).max() < best_r:
            best_q, best_r = q.copy(), float(np.abs(r).max())
        q = q + np.linalg.solve(_fd_tangent(rig, q, 1e-7), r)
    return best_q, best_r


def _wire_tension_by_hand(rig: Rig, qpos: np.ndarray) -> float:
    """Hooke's law on the hook and anchor sites at ``qpos`` [N]."""
    rig.generalized_force(qpos)  # places the sites
    hook = rig.data.site_xpos[rig.model.site(mjcf.WIRE_HOOK_SITE).id]
    anchor = rig.data.site_xpos[rig.model.site(mjcf.WIRE_ANCHOR_SITE).id]
    rest = rig.model.tendon_lengthspring[rig.model.tendon(mjcf.WIRE_TENDON).id][1]
    ea = rig.lab.wire.axial_rigidity
    return float(ea * (np.linalg.norm(anchor - hook) - rest) / rest)


@pytest.mark.parametrize(
    "effects, external",
    [((), False), ((NonlinearJoint(),), False), ((JointCoupling(),), False), ((LinkCompliance(),), False),
     ((GravityCompensator(),), False), ((BaseCompliance(),), False), ((), True)],
    ids=["clean", "nonlinear_joint", "joint_coupling", "link_compliance", "gravity_compensator",
         "base_compliance", "external_wrench"],
)  # fmt: skip
def test_tangent_stiffness_matches_central_differences(robot, effects, external):
    rig = Rig(robot, effects=effects)
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    if external:
        # within the sensor's range beside the wire's 200 N: the F/T sensor reads the external
        # wrench too since 2026-12-01 (a body force on the tool, rig_readout.RigReadout._forces_for_readout)
        rig.apply_external_wrench([120.0, -80.0, 40.0], [4.0, -2.0, 1.2])
    q = rig.tighten(200.0).qpos_all
    k, ref = rig.tangent_stiffness(q), _fd_tangent(rig, q)
    # forward differences inside MuJoCo: ~3e-6 of each row's largest entry (measured)
    row = np.abs(ref).max(axis=1, keepdims=True)
    assert np.all(np.abs(k - ref) < 3e-5 * row), np.abs(k - ref).max(axis=1) / row[:, 0]
    if effects and isinstance(effects[0], NonlinearJoint):  # the effect's own term is in it
        dq = q[1] - POSE[1]
        assert 3 * effects[0].k3_Nm_per_rad3 * dq**2 > 1e3 * 3e-5 * row[1, 0]


@pytest.mark.parametrize("effects", [(), ALL_EFFECTS], ids=["clean", "all_effects"])
def test_solve_and_tighten_agree_with_a_second_solver(robot, effects):
    rig = Rig(robot, effects=effects)
    rig.command(POSE)
    rig.hook("hook_y", "ring_4")
    rng = np.random.default_rng(7)
    unloaded = rig.solve()
    ref, _ = _reference_equilibrium(rig, unloaded.qpos_all + rng.uniform(-1e-5, 1e-5, unloaded.qpos_all.size))
    np.testing.assert_allclose(unloaded.qpos_all, ref, rtol=0, atol=1e-12)
    loaded = rig.tighten(250.0)  # held tension, then the real wire at the rest length it implies
    assert abs(loaded.wire_tension - 250.0) < 1e-8
    ref, _ = _reference_equilibrium(rig, loaded.qpos_all + rng.uniform(-1e-5, 1e-5, loaded.qpos_all.size))
    np.testing.assert_allclose(loaded.qpos_all, ref, rtol=0, atol=1e-12)
    # the real wire at that rest length pulls the commanded tension (Hooke's law, site geometry);
    # 1e-12 rad of round-off in q moves it by EA/L * |J| * 1e-12 ~ 1e-6 N
    assert _wire_tension_by_hand(rig, ref) == pytest.approx(250.0, abs=1e-5)
    assert np.all(np.abs(rig.generalized_force(loaded.qpos_all)) <= rig.residual_tolerance(loaded.qpos_all))


@pytest.mark.parametrize("scale", [1e-2, 1.0, 1e3])
def test_the_round_off_test_scales_with_the_robot(robot, truth, scale):
    stiff = dataclasses.replace(truth, stiffness=tuple(k * scale for k in truth.stiffness))
    rig = Rig(robot, truth=stiff)
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    for solve in (rig.solve, lambda: rig.tighten(200.0)):
        state = solve()
        ref, floor = _reference_equilibrium(rig, state.qpos_all + 1e-6)
        np.testing.assert_allclose(state.qpos_all, ref, rtol=0, atol=1e-12)
        tol = rig.residual_tolerance(state.qpos_all)
        assert np.all(np.abs(rig.generalized_force(state.qpos_all)) <= tol)
        assert floor <= tol.max()  # the second solver's floor is within the tolerance too
        if scale == 1e3:  # a fixed 1e-9 N*m is out of reach here: the floor itself is above it
            assert floor > 1e-9


def test_the_tolerance_pins_every_joint_to_a_picoradian(robot):
    rig = Rig(robot)
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    q = rig.tighten(200.0).qpos_all
    tol = rig.residual_tolerance(q)
    assert np.all(np.abs(rig.generalized_force(q)) <= tol)
    for j in range(q.size):  # a 1e-12 rad error on any joint fails the test: it can fail
        dq = np.zeros(q.size)
        dq[j] = 1e-12
        assert np.any(np.abs(rig.generalized_force(q + dq)) > tol), j


def test_a_failed_tighten_leaves_the_wire_slack_and_names_the_residual(robot):
    rig = Rig(robot)
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    rig.solve()
    with pytest.raises(ConvergenceError, match=r"did not converge in 0 iterations: residual \|r\[\d\]\|"):
        rig.tighten(200.0, max_iterations=0)
    tendon = rig.model.tendon(mjcf.WIRE_TENDON).id
    assert rig.model.tendon_lengthspring[tendon][1] == mjcf.SLACK_LENGTH
    assert rig.solve().wire_tension == 0.0
    with pytest.raises(OutOfRangeError, match=r"max_iterations = -1 must be an integer >= 0"):
        rig.solve(max_iterations=-1)
    with pytest.raises(OutOfRangeError, match=r"tol = -1 N\*m is outside the valid range \[0, inf\]"):
        rig.solve(tol=-1.0)


def _random_tests(rig: Rig, n: int, seed: int) -> dict:
    """Run ``n`` sensor-feasible random tests (pose in the limits, hook, ring, 1 N up to the lab's limit)."""
    rng = np.random.default_rng(seed)
    hooks, rings = list(rig.lab.block.hooks), list(rig.lab.table.anchors)
    out = {"feasible": 0, "overloaded": 0, "worst_tension_error": 0.0, "worst_residual_ratio": 0.0}
    while out["feasible"] < n:
        rig.command(rng.uniform(rig.robot.lower, rig.robot.upper))
        rig.hook(hooks[rng.integers(len(hooks))], rings[rng.integers(len(rings))])
        rig.solve()
        tension = rng.uniform(*rig.lab.tension_range_N)
        try:
            state = rig.tighten(tension)  # a ConvergenceError fails the test
        except SensorOverloadError:
            out["overloaded"] += 1
            continue
        out["feasible"] += 1
        err = abs(state.wire_tension - tension)
        out["worst_tension_error"] = max(out["worst_tension_error"], err)
        ratio = np.max(np.abs(rig.generalized_force(state.qpos_all)) / rig.residual_tolerance(state.qpos_all))
        out["worst_residual_ratio"] = max(out["worst_residual_ratio"], ratio)
    return out


def _check_random(robot, n):
    # no payload limit: the sensor's 990 N range bounds the loads, the widest the solver meets
    out = _random_tests(Rig(robot, LabSetup(rated_payload_kg=None)), n, seed=2023)
    print(f"\n{n} random KR60 tests: {out}")
    assert out["feasible"] == n and out["worst_residual_ratio"] <= 1.0
    assert out["worst_tension_error"] < 1e-8  # holding the tension: ~1e-10 N, not TENSION_TOL


def test_random_kr60_tests_converge(robot):
    _check_random(robot, 50)


@pytest.mark.slow
def test_1000_random_kr60_tests_converge(robot):
    _check_random(robot, 1000)


def test_the_newton_inverse_is_numpys_and_a_singular_tangent_is_named():
    """LAPACK's LU inverse (statics._inverse) against np.linalg.inv on a KR60-like tangent (springs
    of 2e7-2e9 N*m/rad plus a dense gravity part), and a stiffness-free degree of freedom."""
    from vtestbed.world import statics

    rng = np.random.default_rng(3)
    gravity = rng.normal(scale=1e5, size=(6, 6))
    tangent = np.diag([2.2e9, 8.9e8, 1.1e9, 6.4e7, 2.5e7, 2.0e7]) + gravity @ gravity.T / 1e5
    np.testing.assert_allclose(statics._inverse(tangent), np.linalg.inv(tangent), rtol=1e-12, atol=0)
    tangent[:, 3] = tangent[3, :] = 0.0
    with pytest.raises(ConvergenceError, match="tangent stiffness is singular"):
        statics._inverse(tangent)


def test_newton_replaces_a_singular_or_rough_estimate_by_the_exact_tangent():
    """A linear spring system ``r(q) = -K (q - q*)`` with a dense K: the closed form ``q*`` is the
    reference. A singular estimate (a degree of freedom the joint springs do not hold) is
    replaced by the exact tangent at once; a rough one (K's diagonal) is a chord method that
    converges without it."""
    from vtestbed.world import statics

    rng = np.random.default_rng(5)
    springs = np.sqrt([4e6, 3e6, 2e6, 6e4, 3e4, 2e4])
    mix = rng.normal(size=(6, 6))
    # springs plus a dense part 4e-3 of them (||diag(K)^-1 K - I||), as gravity is on the KR60
    stiffness = np.diag(springs**2) + 1e-4 * springs[:, None] * (mix @ mix.T) * springs
    target = rng.normal(scale=1e-3, size=6)
    calls = []

    def residual(q):
        return -stiffness @ (q - target)

    def tangent(q):
        calls.append(q)
        return stiffness.copy()

    def tolerance(q, k):
        return statics.roundoff_tolerance(k, q, np.abs(stiffness) @ (np.abs(q) + 1e-3))

    singular = np.diag(stiffness).copy()
    singular[2] = 0.0
    eq = statics.newton(residual, tangent, tolerance, np.zeros(6), estimate=lambda q: np.diag(singular))
    np.testing.assert_allclose(eq.qpos, target, rtol=0, atol=1e-14)
    assert eq.tangent_calls == len(calls) == 1 and eq.iterations == 1  # exact tangent: one step
    calls.clear()
    eq = statics.newton(
        residual, tangent, tolerance, np.zeros(6), estimate=lambda q: np.diag(np.diag(stiffness))
    )
    np.testing.assert_allclose(eq.qpos, target, rtol=0, atol=1e-14)
    assert eq.tangent_calls == len(calls) == 0 and eq.iterations > 1  # chord steps only
