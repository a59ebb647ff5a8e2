"""The discrepancy benchmark scores "exact label" and its misnamed table against the label that
stands for each hidden effect (benchmarks/_discrepancy_worlds.expected_label). Reference: the
researcher's own candidate pool (``candidates.candidates``): every effect with a candidate must map
to one of its labels, in its own family, or the benchmark's report fails after the run (as it did
for ``block_offset`` once the term was split into its rotation and translation). The two-effect
benchmark's tally is checked on hand-counted records.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def run_with_benchmarks(script: str) -> subprocess.CompletedProcess:
    """``script`` run apart, benchmarks/ on its path: the benchmark's module pins the BLAS threads
    in the environment when imported."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(BENCH), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, check=True)


SCRIPT = """
import _discrepancy_worlds as W
from vtestbed.researcher.candidates import CANDIDATE_NAMES, candidates
from vtestbed.robots import load_robot
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.scenario import load_scenario
from vtestbed.world.effects import EFFECTS

scenario = load_scenario(W.SCENARIO)
kin = ArmKinematics(scenario.robot, None)
pool = {c.label: c.name for c in candidates(kin)}
for name in CANDIDATE_NAMES:
    label = W.expected_label(EFFECTS[name]())
    true = sorted(W.true_labels(EFFECTS[name]()))
    print(name, label, pool.get(label), "|", ";".join(f"{t}={pool.get(t)}" for t in true))
"""


def test_every_effect_with_a_candidate_maps_to_a_label_of_its_family():
    out = run_with_benchmarks(SCRIPT)
    lines = [line.split(" | ") for line in out.stdout.strip().splitlines()]
    rows = [head.split(" ", 1) for head, _ in lines]
    assert len(rows) == 9  # candidates.CANDIDATE_NAMES
    for name, rest in rows:
        label, family = rest.rsplit(" ", 1)
        assert family == name, (name, label)
    assert dict(rows)["block_offset"] == "block_offset(rotation) block_offset"
    # the labels that count a hidden effect named (bench_two_effects): its own, in its family
    true = {head.split(" ", 1)[0]: dict(t.split("=") for t in tail.split(";")) for head, tail in lines}
    for name, labels in true.items():
        assert set(labels.values()) == {name}, (name, labels)
    assert sorted(true["block_offset"]) == ["block_offset(rotation)", "block_offset(translation)"]
    assert [len(v) for k, v in true.items() if k != "block_offset"] == [1] * 8


TALLY = """
import json
import bench_two_effects as B
records = [
    {"named": ["block_offset(translation)", "ft_misalignment"]},  # both: the shift names the offset
    {"named": ["block_offset(rotation)", "block_offset(translation)"]},  # one: both parts, one effect
    {"named": ["ft_misalignment", "joint_coupling(4,5)"]},  # one, and a third name
    {"named": []},
    {"error": "ValueError"},
]
t = B.tally("block_offset+ft_misalignment", records)
print(json.dumps({k: (dict(v) if hasattr(v, "items") else v) for k, v in t.items()}))
"""


def test_the_two_effect_tally_counts_either_part_of_the_block_offset_as_its_name():
    """bench_two_effects counts a pair named when each effect has one of its labels named; the
    block offset's two parts are one effect (hand-counted records)."""
    out = run_with_benchmarks(TALLY)
    t = json.loads(out.stdout)
    assert (t["both"], t["one"], t["wrong"], t["nothing"], t["error"]) == (1, 2, 1, 1, 1)
    assert t["alone"] == {"block_offset": 1, "ft_misalignment": 1}
    assert t["extra"] == {"joint_coupling(4,5)": 1}
