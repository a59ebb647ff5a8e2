"""scenarios/kr60_paper.toml holds exactly the clear tests of the paper's draw (drift test), and
the truth world runs every one of them without a clearance finding."""

import tomllib
import warnings
from pathlib import Path

import numpy as np

from vtestbed.campaigns.paper_tests import paper_tests
from vtestbed.scenario import load_scenario
from vtestbed.world.clearance import truth_clearance
from vtestbed.world.rig import Rig
from vtestbed.world.scanner import Scanner

PAPER = Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml"


def test_paper_scenario_is_what_the_draw_gives():
    scenario = load_scenario(PAPER)
    plan = paper_tests(scenario)
    data = tomllib.loads(PAPER.read_text())
    drawn = np.degrees(scenario.robot.dh_to_controller(plan.q))
    # the file rounds to 0.01 deg and the draw is on that grid: equal to round-off
    np.testing.assert_allclose(np.array(data["poses"]["angles_deg"]), drawn, atol=1e-9)
    assert tuple(data["load"]["hook"]) == plan.hooks
    assert tuple(data["load"]["anchor"]) == plan.anchors
    assert plan.notes["poses_dropped"] == 6  # the header comment says so


def test_every_paper_test_is_clear_in_the_truth_world():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a scenario test that is not clear warns at load
        scenario = load_scenario(PAPER)
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
