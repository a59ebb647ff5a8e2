"""The quick campaign's base scenario (scenarios/kr60_sweep_quick.toml, 20 tests) and the tiny
campaigns the campaign tests build on it (their own copy, stable under others' edits)."""

import copy
import tomllib
from pathlib import Path

from vtestbed.campaigns.spec import parse_campaign

ROOT = Path(__file__).resolve().parents[1]
QUICK = (ROOT / "scenarios" / "kr60_sweep_quick.toml").read_text()
BASE_TEXT = QUICK[: QUICK.index("\n[campaign]\n")]  # the quick campaign's base scenario, 20 tests
BASE = tomllib.loads(BASE_TEXT)
TINY = {"trials": 6, "seed": 9, "axes": {"n_tests": [3, 4], "scanner_noise_scale": [0.5, 1.0]}}
TINY_TOML = """
[campaign]
trials = 6
seed = 9
[campaign.axes]
n_tests = [3, 4]
scanner_noise_scale = [0.5, 1.0]
"""


def campaign_data(**table):
    """The base scenario with a small ``[campaign]`` table (3 trials, seed 5, n_tests 3 and 4)."""
    data = copy.deepcopy(BASE)
    data["campaign"] = {"trials": 3, "seed": 5, "axes": {"n_tests": [3, 4]}} | table
    return data


def tiny(**changes):
    """The tiny campaign: 6 trials x n_tests (3, 4) x scanner_noise_scale (0.5, 1.0), seed 9."""
    data = copy.deepcopy(BASE)
    data["campaign"] = copy.deepcopy(TINY) | changes
    return parse_campaign(data, "tiny")
