import numpy as np
import pytest

from vtestbed.lab import LabSetup
from vtestbed.robots import load_robot
from vtestbed.world.truth import load_truth

# The default test pose (DH, deg): the block's three scanned faces are in view from 0.6 m.
POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)


@pytest.fixture(scope="session")
def robot():
    return load_robot("kuka_kr60_3")


@pytest.fixture(scope="session")
def truth():
    """The KR60-3 world's truth (true stiffness; test references only)."""
    return load_truth("kuka_kr60_3")


@pytest.fixture(scope="session")
def lab():
    return LabSetup()


@pytest.fixture
def rng():
    return np.random.default_rng(20231)


@pytest.fixture(scope="session")
def optimum(robot):
    """The criterion's optimum at the wrist centre (seed 3)."""
    from vtestbed.design import kappa

    return kappa.optimize(robot, seed=3)


@pytest.fixture(scope="session")
def scene():
    """The default pose, unloaded: rig, true block pose, a placed scanner and its noise-free hits.

    Shared read-only by the scanner, scan-noise and PLY tests (none of them moves the rig)."""
    from vtestbed.world.rig import Rig
    from vtestbed.world.scanner import Scanner

    rig = Rig()
    rig.command(np.radians(POSE_DEG))
    rig.hook("hook_x", "ring_5")
    state = rig.solve()
    scanner = Scanner.place(rig.lab, state.block_pose)
    hits = scanner.cast(rig.model, rig.data)
    return rig, state, scanner, hits


@pytest.fixture(scope="session")
def tiny_sweep(tmp_path_factory):
    """The tiny campaign (24 trials) swept on one process: (results, output folder)."""
    from quick_campaign import tiny

    from vtestbed.campaigns.runner import sweep

    out = tmp_path_factory.mktemp("sweep") / "ref"
    return sweep(tiny(), out, workers=1, progress=False), out


def paper_scenario_data(n_tests: int, n_val: int, name: str, seed: int, **scanner) -> dict:
    """The paper scenario's mapping cut to ``n_tests`` identification and ``n_val`` validation tests."""
    import copy
    import tomllib
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml").read_text()
    data = copy.deepcopy(tomllib.loads(text))
    data["name"], data["seed"] = name, seed
    data["poses"]["angles_deg"] = data["poses"]["angles_deg"][:n_tests]
    data["validation"]["angles_deg"] = data["validation"]["angles_deg"][:n_val]
    for key in ("hook", "anchor"):
        data["load"][key] = data["load"][key][:n_tests]
        data["validation"][key] = data["validation"][key][:n_val]
    data["scanner"].update(scanner)
    return data
