"""scenarios/kr60_minimax20.toml against its two sources: its 20 tests are the minimax design's
table in docs/poses.md (controller angles, rounded to 0.01 deg there), and everything else is
scenarios/kr60_paper.toml's, so that the two scenarios differ in their identification tests only
(the naming forecast and the discrepancy benchmark compare them)."""

import re
import tomllib
from pathlib import Path

import numpy as np

from vtestbed.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "kr60_minimax20.toml"
TABLE_HEADING = "The 20 minimax tests for the KR60 with tensions up to 200 N"


def docs_table() -> list[tuple[list[float], str, str, float]]:
    text = (ROOT / "docs" / "poses.md").read_text()
    block = text[text.index(TABLE_HEADING) :]
    rows = []
    for line in block.splitlines():
        m = re.match(r"\| (\d+) \| ([-\d., ]+) \| (\w+) \| (\w+) \| ([\d.]+) \|", line)
        if not m:
            if rows:
                break  # the table's end
            continue  # the heading's text and the table's header rows
        rows.append(([float(v) for v in m.group(2).split(",")], m.group(3), m.group(4), float(m.group(5))))
    return rows


def test_the_tests_are_the_docs_minimax_table():
    sc = load_scenario(SCENARIO)
    rows = docs_table()
    assert len(rows) == 20 == len(sc.poses)
    controller = np.degrees([sc.robot.dh_to_controller(q) for q in sc.poses])
    np.testing.assert_allclose(controller, [r[0] for r in rows], atol=0.0051)  # the table's rounding
    assert list(sc.load.hooks) == [r[1] for r in rows]
    assert list(sc.load.anchors) == [r[2] for r in rows]
    assert list(sc.load.tensions) == [r[3] for r in rows]


def test_everything_else_is_the_paper_scenarios():
    ours = tomllib.loads(SCENARIO.read_text())
    paper = tomllib.loads((ROOT / "scenarios" / "kr60_paper.toml").read_text())
    for key in ("name", "description", "poses", "load"):
        ours.pop(key), paper.pop(key)
    assert ours == paper
