import numpy as np
import pytest

from vtestbed.lab import LabSetup
from vtestbed.robots import load_robot
from vtestbed.world.truth import load_truth


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
