"""Seeded fuzzing of the loaders (issue 13): scenario texts, campaign tables, setup.json and tests.csv.

Each kind starts from a valid file and applies random mutations, at the text level (truncation,
byte flips, deleted or doubled lines) and at the value level (a field replaced by a number of the
wrong sign or size, NaN, infinity, a string, a list, a table, a deleted or unknown key). Every
outcome must be a vtestbed error (VtestbedError) or a valid result whose values are finite and in
range: no other exception (a crash) and nothing accepted as nonsense. Parsing only, no simulation:
about a second per kind. ``VTESTBED_FUZZ_CASES`` raises the number of cases per kind (default 1000).
"""

from __future__ import annotations

import copy
import json
import math
import os
import random
import tomllib
from pathlib import Path

import numpy as np
import pytest
from test_dataset import _records, _setup, _write

from vtestbed.campaigns.spec import parse_campaign
from vtestbed.dataset import read_setup, read_tests, write_setup
from vtestbed.errors import VtestbedError
from vtestbed.lab import DEFAULT_SCANNER_DISTANCE_M
from vtestbed.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
CASES = int(os.environ.get("VTESTBED_FUZZ_CASES", "1000"))
NASTY = [float("nan"), float("inf"), -float("inf"), -1, 0, -0.0, 1e308, -1e308, 2**70, 1e-300, 0.5, 7, True, False,
         "", "x", "nan", "../../etc/passwd", "/abs.ply", "é\u0000", [], [1], [1, 2, 3], [[1, 2], [3]], [float("nan")] * 6,
         {}, {"a": 1}, None]  # fmt: skip


def _paths(tree, prefix=()):
    """Every (path, value) in a tree of dicts and lists."""
    yield prefix, tree
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield from _paths(v, (*prefix, i))


def _mutate_tree(data, rng: random.Random):
    """A deep copy of ``data`` with 1-3 random value-level mutations."""
    data = copy.deepcopy(data)
    for _ in range(rng.randint(1, 3)):
        paths = [p for p, _ in _paths(data) if p]
        if not paths:
            return rng.choice(NASTY)
        path = rng.choice(paths)
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        key, op = path[-1], rng.random()
        if op < 0.6:
            parent[key] = copy.deepcopy(rng.choice(NASTY))
        elif op < 0.7 and isinstance(parent, dict):
            del parent[key]
        elif op < 0.8 and isinstance(parent, dict):
            parent[f"unknown_{rng.randint(0, 9)}"] = 1
        elif op < 0.9 and isinstance(parent[key], list):
            parent[key] = parent[key][: rng.randint(0, len(parent[key]))]
        elif isinstance(parent[key], int | float) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * rng.choice([-1, 10, 1e6, 1e-6, float("nan")])
        else:
            parent[key] = copy.deepcopy(rng.choice(NASTY))
    return data


def _mutate_text(text: str, rng: random.Random) -> bytes:
    """``text`` with a random text-level mutation (as bytes: some are not UTF-8)."""
    raw = text.encode()
    op = rng.randrange(6)
    if op == 0:
        return raw[: rng.randrange(len(raw))]  # truncated
    if op == 1:
        b = bytearray(raw)
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    lines = text.splitlines(keepends=True)
    i = rng.randrange(len(lines))
    if op == 2:
        del lines[i]
    elif op == 3:
        lines.insert(i, lines[rng.randrange(len(lines))])
    elif op == 4:
        cut = lines[i].rstrip("\n")
        lines[i] = cut[: rng.randrange(len(cut) + 1)] + "\n"
    else:
        tokens = ["nan", "inf", "-1", "1e999", '"x"', "[]", "{}", "", ",", "\\", "\u00e9", "0"]
        line = lines[i]
        j = rng.randrange(len(line) + 1)
        lines[i] = line[:j] + rng.choice(tokens) + line[j:]
    return "".join(lines).encode("utf-8", "surrogatepass")


