"""The static solver on random feasible tests of every robot under models/ (the robot's own lab).

A feasible test: a pose drawn uniformly within the joint limits, a hook, a ring and a tension
drawn uniformly in the lab's range (1 N up to its max_tension_N) that the rig accepts (the
sensor's wrench in range). The quick test also asks the nominal clearance check (links, sensor
and block off the table and the floor, the wire clear, the scanner's view open:
docs/clearance.md); the 1000-test one does not (the check costs 15 ms a draw and refuses 70-90 %
of them: minutes), so it covers a superset of the tests a lab can run; 10 (100 in the slow
run) clear tests per robot check that subset itself. Everything is drawn
from one seeded numpy Generator per robot.

References, independent of the solver: the net generalized force recomputed with MuJoCo's own
``mj_forward`` at the solution (``qfrc_passive - qfrc_bias``) against the size of the forces it
sums, and the wire tension from Hooke's law on MuJoCo's site geometry.
"""

import time

import mujoco
import numpy as np
import pytest

from vtestbed.design.clearance import NominalClearance
from vtestbed.errors import SensorOverloadError
from vtestbed.robot_lab import lab_for_robot
from vtestbed.robots import available_robots, load_robot
from vtestbed.world import mjcf
from vtestbed.world.rig import Rig
from vtestbed.world.truth import load_truth

EPS = np.finfo(float).eps


def _residual_by_mujoco(rig: Rig, data: mujoco.MjData, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r, scale) [N*m] from ``data`` (not the rig's): r = qfrc_passive - qfrc_bias at qvel = 0,
    and the size of what it sums, ``|qfrc_passive| + |qfrc_bias| + k_j (|q_j| + 1)``: the spring
    torque ``k_j (q_j - q_ref)`` carries the round-off of ``q_j`` and ``q_ref`` times ``k_j``."""
    data.qpos[:] = qpos
    data.qvel[:] = 0.0
    mujoco.mj_forward(rig.model, data)
    springs = rig.model.jnt_stiffness[rig.model.dof_jntid] * (
        np.abs(qpos[rig.model.jnt_qposadr[rig.model.dof_jntid]]) + 1
    )
    return data.qfrc_passive - data.qfrc_bias, np.abs(data.qfrc_passive) + np.abs(data.qfrc_bias) + springs


def _tension_by_hooke(rig: Rig, data: mujoco.MjData) -> float:
    """Hooke's law on the hook and anchor sites of ``data`` (after :func:`_residual_by_mujoco`) [N]."""
    hook = data.site_xpos[rig.model.site(mjcf.WIRE_HOOK_SITE).id]
    anchor = data.site_xpos[rig.model.site(mjcf.WIRE_ANCHOR_SITE).id]
    rest = rig.model.tendon_lengthspring[rig.model.tendon(mjcf.WIRE_TENDON).id][1]
    return float(rig.lab.wire.axial_rigidity * (np.linalg.norm(anchor - hook) - rest) / rest)


def random_feasible_tests(name: str, n: int, seed: int, clear: bool) -> dict:
    """Solve ``n`` random feasible tests of robot ``name`` (``clear``: also clear under the nominal
    clearance check); the worst figures and the draw counts."""
    robot = load_robot(name)
    lab = lab_for_robot(robot)
    rig = Rig(robot, lab, truth=load_truth(name))
    data = mujoco.MjData(rig.model)
    clearance = NominalClearance(robot, lab, lab.scanner_distance)
    rng = np.random.default_rng(seed)
    hooks, rings = list(lab.block.hooks), list(lab.table.anchors)
    out = {"feasible": 0, "drawn": 0, "not_clear": 0, "overloaded": 0, "worst_residual_eps": 0.0,
           "worst_tolerance_ratio": 0.0, "worst_tension_error_N": 0.0, "max_iterations": 0}  # fmt: skip
    t0 = time.perf_counter()
    while out["feasible"] < n:
        out["drawn"] += 1
        q = rng.uniform(robot.lower, robot.upper)
        hook, ring = hooks[rng.integers(len(hooks))], rings[rng.integers(len(rings))]
        tension = rng.uniform(*lab.tension_range_N)
        if clear and not clearance.check(q, hook, ring).ok:
            out["not_clear"] += 1
            continue
        rig.command(q)
        rig.hook(hook, ring)
        rig.solve()  # a ConvergenceError fails the test
        try:
            state = rig.tighten(tension)
        except SensorOverloadError:
            out["overloaded"] += 1
            continue
        out["feasible"] += 1
        out["max_iterations"] = max(out["max_iterations"], state.iterations)
        r, scale = _residual_by_mujoco(rig, data, state.qpos_all)
        out["worst_residual_eps"] = max(out["worst_residual_eps"], np.max(np.abs(r) / scale) / EPS)
        tol = rig.residual_tolerance(state.qpos_all)
        out["worst_tolerance_ratio"] = max(out["worst_tolerance_ratio"], np.max(np.abs(r) / tol))
        err = abs(_tension_by_hooke(rig, data) - tension)
        out["worst_tension_error_N"] = max(out["worst_tension_error_N"], err)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def _check(name: str, n: int, clear: bool):
    out = random_feasible_tests(name, n, seed=2023, clear=clear)
    print(f"\n{name}: {n} random feasible tests (clearance {clear}): {out}")
    assert out["feasible"] == n and out["max_iterations"] <= 10
    # round-off: each component within 64 eps of the size of the forces it sums (measured: 16)
    assert out["worst_residual_eps"] <= 64.0
    assert out["worst_tolerance_ratio"] <= 1.0  # and within the solver's own floor
    # Hooke's law at the solution: the wire pulls what was asked (measured: 3e-10 N)
    assert out["worst_tension_error_N"] < 1e-8


@pytest.mark.parametrize("name", available_robots())
def test_1000_random_feasible_tests_converge(name):
    _check(name, 1000, clear=False)  # about 1 s a robot


@pytest.mark.parametrize("name", available_robots())
def test_random_clear_tests_converge(name):
    _check(name, 10, clear=True)


@pytest.mark.slow
@pytest.mark.parametrize("name", available_robots())
def test_100_random_clear_tests_converge(name):
    _check(name, 100, clear=True)  # UR10: 20 s, 9 of 10 draws refused by the clearance check
