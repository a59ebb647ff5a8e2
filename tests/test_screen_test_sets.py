"""benchmarks/screen_test_sets.py's bookkeeping, against references written by hand: the draws an
interrupted run keeps (its ``screen.jsonl`` with a half-written last line), the max-min choice of
the kept draw (effects against 80 %, pairs against 90 %), the seed range, and the benchmark worlds' switch of scenario (a prepared world of
the previous scenario must not be reused: the cache's key names the effect and size only).
"""

import json
import sys
from pathlib import Path

import pytest

from vtestbed.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import _discrepancy_worlds  # noqa: E402
import screen_test_sets as screen  # noqa: E402


def record(seed: int, shares: dict[str, float], pairs: dict[str, float] | None = None) -> dict:
    rec = {"seed": seed, "effects": {n: {"right": v} for n, v in shares.items()}, "pairs": pairs or {}}
    return {**rec, **screen.margins(rec)}


def test_an_interrupted_screen_keeps_its_finished_draws(tmp_path):
    log = tmp_path / "screen.jsonl"
    kept = [record(2023, {"a": 0.81, "b": 0.9}), record(2024, {"a": 0.7, "b": 0.95})]
    text = "".join(json.dumps(r) + "\n" for r in kept) + json.dumps(record(2025, {"a": 0.5}))[:40]
    log.write_text(text)  # the run stopped while writing seed 2025's line
    done = screen.finished(log)
    assert sorted(done) == [2023, 2024]
    assert done[2024]["effects"]["b"]["right"] == pytest.approx(0.95, abs=1e-12)
    assert screen.finished(tmp_path / "absent.jsonl") == {}


def test_the_kept_draw_is_the_best_worst_effect_not_the_best_mean():
    records = [
        record(1, {"a": 0.99, "b": 0.99, "c": 0.70}),  # best mean 0.893, worst 0.70
        record(2, {"a": 0.82, "b": 0.83, "c": 0.81}),  # worst 0.81: kept
        record(3, {"a": 0.80, "b": 0.81, "c": 0.81}),  # worst 0.80
        record(4, {"a": 0.81, "b": 0.81, "c": 0.81}),  # worst 0.81 too, lower mean than 2
    ]
    assert screen.best_draw(records)["seed"] == 2
    assert records[0]["worst"] == "c" and records[0]["mean_right"] == pytest.approx(2.68 / 3)


def test_a_pair_below_its_target_weighs_against_the_effects_margins():
    records = [
        record(1, {"a": 0.86, "b": 0.85}, {"x+y": 0.88}),  # effects +5 points, the pair -2: margin -2
        record(2, {"a": 0.82, "b": 0.81}, {"x+y": 0.95}),  # effects +1, the pair +5: margin +1, kept
        record(3, {"a": 0.90, "b": 0.79}, {"x+y": 0.99}),  # effect b -1
    ]
    assert [r["short"] for r in records] == ["x+y", "b", "b"]
    assert [r["margin"] for r in records] == pytest.approx([-0.02, 0.01, -0.01])
    assert screen.best_draw(records)["seed"] == 2
    pairs_only = screen.margins({"effects": {}, "pairs": {"x+y": 0.93, "u+v": 0.97}})
    assert pairs_only["worst"] is None and pairs_only["short"] == "x+y"
    assert pairs_only["margin"] == pytest.approx(0.03)


@pytest.mark.parametrize(("text", "seeds"), [("2023", [2023]), ("2023-2026", [2023, 2024, 2025, 2026])])
def test_seed_range(text, seeds):
    assert screen.seed_range(text) == seeds


@pytest.mark.parametrize("text", ["2026-2023", "a-b", "2023-"])
def test_seed_range_refuses_an_empty_or_malformed_range(text):
    with pytest.raises(ValueError):
        screen.seed_range(text)


def test_a_new_scenario_drops_the_previous_prepared_world(monkeypatch):
    monkeypatch.setenv("VTESTBED_BENCH_SCENARIO", str(_discrepancy_worlds.SCENARIO))
    before = _discrepancy_worlds.SCENARIO
    try:
        for name in ("kr60_paper.toml", "kr60_paper_a6.toml"):
            _discrepancy_worlds.set_scenario(ROOT / "scenarios" / name)
            prepared, _ = _discrepancy_worlds.prepared_world(None, 1.0, validation=False)
            want = load_scenario(ROOT / "scenarios" / name)
            assert prepared.scenario.name == want.name
            assert len(prepared.tests) == len(want.poses)
    finally:
        _discrepancy_worlds.set_scenario(before)