class Tally:
    """Outcomes of one kind: accepted, refused (a VtestbedError) and crashes (anything else)."""

    def __init__(self):
        self.accepted = self.refused = 0
        self.crashes: list[str] = []

    def run(self, case, parse, check):
        try:
            value = parse()
        except VtestbedError as exc:
            assert str(exc), "an error without a message"
            self.refused += 1
            return
        except Exception as exc:  # noqa: BLE001 - a crash is what we are looking for
            self.crashes.append(f"case {case}: {type(exc).__name__}: {exc}"[:300])
            return
        problem = check(value)
        if problem:
            self.crashes.append(f"case {case}: accepted nonsense: {problem}"[:300])
        else:
            self.accepted += 1

    def assert_clean(self):
        print(f"{CASES} cases: {self.accepted} accepted, {self.refused} refused, {len(self.crashes)} crashes")
        assert self.crashes == [], "\n".join(self.crashes[:10])
        assert self.accepted + self.refused == CASES
        assert self.accepted > 0 and self.refused > CASES // 2  # the mutations both pass and bite


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in arrays)


def _check_scenario(s) -> str:
    r = s.robot
    for label, q in (("poses", s.poses), ("validation poses", s.validation_poses)):
        if len(q) and (not _finite(q) or np.any(q < r.lower - 1e-9) or np.any(q > r.upper + 1e-9)):
            return f"{label} outside the joint limits or not finite: {q}"
    for plan in (s.load, s.validation_load):
        t = np.asarray(plan.tensions, dtype=float)
        if len(t) and (not _finite(t) or t.min() < 1.0 or t.max() > s.lab.sensor.max_force):
            return f"tensions {t}"
    if not (0 < s.scanner.distance < 10) or not math.isfinite(s.scanner.distance):
        return f"scanner distance {s.scanner.distance}"
    noise = s.scanner.noise_model
    if noise is not None:
        values = [v for v in vars(noise).values() if isinstance(v, int | float)]
        if not _finite(values) or min(values, default=0) < 0:
            return f"scan noise {noise}"
    if not _finite(s.force_sensor.noise_std, s.force_sensor.bias) or np.min(s.force_sensor.noise_std) < 0:
        return f"force sensor {s.force_sensor}"
    if not (isinstance(s.seed, int) and s.seed >= 0) or s.n_tests < 1:
        return f"seed {s.seed!r}, {s.n_tests} tests"
    return ""


def test_fuzz_scenario_texts_and_tables(tmp_path):
    text = (ROOT / "scenarios" / "kr60_paper.toml").read_text()
    data = tomllib.loads(text)
    rng, tally, path = random.Random(13), Tally(), tmp_path / "s.toml"
    for case in range(CASES):
        if case % 2:
            mutated = _mutate_tree(data, rng)
            tally.run(case, lambda m=mutated: parse_scenario(m, "fuzz.toml"), _check_scenario)
        else:
            path.write_bytes(_mutate_text(text, rng))
            tally.run(case, lambda: load_scenario(path), _check_scenario)
    tally.assert_clean()


def _check_campaign(c) -> str:
    problem = _check_scenario(c.scenario)
    if problem:
        return problem
    if not (isinstance(c.trials, int) and c.trials >= 1) or not (isinstance(c.seed, int) and c.seed >= 0):
        return f"trials {c.trials!r}, seed {c.seed!r}"
    for cell in c.cells():
        scales = [v for v in (cell.scanner_noise_scale, cell.ft_noise_scale) if v is not None]
        if not _finite(scales) or min(scales) < 0 or cell.n_tests < 2:
            return f"cell {cell}"
    return ""


def test_fuzz_campaign_tables(tmp_path):
    text = (ROOT / "scenarios" / "kr60_sweep_quick.toml").read_text()
    data = tomllib.loads(text)
    rng, tally = random.Random(14), Tally()
    for case in range(CASES):
        mutated = copy.deepcopy(data)
        mutated["campaign"] = _mutate_tree(data["campaign"], rng) if case % 4 else _mutate_tree(data, rng).get(
            "campaign", {}
        )  # fmt: skip
        tally.run(case, lambda m=mutated: parse_campaign(m, "fuzz.toml"), _check_campaign)
    tally.assert_clean()


def _check_setup(s) -> str:
    if not (isinstance(s.robot, str) and s.robot) or s.angle_convention not in ("dh", "controller"):
        return f"robot {s.robot!r}, convention {s.angle_convention!r}"
    if not _finite(s.block_in_flange, s.sensor_in_flange, s.sensor_range, s.block_edge):
        return "non-finite numbers"
    if s.block_edge <= 0 or min(s.sensor_range) <= 0 or len(s.sensor_range) != 6:
        return f"edge {s.block_edge}, range {s.sensor_range}"
    for m in (s.block_in_flange, s.sensor_in_flange):
        if m.shape != (4, 4) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6):
            return f"not a rigid transform: {m}"
    return ""


