"""What the paper's linear model leaves with perfect sensors, and where it comes from.

Identifies (FGLS) from MuJoCo's true block displacements and sensor wrenches on the tests of
``scenarios/kr60_paper.toml`` (no scanner, no noise: only the model error remains), with gravity
on at 200 N, then with gravity off at 200, 100 and 50 N (the load-dependent Jacobian's bias is
proportional to the tension). Prints the bias per joint [%], the README's "What remains with
perfect sensors" figures.

    .venv/bin/python benchmarks/bench_model_bias.py [SCENARIO]
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_researcher_discrepancy import world_measurements  # noqa: E402

from vtestbed.researcher.identify import identify  # noqa: E402
from vtestbed.researcher.measure import stacked  # noqa: E402
from vtestbed.scenario import load_scenario  # noqa: E402
from vtestbed.world.truth import load_truth  # noqa: E402


def main(path: Path) -> None:
    scenario = load_scenario(path)
    k_true = load_truth(scenario.robot_name).stiffness
    print(f"{path.name}: bias of the paper's model [%] per joint, FGLS on the true displacements")
    for gravity, tension in ((True, 200.0), (False, 200.0), (False, 100.0), (False, 50.0)):
        load = dataclasses.replace(scenario.load, tensions=(tension,) * len(scenario.poses))
        _, _, tests = world_measurements(dataclasses.replace(scenario, load=load), gravity=gravity)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # noise-free data: the FGLS weights are degenerate-ish
            result = identify(*stacked(tests), method="fgls")
        bias = (result.stiffness / k_true - 1.0) * 100.0
        cells = ", ".join(f"{b:+.3f}" for b in bias)
        print(f"  gravity {'on ' if gravity else 'off'} {tension:5.0f} N: {cells}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "scenarios" / "kr60_paper.toml")
