"""scenarios/kr60_paper.toml holds exactly the clear tests of the paper's draw (drift test), and
the truth world runs every one of them without a clearance finding; so do
scenarios/kr60_paper_a6.toml, the same draw with A6 free, and scenarios/kr60_paper_a6a1.toml and
kr60_paper_a6a1_2033.toml, the draws of seeds 2025 and 2033 with A6 and A1 free, whose other tables
are the paper's."""

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
PAPER_A6A1 = PAPER.with_name("kr60_paper_a6a1.toml")
PAPER_2033 = PAPER.with_name("kr60_paper_a6a1_2033.toml")
# (file, seed, free_a6, free_a1, poses the clearance check dropped: each header comment says so)
DRAWS = [
    (PAPER, 2023, False, False, 6),
    (PAPER_A6, 2023, True, False, 10),
    (PAPER_A6A1, 2025, True, True, 10),
    (PAPER_2033, 2033, True, True, 9),
]
IDS = ["paper", "free_a6", "free_a6_a1", "free_a6_a1_2033"]


@pytest.mark.parametrize(("path", "seed", "free_a6", "free_a1", "dropped"), DRAWS, ids=IDS)
def test_paper_scenario_is_what_the_draw_gives(path, seed, free_a6, free_a1, dropped):
    scenario = load_scenario(PAPER)
    plan = paper_tests(scenario, seed=seed, free_a6=free_a6, free_a1=free_a1)
    data = tomllib.loads(path.read_text())
    drawn = np.degrees(scenario.robot.dh_to_controller(plan.q))
    # the file rounds to 0.01 deg and the draw is on that grid: equal to round-off
    np.testing.assert_allclose(np.array(data["poses"]["angles_deg"]), drawn, atol=1e-9)
    assert tuple(data["load"]["hook"]) == plan.hooks
    assert tuple(data["load"]["anchor"]) == plan.anchors
    assert plan.notes["poses_dropped"] == dropped  # the header comment says so


@pytest.mark.parametrize(
    ("path", "free_a1"), [(PAPER_A6, False), (PAPER_A6A1, True), (PAPER_2033, True)], ids=IDS[1:]
)
def test_a_free_draw_differs_from_the_paper_in_its_free_angles_only(path, free_a1):
    paper, free = (tomllib.loads(p.read_text()) for p in (PAPER, path))
    angles = np.array(free["poses"]["angles_deg"])
    assert np.ptp(angles[:, 5]) > 180.0 and np.all(np.array(paper["poses"]["angles_deg"])[:, 5] == 45.0)
    if free_a1:  # uniform within +-45 deg (paper_tests.FREE_A1_DEG)
        assert np.all(np.abs(angles[:, 0]) <= 45.0) and np.ptp(angles[:, 0]) > 45.0
    else:
        assert np.all(angles[:, 0] == 0.0)  # A1 = 0 as the paper's
    for key in ("name", "description", "seed", "poses", "load"):
        paper.pop(key), free.pop(key)
    assert free == paper  # the lab, the sensors, the validation tests


@pytest.mark.parametrize(
    ("path", "seed", "free_a1"),
    [(PAPER_A6, 2023, False), (PAPER_A6A1, 2025, True), (PAPER_2033, 2033, True)],
    ids=IDS[1:],
)
def test_the_variant_script_writes_the_free_scenarios_tables(path, seed, free_a1):
    sys.path.insert(0, str(PAPER.parents[1] / "benchmarks"))
    import draw_paper_variant

    def tables(text: str) -> str:
        return text[text.index("[poses]") :]

    assert tables(draw_paper_variant.variant_text(seed, free_a1=free_a1)) == tables(path.read_text())


def test_free_a1_alone_is_refused():
    with pytest.raises(OutOfRangeError, match="free_a1 = True needs free_a6 = True"):
        paper_tests(load_scenario(PAPER), free_a1=True)


@pytest.mark.parametrize("path", [PAPER, PAPER_A6, PAPER_A6A1, PAPER_2033], ids=IDS)
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
