"""Criterion evaluations per second (vectorised numpy DH vs per-pose Pinocchio), and the time of
the optimiser, the joint 2-3 map, the influence analysis and a D-optimal test selection.

Then the design comparison (issue 16): the worst joint's predicted relative std (SIGMA_P, SIGMA_R,
prior = the paper's Table 5) of the paper's kappa selection and of the minimax, A- and D-optimal
choices from a random feasible pool, at 12 and 20 tests, tensions up to 200 N and up to the lab's
limit, with each design's chosen / lower bound (minimax) and the times.

Run: .venv/bin/python benchmarks/bench_poses.py [--pool-poses 400] [--no-basics]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vtestbed.design import influence, kappa, minimax, pool, regions
from vtestbed.design import optimal as design
from vtestbed.design.priors import PAPER_TABLE5  # noqa: E402
from vtestbed.lab import PAPER_LAB
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


def design_comparison(robot, n_poses: int):
    """Minimax vs kappa vs A vs D at 12 and 20 tests, at 200 N and at the lab's limit."""
    k, lab = PAPER_TABLE5.stiffness, PAPER_LAB
    opt = kappa.optimize(robot, point="wrist", seed=0, q6=np.radians(45.0))
    pmap = regions.joint_plane_map(robot, opt.q, "wrist", step_deg=1.0)
    cons = pool.zone_constraints(lab)
    found = regions.restrict(regions.find_regions(pmap, threshold=0.7), pmap, robot, cons)
    region_q = regions.sample_poses(robot, pmap, found, 200, np.random.default_rng(0), constraints=cons,
                                    wrist_jitter_deg=30.0, threshold=0.7).q  # fmt: skip
    poses = pool.random_poses(robot, lab, n_poses, np.random.default_rng(0))
    top = lab.max_tension[0]
    print(
        f"\ndesign comparison: worst joint's predicted std(k)/k [%] (prior = truth), pool of {n_poses} random poses"
    )
    print(f"{'tension':>18s} {'n':>3s} {'kappa':>7s} {'minimax':>8s} {'A':>7s} {'D':>7s} {'bound':>7s}"
          f" {'mm/bound':>8s} {'mm/kappa':>8s} {'time mm':>8s}")  # fmt: skip
    pools = {}
    for tension in (200.0, top):
        t0 = time.perf_counter()
        cands = pools[tension] = pool.candidate_pool(robot, lab, poses=poses, max_tension=tension)
        t_pool = time.perf_counter() - t0
        for n in (12, 20):
            kap = design.evaluate(pool.kappa_selection(robot, region_q, n, 200.0, lab), k).minimax_value
            t0 = time.perf_counter()
            mm = minimax.design(cands.a, n, k, "minimax")
            t_mm = time.perf_counter() - t0
            worst = {
                c: minimax.design(cands.a, n, k, c, bound=False).selection.report.minimax_value for c in "AD"
            }
            w = mm.selection.report.minimax_value
            lb = np.sqrt(mm.relaxation.bound)
            print(f"{f'<= {tension:g} N':>18s} {n:3d} {kap * 100:7.3f} {w * 100:8.3f} {worst['A'] * 100:7.3f}"
                  f" {worst['D'] * 100:7.3f} {lb * 100:7.3f} {w / lb:8.3f} {w / kap:8.3f} {t_mm:7.1f}s")  # fmt: skip
        print(f"{'':18s} pool: {len(cands)} candidates, {cands.refused}, built in {t_pool:.1f} s")
    print("kappa: the paper's selection (region poses in draw order, 200 N); mm = minimax")
    return pools


def sequential_study(cands, seeds: int = 5) -> None:
    """Prior off by x2 or x0.5 per joint (random signs): a fixed 20-test design against pilot 8 +
    6 + 6 tests, each batch chosen from the current estimate (drawn from the linear model's exact
    estimator distribution, c_hat ~ N(c_true, M^-1)); worst joint's std at the truth over the
    true-prior 20-test design's."""
    k = PAPER_TABLE5.stiffness
    a = cands.a
    best = design.evaluate(a[list(minimax.design(a, 20, k).selection.indices)], k).minimax_value
    print(
        f"\nsequential design, tensions up to {max(cands.tensions):g} N: true-prior 20 tests {best * 100:.3f} %"
    )
    print(
        f"{'seed':>4s} {'prior factors':>28s} {'fixed/true':>10s} {'seq/true':>9s} {'pilot est. err [%]':>30s}"
    )
    ratios = []
    for seed in range(seeds):
        rng = np.random.default_rng(100 + seed)
        f = 2.0 ** rng.choice([-1.0, 1.0], 6)
        fixed = minimax.design(a, 20, k * f).selection.indices
        worst_fixed = design.evaluate(a[list(fixed)], k).minimax_value
        chosen = list(minimax.design(a, 8, k * f).selection.indices)
        m0 = design.information_matrix(a[chosen])
        errs = None
        for batch in (6, 6):
            c_hat = 1 / k + np.linalg.cholesky(np.linalg.inv(m0)) @ rng.standard_normal(6)
            if errs is None:
                errs = (1 / c_hat) / k - 1
            nxt = minimax.design(a, batch, 1 / c_hat, base_information=m0).selection.indices
            chosen += list(nxt)
            m0 = design.information_matrix(a[chosen])
        worst_seq = design.evaluate(a[chosen], k).minimax_value
        ratios.append(worst_seq / best)
        print(f"{seed:4d} {str(f.tolist()):>28s} {worst_fixed / best:10.3f} {worst_seq / best:9.3f} "
              f"{str(np.round(errs * 100, 2).tolist()):>30s}")  # fmt: skip
    print(f"sequential / true-prior: mean {np.mean(ratios):.3f}, worst {np.max(ratios):.3f} (target <= 1.2)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pool-poses", type=int, default=400, help="random poses of the design pool")
    parser.add_argument("--no-basics", action="store_true", help="only the design comparison")
    args = parser.parse_args()
    robot = load_robot()
    if not args.no_basics:
        basics(robot)
    pools = design_comparison(robot, args.pool_poses)
    sequential_study(pools[200.0])


def basics(robot) -> None:
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
