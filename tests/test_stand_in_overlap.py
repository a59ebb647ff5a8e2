"""How much of a named term's pattern another candidate reproduces (diagnose.stand_in_overlap).

Reference: the squared cosine of the angle between the pattern and the candidate's span
(scipy.linalg.subspace_angles), both with the stiffness columns projected out through
scipy.linalg.null_space; a clone of the named term reproduces it fully, a stiffness column not
at all. Data: noise-free world measurements of the paper's tests with a block offset hidden.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import null_space, subspace_angles
from test_researcher_discrepancy import PAPER, SIGMA, world_measurements

from vtestbed.researcher.candidates import Candidate, ModelContext, candidates
from vtestbed.researcher.diagnose import STAND_IN_R2, Whitener, fit_model, name_effects, stand_in_overlap
from vtestbed.researcher.discrepancy import stand_ins
from vtestbed.researcher.identify import stack
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.scenario import load_scenario
from vtestbed.world.effects import BlockOffset


@pytest.fixture(scope="module")
def hidden_offset():
    effect = BlockOffset(translation_mm=(1.0, -0.5, 0.8), rotation_deg=(0.5, -0.3, 1.0))
    setup, kin, ms = world_measurements(load_scenario(PAPER), (effect,), gravity=False, n=20)
    ctx = ModelContext(ms, setup, kin)
    return ctx, Whitener(NoiseFloor(np.diag(SIGMA**2), n_samples=100, n_tests=20)), candidates(kin)


def _stiffness_column(ctx) -> Candidate:
    def columns(c, compliance):
        return stack([m.jacobian for m in c.measurements], [m.wrench for m in c.measurements])[:, :1]

    return Candidate("stiffness", "joint 1's compliance", ("c1",), columns)


def test_overlap_is_the_squared_cosine_to_the_candidates_span(hidden_offset):
    ctx, white, pool = hidden_offset
    by = {c.label: c for c in pool}
    named = by["block_offset(rotation)"]
    fit = fit_model(ctx, white, [named])
    clone = replace(named, label="block_offset (clone)")
    others = [clone, _stiffness_column(ctx), *(c for c in pool if c is not named)]
    overlap = stand_in_overlap(ctx, white, fit, named, [], others)
    assert overlap["block_offset (clone)"] == pytest.approx(1.0, abs=1e-9)
    assert overlap["joint 1's compliance"] < 1e-9
    ms = ctx.measurements
    keep = null_space(white(stack([m.jacobian for m in ms], [m.wrench for m in ms])).T)  # stiffness-free
    theta = np.array(list(fit.theta["block_offset(rotation)"].values()))
    pattern = keep.T @ (white(named.columns(ctx, fit.compliance)) @ theta)
    for cand in pool:
        if cand is named:
            continue
        span = keep.T @ white(cand.columns(ctx, fit.compliance))
        expected = np.cos(subspace_angles(pattern[:, None], span)[0]) ** 2
        assert overlap[cand.label] == pytest.approx(expected, abs=1e-6), cand.label
    assert 0.0 <= min(overlap.values()) and max(overlap.values()) <= 1.0


def test_the_search_records_each_rounds_overlap(hidden_offset):
    """The chosen term's round carries every other candidate's overlap (its own row: None)."""
    ctx, white, pool = hidden_offset
    chosen, steps, _ = name_effects(ctx, white, pool)
    assert [c.label for c in chosen] == ["block_offset(rotation)"]
    rows = {r["label"]: r["overlap"] for r in steps[0].tests}
    assert rows["block_offset(rotation)"] is None
    fit = fit_model(ctx, white, chosen)
    again = stand_in_overlap(ctx, white, fit, chosen[0], [], [c for c in pool if c is not chosen[0]])
    for label, value in again.items():
        assert rows[label] == pytest.approx(value, abs=1e-9)


def test_the_report_lists_the_candidates_that_could_stand_in():
    """Only named terms, only overlaps at or above STAND_IN_R2, largest first; an absorbed
    candidate (no free parameter, df 0) is not a stand-in."""
    rows = [{"label": "a", "overlap": None}, {"label": "b", "overlap": 0.98}, {"label": "c", "overlap": 0.2},
            {"label": "d", "overlap": STAND_IN_R2}, {"label": "e", "overlap": 0.75}]  # fmt: skip
    rows = [{**r, "df": 1} for r in rows] + [{"label": "f", "overlap": 0.99, "df": 0}]
    other = [{"label": "b", "overlap": None, "df": 1}, {"label": "a", "overlap": 0.9, "df": 1}]
    report = {"named": ["a"], "rounds": [{"chosen": "a", "tests": rows}, {"chosen": "b", "tests": other}]}
    assert stand_ins(report) == {"a": [("b", 0.98), ("e", 0.75), ("d", STAND_IN_R2)]}
    rows[1]["overlap"] = STAND_IN_R2 - 1e-9
    assert [label for label, _ in stand_ins(report)["a"]] == ["e", "d"]


def test_a_confusable_round_records_the_runner_ups_overlap(hidden_offset):
    """A clone of the hidden block offset ties with it (a confusable round): the round carries the
    shares of the runner-up's pattern too, each the squared cosine to the candidate's span."""
    ctx, white, pool = hidden_offset
    clone = replace(
        next(c for c in pool if c.label == "block_offset(rotation)"), label="block_offset (clone)"
    )
    chosen, steps, _ = name_effects(ctx, white, [*pool, clone], max_terms=1)
    first = steps[0]
    assert (first.chosen, first.runner_up) == ("block_offset(rotation)", "block_offset (clone)")
    assert first.delta == pytest.approx(0.0, abs=1e-6)
    rows = {r["label"]: r["runner_overlap"] for r in first.tests}
    assert rows["block_offset (clone)"] is None and rows["block_offset(rotation)"] == pytest.approx(
        1.0, abs=1e-9
    )
    ms = ctx.measurements
    keep = null_space(white(stack([m.jacobian for m in ms], [m.wrench for m in ms])).T)
    fit = fit_model(ctx, white, [clone])
    pattern = keep.T @ (
        white(clone.columns(ctx, fit.compliance)) @ np.array(list(fit.theta[clone.label].values()))
    )
    for cand in pool:
        if cand.label == "block_offset(rotation)":
            continue
        span = keep.T @ white(cand.columns(ctx, fit.compliance))
        expected = np.cos(subspace_angles(pattern[:, None], span)[0]) ** 2
        assert rows[cand.label] == pytest.approx(expected, abs=1e-6), cand.label
    # a decisive round (no clone) has no such column
    _, steps, _ = name_effects(ctx, white, pool, max_terms=1)
    assert all("runner_overlap" not in r for r in steps[0].tests)
