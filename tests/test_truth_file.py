"""``TruthFile``: the truth table joined from per-test pieces is the JSON the json module writes.

Reference: ``json.dumps`` of the same mapping (strict: NaN as null) through
:func:`vtestbed.files.dumps`, byte for byte, and ``json.loads`` of the file.
"""

import json

import numpy as np

from vtestbed.files import dumps
from vtestbed.truth_file import TruthFile


def _record(i: int) -> dict:
    rng = np.random.default_rng(i)
    return {
        "group": "identification",
        "tension_N": float(rng.uniform(100, 200)),
        "q_loaded_rad": rng.normal(size=6).tolist(),
        "block_pose_loaded": rng.normal(size=(4, 4)).tolist(),
        "points": [int(rng.integers(1000, 9000)), 17],
        "flag": np.bool_(True),
        "missing": float("nan"),
    }


def test_each_rewrite_is_the_json_of_the_whole_mapping(tmp_path):
    header = {"scenario": "x", "seed": np.int64(7), "stiffness_true_Nm_per_rad": [1.5e6, 2e6], "effects": []}
    truth = TruthFile(tmp_path / "truth.json", dict(header))
    for i in range(4):
        path = truth.add(f"T{i + 1:03d}", _record(i))
        expected = header | {"tests": {f"T{k + 1:03d}": _record(k) for k in range(i + 1)}}
        assert path.read_text() == dumps(expected)  # the same bytes as serialising it all at once
        loaded = json.loads(path.read_text())
        assert loaded["tests"][f"T{i + 1:03d}"]["missing"] is None  # strict JSON: NaN is null
        assert len(loaded["tests"]) == i + 1 and loaded["seed"] == 7


def test_a_resumed_file_keeps_its_tests_and_appends(tmp_path):
    path = tmp_path / "truth.json"
    first = TruthFile(path, {"scenario": "x"})
    first.add("T001", _record(1))
    resumed = TruthFile(path, json.loads(path.read_text()) | {"repeats": 3})
    resumed.add("T002", _record(2))
    reference = json.loads(
        dumps({"scenario": "x", "repeats": 3, "tests": {"T001": _record(1), "T002": _record(2)}})
    )
    assert json.loads(path.read_text()) == reference


def test_no_tests_and_no_header(tmp_path):
    assert json.loads(TruthFile(tmp_path / "a.json", {}).text()) == {"tests": {}}
    assert json.loads(TruthFile(tmp_path / "b.json", {"seed": 1}).text()) == {"seed": 1, "tests": {}}
