"""Static equilibrium of the truth world: each stage's median time next to its target and floor.

Stages (20 random KR60 poses, hook_x to ring_5; median over poses of the median of repeats):
the unloaded solve from the commanded pose (what every test does first), the taut solve (wire at
200 N) from the commanded pose, a warm solve, tightening to 200 N from the unloaded state, and
the cold taut Newton solve alone ("Newton, taut": ``solve()`` without its readout of the state,
which runs mj_forward for the sensor, reads the poses and moves the wire's capsule, ~17 us; the
issue's floor of 76 us is a minimal Newton without that readout).
Floors: the measurements of issue 12 for a minimal Newton (tangent from mjd_inverseFD) and a
minimal held-tension tighten; "work" is the MuJoCo work alone (calls x the cost of one residual,
tangent and readout, measured here). Then 1000 sensor-feasible random tests, counting failures.

Run: .venv/bin/python benchmarks/bench_equilibrium.py
"""

from __future__ import annotations

import numpy as np
from _timing import median_time  # benchmarks/ is on sys.path when run as a script

from vtestbed.errors import ConvergenceError, SensorOverloadError
from vtestbed.world.rig import Rig

# Issue 12 (this machine): before = the chord/secant solver; floor = a minimal implementation.
BEFORE = {"cold taut": (227e-6, 19), "tighten": (1.19e-3, 85)}
FLOOR = {
    "cold taut": (76e-6, "3 Newton iterations"),
    "Newton, taut": (76e-6, "3 Newton iterations"),
    "tighten": (53e-6, "6 residual calls"),
}
TARGET = {"cold unloaded": 80e-6, "cold taut": 80e-6, "tighten": 100e-6, "Newton, taut": 80e-6}


def _counted(rig: Rig, fn, counts: list) -> None:
    r0, t0 = rig.residual_calls, rig.tangent_calls
    fn()
    counts.append((rig.residual_calls - r0, rig.tangent_calls - t0))


def _random_tests(n: int = 1000, seed: int = 2023) -> tuple[int, int, int]:
    rig, rng = Rig(), np.random.default_rng(seed)
    hooks, rings = list(rig.lab.block.hooks), list(rig.lab.table.anchors)
    low, high = rig.lab.tension_range_N  # the lab's limit (588.6 N for the KR60: its rated payload)
    feasible = overloaded = failed = 0
    while feasible < n:
        rig.command(rng.uniform(rig.robot.lower, rig.robot.upper))
        rig.hook(hooks[rng.integers(len(hooks))], rings[rng.integers(len(rings))])
        try:
            rig.solve()
            rig.tighten(rng.uniform(low, high))
            feasible += 1
        except SensorOverloadError:
            overloaded += 1
        except ConvergenceError:
            failed += 1
            feasible += 1
    return feasible, overloaded, failed


def main() -> None:
    rig = Rig()
    rng = np.random.default_rng(0)
    lows, highs = np.radians([-20, -90, -60, -90, 30, -90]), np.radians([20, -30, 20, 90, 90, 90])
    poses = [rng.uniform(lows, highs) for _ in range(20)]
    times = {k: [] for k in ("cold unloaded", "cold taut", "warm", "tighten", "Newton, taut")}
    counts = {k: [] for k in times}
    for q in poses:
        rig.command(q)
        rig.hook("hook_x", "ring_5")
        unloaded_q = rig.solve().qpos_all
        unloaded_tangent = rig._tangent_guess  # (tangent, inverse)

        def cold_unloaded():
            rig.slacken_wire()
            rig._q_guess = rig.model.qpos_spring.copy()  # from the commanded pose
            rig.solve()

        def tighten(u=unloaded_q, k=unloaded_tangent):
            rig.slacken_wire()
            rig._q_guess = u.copy()  # from the unloaded equilibrium and its tangent, as a test runs
            rig._tangent_guess = k
            rig.tighten(200.0)

        def cold_taut():
            rig._q_guess = rig.model.qpos_spring.copy()
            rig.solve()

        def newton_taut():  # the solve without the state's readout (sensor, poses, wire capsule)
            rig._equilibrium(rig.model.qpos_spring.copy(), 50)

        for name, fn, repeats in (
            ("cold unloaded", cold_unloaded, 20),
            ("tighten", tighten, 20),
            ("cold taut", cold_taut, 20),
            ("warm", rig.solve, 20),
            ("Newton, taut", newton_taut, 20),
        ):
            _counted(rig, fn, counts[name])
            times[name].append(median_time(fn, repeats))

    q = rig.solve().qpos_all
    t_res = median_time(lambda: rig.generalized_force(q), 200)
    t_tan = median_time(lambda: rig.tangent_stiffness(q), 100)
    t_read = median_time(lambda: rig._readout(q, 0.0, 0), 100)
    print(
        "static equilibrium of the KR60, 20 poses, median over poses of medians of 20 repeats (machine shared):"
    )
    print(
        f"  one residual {t_res * 1e6:.1f} us, one tangent (mjd_inverseFD) {t_tan * 1e6:.1f} us, readout {t_read * 1e6:.1f} us"
    )
    print(
        f"  {'stage':14s} {'time':>9s} {'target':>8s} {'work':>8s} {'floor (issue 12), time/floor':>36s} {'calls res/tan (median, max)':>28s}  before"
    )
    for name in times:
        res = np.array([c[0] for c in counts[name]])
        tan = np.array([c[1] for c in counts[name]])
        work = np.median(res) * t_res + np.median(tan) * t_tan + (t_read if name != "Newton, taut" else 0.0)
        target = f"{TARGET[name] * 1e6:6.0f} us" if name in TARGET else "       -"
        t = np.median(times[name])
        floor = (
            f"{FLOOR[name][0] * 1e6:.0f} us ({t / FLOOR[name][0]:.2f}x), {FLOOR[name][1]}"
            if name in FLOOR
            else "-"
        )
        before = f"{BEFORE[name][0] * 1e6:.0f} us, {BEFORE[name][1]} residuals" if name in BEFORE else "-"
        print(
            f"  {name:14s} {t * 1e6:6.1f} us {target} {work * 1e6:5.1f} us {floor:>36s} "
            f"{np.median(res):6.0f}/{np.median(tan):.0f} ({res.max()}/{tan.max()}){'':>12s}  {before}"
        )
    feasible, overloaded, failed = _random_tests()
    print(
        f"random tests (pose in the limits, any hook and ring, 1 N to the lab's limit): {feasible - failed}/{feasible} "
        f"sensor-feasible tests converged ({failed} failures; {overloaded} draws overloaded the sensor)"
    )


if __name__ == "__main__":
    main()
