"""scenarios/kr60_paper.toml holds exactly the clear tests of the paper's draw (drift test), and
the truth world runs every one of them without a clearance finding; so does
scenarios/kr60_paper_a6.toml, the same draw with A6 free, whose other tables are the paper's."""

import sys
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from vtestbed.campaigns.paper_tests import paper_tests
from vtestbed.errors import OutOfRangeError
from vtestbed.scenario import load_scenario
from vtestbed.world.clearance import truth_clearance
from vtestbed.world.rig import Rig
from vtestbed.world.scanner import Scanner

PAPER = Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml"
PAPER_A6 = PAPER.with_name("kr60_paper_a6.toml")
# (file, free_a6, poses the clearance check dropped: each header comment says so)
DRAWS = [(PAPER, False, 6), (PAPER_A6, True, 10)]


@pytest.mark.parametrize(("path", "free_a6", "dropped"), DRAWS, ids=["paper", "free_a6"])
def test_paper_scenario_is_what_the_draw_gives(path, free_a6, dropped):
    scenario = load_scenario(PAPER)
    plan = paper_tests(scenario, free_a6=free_a6)
    data = tomllib.loads(path.read_text())
    drawn = np.degrees(scenario.robot.dh_to_controller(plan.q))
    # the file rounds to 0.01 deg and the draw is on that grid: equal to round-off
    np.testing.assert_allclose(np.array(data["poses"]["angles_deg"]), drawn, atol=1e-9)
    assert tuple(data["load"]["hook"]) == plan.hooks
    assert tuple(data["load"]["anchor"]) == plan.anchors
    assert plan.notes["poses_dropped"] == dropped  # the header comment says so


def test_the_free_a6_draw_differs_from_the_paper_in_a6_only():
    paper, free = (tomllib.loads(p.read_text()) for p in (PAPER, PAPER_A6))
    a6 = np.array(free["poses"]["angles_deg"])[:, 5]
    assert np.ptp(a6) > 180.0 and np.all(np.array(paper["poses"]["angles_deg"])[:, 5] == 45.0)
    assert np.all(np.array(free["poses"]["angles_deg"])[:, 0] == 0.0)  # A1 = 0 as the paper's
    for key in ("name", "description", "poses", "load"):
        paper.pop(key), free.pop(key)
    assert free == paper  # the lab, the sensors, the validation tests


def test_the_variant_script_writes_the_free_a6_scenarios_tables():
    sys.path.insert(0, str(PAPER.parents[1] / "benchmarks"))
    import draw_paper_variant

    def tables(text: str) -> str:
        return text[text.index("[poses]") :]

    assert tables(draw_paper_variant.variant_text(2023, free_a1=False)) == tables(PAPER_A6.read_text())


def test_free_a1_alone_is_refused():
    with pytest.raises(OutOfRangeError, match="free_a1 = True needs free_a6 = True"):
        paper_tests(load_scenario(PAPER), free_a1=True)


@pytest.mark.parametrize("path", [PAPER, PAPER_A6], ids=["paper", "free_a6"])
def test_every_paper_test_is_clear_in_the_truth_world(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a scenario test that is not clear warns at load
        scenario = load_scenario(path)
    rig = Rig(scenario.robot, scenario.lab)
    for i, q in enumerate(scenario.poses):
        rig.command(q)
        rig.hook(scenario.load.hooks[i], scenario.load.anchors[i])
        scanner = Scanner.place(scenario.lab, rig.solve().block_pose, distance_m=scenario.scanner.distance)
        report = truth_clearance(rig, rig.tighten(scenario.load.tensions[i]), scanner.pose_world[:3, 3])
        # clear by the documented margin (docs/clearance.md): every pair at a positive distance
        assert report.ok and report.worst().distance_m > 0.0, (i, report.worst())


def test_scenarios_built_on_the_paper_tests_share_them_verbatim():
    text = PAPER.read_text()
    block = text[text.index("# 20 test poses") : text.index("# The paper's Table 6 poses")]
    for name in ("kr60_ideal", "kr60_hidden_link", "kr60_confusable"):
        assert block in (PAPER.parent / f"{name}.toml").read_text(), name
