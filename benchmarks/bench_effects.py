"""Hidden effects: what each does to the experiment, and what it costs the static solve.

Prints (1) per effect at its realistic default on scenarios/kr60_paper.toml: its share of the
true block deflection, and the change of the stiffness identified with the paper's linear model
(noise-free scanner and force sensor, so the change is the effect's alone), as a Markdown table
for docs/effects.md; (2) the cold static solve with each effect against the clean world
(target: within 2x).

    .venv/bin/python benchmarks/bench_effects.py [--skip-table]
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import median_time  # noqa: E402

from vtestbed.campaigns.montecarlo import prepare, trial  # noqa: E402
from vtestbed.scenario import ForceSensorPlan, load_scenario  # noqa: E402
from vtestbed.world.effects import EFFECTS  # noqa: E402
from vtestbed.world.effects.size import effect_sizes  # noqa: E402
from vtestbed.world.rig import Rig  # noqa: E402
from vtestbed.world.sensors import ForceTorqueSensor  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def identified_errors(scenario) -> np.ndarray:
    """rel_err [%] per joint of a noise-free identification of ``scenario``'s 20 tests."""
    prepared = prepare(scenario)
    sensor = ForceTorqueSensor(scenario.lab.sensor, (0.0,) * 6, (0.0,) * 6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = trial(prepared, 0, noise=None, sensor=sensor)
    return (result.stiffness / prepared.stiffness_true - 1) * 100


def table(base) -> None:
    effects = [kind() for kind in EFFECTS.values()]
    sizes = {s.name: s for s in effect_sizes(base, effects)}
    clean = identified_errors(base)
    print("| effect (realistic default) | deflection share, translation RMS / max [%] | rotation RMS [%] "
          "| F/T change RMS [%] | change of identified k, joints 1-6 [% of k_true] |")  # fmt: skip
    print("| --- | --- | --- | --- | --- |")
    print(
        f"| none (clean world, paper model's own bias) | - | - | - | {', '.join(f'{v:+.3f}' for v in clean)} |"
    )
    for effect in effects:
        hidden = dataclasses.replace(base, effects=(effect,))
        delta = identified_errors(hidden) - clean
        s = sizes[effect.name]
        print(f"| `{effect.name}` | {s.translation_rms * 100:.2f} / {s.translation_max * 100:.2f} | "
              f"{s.rotation_rms * 100:.2f} | {s.wrench_rms * 100:.2f} | {', '.join(f'{v:+.3f}' for v in delta)} |")  # fmt: skip


def solve_times(base, rounds: int = 7) -> None:
    """Cold solve (from the commanded pose) at every test of the scenario, interleaved over the
    worlds in ``rounds`` rounds so that a busy machine slows them all alike; best round reported."""
    print(
        f"\ncold static solve, wire slack, gravity; mean over the {base.n_tests} tests, best of {rounds} rounds:"
    )
    worlds = [("clean", ())] + [(n, (k(),)) for n, k in EFFECTS.items()]
    rigs = {name: Rig(base.robot, base.lab, effects=effects) for name, effects in worlds}

    def solve_all(rig):
        for i, q in enumerate(base.poses):
            rig.command(q)
            rig.hook(base.load.hooks[i], base.load.anchors[i])
            rig.solve()

    best = {name: np.inf for name in rigs}
    order = list(rigs)
    rng = np.random.default_rng(0)
    for _ in range(rounds):
        rng.shuffle(order)  # no world always runs first (after the others' cache traffic)
        for name in order:
            rig = rigs[name]
            best[name] = min(best[name], median_time(lambda rig=rig: solve_all(rig), 1) / base.n_tests)
    for name, rig in rigs.items():
        print(
            f"  {name:22} {best[name] * 1e6:7.0f} us  x{best[name] / best['clean']:4.2f}  ({rig.model.nv} dof)"
        )


def main() -> None:
    base = load_scenario(ROOT / "scenarios" / "kr60_paper.toml")
    base = dataclasses.replace(
        base,
        scanner=dataclasses.replace(base.scanner, noise=False, noise_model=None),
        force_sensor=ForceSensorPlan((0.0,) * 6, (0.0,) * 6),
    )
    if "--skip-table" not in sys.argv:
        table(base)
    solve_times(base)


if __name__ == "__main__":
    main()
