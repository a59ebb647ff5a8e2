"""Criterion evaluations per second (vectorised numpy DH vs per-pose Pinocchio), and the time of
the optimiser, the joint 2-3 map, the influence analysis and a D-optimal test selection.

Run: .venv/bin/python benchmarks/bench_poses.py
"""

from __future__ import annotations

import time

import numpy as np

from vtestbed.design import influence, kappa, regions
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5  # noqa: E402
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.robots import load_robot


def best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def pinocchio_criterion(kin: ArmKinematics, q: np.ndarray) -> float:
    wrist = np.linalg.inv(kin.flange_pose(q)) @ kin.joint_poses(q)[4]
    jac = kin.jacobian(q, tool_in_flange=wrist)
    return float(kappa.inv_kappa_frobenius(jac[:3, :3]) * kappa.inv_kappa_frobenius(jac[3:, 3:]))


def main() -> None:
    robot = load_robot()
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.lower, robot.upper, (200_000, 6))
    t = best_of(lambda: kappa.inv_kappa_batch(robot, q))
    print(
        f"vectorised numpy criterion: {q.shape[0] / t / 1e6:6.2f} M poses/s ({t * 1e9 / q.shape[0]:.0f} ns/pose)"
    )
    kin = ArmKinematics(robot)
    few = q[:2000]
    t = best_of(lambda: [pinocchio_criterion(kin, x) for x in few])
    print(
        f"per-pose Pinocchio criterion: {few.shape[0] / t / 1e3:6.1f} k poses/s ({t * 1e6 / few.shape[0]:.1f} us/pose)"
    )
    t = best_of(lambda: kappa.criterion(robot, q[0]), 200)
    print(f"kappa.criterion (one pose, checks included): {t * 1e6:.1f} us")
    opt = None

    def run_opt():
        nonlocal opt
        opt = kappa.optimize(robot, seed=0)

    print(f"optimize (DE + polish, wrist): {best_of(run_opt) * 1e3:.0f} ms, {opt.nfev} poses")
    print(f"joint 2-3 map at 0.5 deg: {best_of(lambda: regions.joint_plane_map(robot, opt.q)) * 1e3:.0f} ms")
    print(
        f"influence (4 joints, 721 samples, fd): {best_of(lambda: influence.joint_influence(robot, opt.q)) * 1e3:.0f} ms"
    )
    pmap = regions.joint_plane_map(robot, opt.q, step_deg=1.0)
    found = regions.find_regions(pmap)
    sample = regions.sample_poses(robot, pmap, found, 40, rng, wrist_jitter_deg=30, threshold=0.7)
    t0 = time.perf_counter()
    cands = design.candidate_tests(robot, sample.q)
    t_cand = time.perf_counter() - t0
    k = PAPER_TABLE5.stiffness
    t = best_of(lambda: design.select_tests(cands, 10, k, criterion="D", method="exchange"))
    print(
        f"{len(cands)} candidate tests from 40 poses: {t_cand * 1e3:.0f} ms; D-optimal exchange of 10: {t * 1e3:.1f} ms"
    )


if __name__ == "__main__":
    main()
