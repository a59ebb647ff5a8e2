"""Least-squares identification and the convergence study against the number of tests.

Run: .venv/bin/python benchmarks/bench_identify.py

Target (issue 12): FGLS on 500 tests, jackknife covariance included, under 1 s; the convergence
study (a fit on the first n tests for n = 1..N, ``report.convergence``) at most quadratic in N.
For comparison the figures measured before (a dense 6T x 6T whitening matrix rebuilt per FGLS
iteration and per jackknife refit) and those of the row-scaling prototype are printed too.

Synthetic tests from the real kinematics: Pinocchio Jacobians of the KR60-3 at the block, at
random poses inside the joint limits (near-singular ones skipped), a 200 N wire force in a random
direction acting 5 cm off the block origin, displacements ``A c`` at the paper's Table 5 stiffness
plus scanner-like noise (3 um, 5 urad). Times are medians of repeats, BLAS on one thread; other
users of the machine only ever slow a run down.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import warnings  # noqa: E402

import numpy as np  # noqa: E402
from _timing import median_time  # noqa: E402  benchmarks/ is on sys.path when run as a script

from vtestbed.design.priors import PAPER_TABLE5  # noqa: E402
from vtestbed.lab import LabSetup  # noqa: E402
from vtestbed.researcher.identify import identify  # noqa: E402
from vtestbed.researcher.kinematics import ArmKinematics  # noqa: E402
from vtestbed.researcher.measure import TestMeasurement  # noqa: E402
from vtestbed.researcher.report import convergence  # noqa: E402
from vtestbed.robots import load_robot  # noqa: E402

SIGMA = np.array([3e-6, 3e-6, 3e-6, 5e-6, 5e-6, 5e-6])  # scanner-like displacement noise [m, rad]
TARGET_500_S = 1.0
BEFORE = {100: 0.77, 500: 57.0}  # dense whitening, issue 12 [s]
PROTOTYPE = {100: 0.061, 500: 0.65}  # row-scaling prototype, issue 12 [s]
BEFORE_CONVERGENCE = "8.2 s at N = 100, ~N^4"


def synthetic_tests(count: int, seed: int = 0) -> list[TestMeasurement]:
    """``count`` identification tests: real Jacobians at random poses, d = A c + noise."""
    robot = load_robot("kuka_kr60_3")
    kin = ArmKinematics(robot, LabSetup().block_in_flange)
    rng = np.random.default_rng(seed)
    k = PAPER_TABLE5.stiffness
    out: list[TestMeasurement] = []
    while len(out) < count:
        q = robot.random_pose(rng, margin=0.1)
        jac = kin.jacobian(q, frame="tool")
        s = np.linalg.svd(jac, compute_uv=False)
        if s[-1] < 1e-3 * s[0]:
            continue  # near the wrist singularity: a lab would not test there
        force = rng.normal(size=3)
        force *= 200.0 / np.linalg.norm(force)
        wrench = np.r_[force, np.cross(rng.normal(0.0, 0.05, 3), force)]
        d = jac @ ((jac.T @ wrench) / k) + rng.normal(size=6) * SIGMA
        out.append(
            TestMeasurement(f"T{len(out):04d}", "identification", q, wrench, d, jac, np.eye(4), np.eye(4))
        )
    return out


def _arrays(tests):
    return (
        np.array([m.jacobian for m in tests]),
        np.array([m.wrench for m in tests]),
        np.array([m.displacement for m in tests]),
    )


def main() -> None:
    pool = synthetic_tests(1000)
    print("FGLS identification (jackknife covariance from 8 tests on), median wall time:")
    sizes, times = [], []
    for n, repeats in ((20, 9), (100, 7), (500, 5), (1000, 5)):
        jac, wrench, d = _arrays(pool[:n])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = median_time(lambda jac=jac, wrench=wrench, d=d: identify(jac, wrench, d), repeats)
        sizes.append(n)
        times.append(t)
        notes = []
        if n in BEFORE:
            notes.append(
                f"before {BEFORE[n]:g} s, prototype (floor) {PROTOTYPE[n]:g} s: {t / PROTOTYPE[n]:.2f}x"
            )
        if n == 500:
            notes.append(f"target < {TARGET_500_S:g} s: {'met' if t < TARGET_500_S else 'MISSED'}")
        print(f"  {n:5d} tests: {t * 1e3:8.2f} ms  ({repeats} repeats)  {'; '.join(notes)}")
    slope = np.polyfit(np.log(sizes[1:]), np.log(times[1:]), 1)[0]
    print(f"  growth 100..1000 tests: T^{slope:.2f} (before: T^2.8)")

    print("convergence study (fits on the first n = 1..N tests), median wall time:")
    sizes, times = [], []
    for n, repeats in ((20, 7), (100, 5), (200, 5)):
        tests = pool[:n]
        t = median_time(lambda tests=tests: convergence(tests, "fgls", None), repeats)
        sizes.append(n)
        times.append(t)
        print(f"  N = {n:4d}: {t:7.3f} s  ({repeats} repeats)")
    slope = np.polyfit(np.log(sizes), np.log(times), 1)[0]
    verdict = "met" if slope <= 2.1 else "MISSED"
    print(f"  growth: N^{slope:.2f} (target at most N^2: {verdict}; before: {BEFORE_CONVERGENCE})")


if __name__ == "__main__":
    main()