def test_fuzz_setup_json(tmp_path, lab):
    write_setup(tmp_path, _setup(lab))
    text = (tmp_path / "setup.json").read_text()
    data = json.loads(text)
    rng, tally = random.Random(15), Tally()
    for case in range(CASES):
        if case % 2:
            (tmp_path / "setup.json").write_text(json.dumps(_mutate_tree(data, rng)))
        else:
            (tmp_path / "setup.json").write_bytes(_mutate_text(text, rng))
        tally.run(case, lambda: read_setup(tmp_path), _check_setup)
    tally.assert_clean()


def _check_tests(root: Path):
    base = root.resolve()

    def check(records) -> str:
        for r in records:
            if not _finite(r.q_deg, r.wrench_unloaded, r.wrench_loaded, r.scanner_pose):
                return f"{r.test_id}: non-finite numbers"
            if r.group not in ("identification", "validation") or not r.test_id.strip():
                return f"{r.test_id!r}: group {r.group!r}"
            if np.any(np.abs(r.wrench_loaded) > np.array(RANGE)) or np.any(
                np.abs(r.wrench_unloaded) > np.array(RANGE)
            ):
                return f"{r.test_id}: an overload accepted"  # fmt: skip
            for c in (r.cloud_unloaded, r.cloud_loaded):
                if not Path(c).resolve().is_relative_to(base):
                    return f"{r.test_id}: cloud {c} outside the dataset"
        ids = [r.test_id for r in records]
        return "duplicate ids" if len(set(ids)) != len(ids) else ""

    return check


RANGE = (1000.0,) * 6  # above the synthetic readings (normal, std 100)


def test_fuzz_tests_csv(tmp_path, lab):
    write_setup(tmp_path, _setup(lab))
    _write(tmp_path, _records(tmp_path, count=4))
    text = (tmp_path / "tests.csv").read_text()
    header, *rows = text.splitlines()
    rng, tally = random.Random(16), Tally()
    tokens = ["nan", "inf", "-inf", "1e999", "", "x", "../../x.ply", "/etc/passwd", "clouds/../../y.ply",
              "calibration", "1e3", "-1e3", " ", '"', "é"]  # fmt: skip
    for case in range(CASES):
        if case % 2:
            lines = [r.split(",") for r in rows]
            for _ in range(rng.randint(1, 2)):
                fields = rng.choice(lines)
                op = rng.random()
                if op < 0.7:
                    fields[rng.randrange(len(fields))] = rng.choice(tokens)
                elif op < 0.85:
                    del fields[rng.randrange(len(fields))]
                else:
                    fields.append(rng.choice(tokens))
            (tmp_path / "tests.csv").write_text("\n".join([header, *(",".join(f) for f in lines)]) + "\n")
        else:
            (tmp_path / "tests.csv").write_bytes(_mutate_text(text, rng))
        tally.run(
            case, lambda: read_tests(tmp_path, check_files=False, sensor_range=RANGE), _check_tests(tmp_path)
        )
    tally.assert_clean()


@pytest.mark.parametrize("distance", [DEFAULT_SCANNER_DISTANCE_M])
def test_the_fuzzed_files_start_valid(tmp_path, lab, distance):
    """The seeds of the fuzzing are valid files (else every case would be refused for one reason)."""
    s = load_scenario(ROOT / "scenarios" / "kr60_paper.toml")
    assert _check_scenario(s) == "" and s.scanner.distance == pytest.approx(distance, rel=1e-12)
    assert _check_campaign(parse_campaign(tomllib.loads((ROOT / "scenarios" / "kr60_sweep_quick.toml").read_text()))) == ""  # fmt: skip
    write_setup(tmp_path, _setup(lab))
    _write(tmp_path, _records(tmp_path, count=4))
    assert _check_setup(read_setup(tmp_path)) == ""
    assert _check_tests(tmp_path)(read_tests(tmp_path, sensor_range=RANGE)) == ""
