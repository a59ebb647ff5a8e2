"""Write a scenario with the paper's draw of 20 tests, its wrist roll A6 (and base A1) free.

The draw is :func:`vtestbed.campaigns.paper_tests.paper_tests` with ``free_a6`` (and ``free_a1``)
at ``--seed``; every other table is ``scenarios/kr60_paper.toml``'s, as in
``scenarios/kr60_paper_a6.toml`` (``--seed 2023``, A6 only) and ``scenarios/kr60_paper_a6a1.toml``
(``--seed 2025 --free-a1``). ``naming_forecast.py --scenario`` and
``bench_discrepancy.py --scenario`` read the file (docs/discrepancy_benchmark.md, "A forecast of
the first name, and the paper's fixed A6"). Angles in the file: KUKA controller degrees.

    .venv/bin/python benchmarks/draw_paper_variant.py --seed 2024 [--free-a1] --out /tmp/kr60_a6_2024.toml
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from vtestbed.campaigns.paper_tests import paper_tests, paper_tests_toml
from vtestbed.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
VALIDATION_MARK = "# The paper's Table 6 poses"  # where the paper file's tables after [load] begin


def variant_text(seed: int, free_a1: bool) -> str:
    """The scenario file's text: the paper's header and tables, the drawn [poses] and [load]."""
    paper = PAPER.read_text()
    scenario = load_scenario(PAPER)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the draw reports the poses it drops; the header counts them
        plan = paper_tests(scenario, seed=seed, free_a6=True, free_a1=free_a1)
    name = f"kr60_a6{'a1' if free_a1 else ''}_{seed}"
    head = (
        f'name = "{name}"\n'
        f'description = "The paper\'s draw with A6{" and A1" if free_a1 else ""} free (seed {seed})"\n'
        f'robot = "{scenario.robot.name}"\nseed = {seed}\n\n'
        f"# benchmarks/draw_paper_variant.py --seed {seed}{' --free-a1' if free_a1 else ''}: "
        f"{plan.notes['poses_dropped']} draws dropped by the clearance check\n\n"
    )
    return head + paper_tests_toml(scenario, plan) + "\n" + paper[paper.index(VALIDATION_MARK) :]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=2023)
    ap.add_argument("--free-a1", action="store_true", help="A1 uniform within +-45 deg too")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.write_text(variant_text(args.seed, args.free_a1))
    print(args.out)


if __name__ == "__main__":
    main()
