"""Median time of one static equilibrium solve of the truth world (wire taut), and of tightening.

Run: .venv/bin/python benchmarks/bench_equilibrium.py
"""

from __future__ import annotations

import numpy as np
from _timing import median_time  # benchmarks/ is on sys.path when run as a script

from vtestbed.world.rig import Rig


def main() -> None:
    rig = Rig()
    rng = np.random.default_rng(0)
    poses = [
        np.radians(
            [
                rng.uniform(-20, 20),
                rng.uniform(-90, -30),
                rng.uniform(-60, 20),
                rng.uniform(-90, 90),
                rng.uniform(30, 90),
                rng.uniform(-90, 90),
            ]
        )
        for _ in range(20)
    ]
    cold, warm, tighten, iters = [], [], [], []
    for q in poses:
        rig.command(q)
        rig.hook("hook_x", "ring_5")
        state = rig.tighten(200.0)

        def cold_solve():
            rig._q_guess = rig.model.qpos_spring.copy()  # start from the commanded pose
            iters.append(rig.solve().iterations)

        cold.append(median_time(cold_solve, 20))
        warm.append(median_time(rig.solve, 50))
        tighten.append(median_time(lambda: rig.tighten(200.0), 5))
        assert state.residual < 1e-8
    print("static equilibrium, wire taut at 200 N, 20 poses (median over poses of median times):")
    print(
        f"  cold start from the commanded pose: {np.median(cold) * 1e6:8.1f} us  ({np.median(iters):.0f} Newton iterations)"
    )
    print(f"  warm start (previous equilibrium):  {np.median(warm) * 1e6:8.1f} us")
    print(
        f"  tighten to 200 N (secant on the rest length, slack solve included): {np.median(tighten) * 1e3:6.2f} ms"
    )
    print(
        "  bound: ~2 us per residual (5 MuJoCo calls); a finite-difference Jacobian costs 6 residuals; "
        "Python call overhead dominates"
    )


if __name__ == "__main__":
    main()
