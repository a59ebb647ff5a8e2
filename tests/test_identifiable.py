"""Parameters the stiffnesses already explain are left out of a candidate (diagnose.identifiable).

References: the closed form of a base twist (joint 1 of the KR60 turns about the base's z axis
through its origin, so a twist of the foundation about z moves the block exactly as joint 1
does) and series springs (the world's joint 1 and its foundation twist in series have the
compliance ``1/k1 + 1/k_twist``, which the fit must recover as joint 1's). Data: noise-free world
measurements of the paper's 20 tests with a compliant foundation hidden (MuJoCo).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_researcher_discrepancy import PAPER, SIGMA, world_measurements

from vtestbed.researcher.candidates import ModelContext, candidates
from vtestbed.researcher.diagnose import Whitener, _drop_redundant, fit_model, identifiable
from vtestbed.researcher.identify import stack
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.researcher.statics import ExactStatics
from vtestbed.scenario import load_scenario
from vtestbed.world.effects import BaseCompliance
from vtestbed.world.truth import load_truth

BASE = BaseCompliance(stiffness_Nm_per_rad=(4e7, 5e7, 8e7))  # about x5 the realistic foundation


@pytest.fixture(scope="module")
def foundation():
    scenario = load_scenario(PAPER)
    setup, kin, ms = world_measurements(scenario, (BASE,), n=20)
    ctx = ModelContext(ms, setup, kin, ExactStatics(kin, setup))
    white = Whitener(NoiseFloor(np.diag(SIGMA**2), n_samples=100, n_tests=20))
    return ctx, white, load_truth(scenario.robot.name).stiffness


def test_the_base_twist_is_joint_1_and_is_left_out(foundation):
    ctx, white, _ = foundation
    ms = ctx.measurements
    joint1 = stack([m.jacobian for m in ms], [m.wrench for m in ms])[:, 0]
    twist = np.concatenate(
        [ctx.hinge_column(t, np.zeros(3), np.array([0.0, 0.0, 1.0])) for t in range(len(ms))]
    )
    np.testing.assert_allclose(twist, joint1, rtol=0, atol=1e-12 * np.abs(joint1).max())  # closed form
    (base,) = candidates(ctx.kin, ("base_compliance",))
    (kept,) = identifiable(ctx, white, [base], fit_model(ctx, white, []).compliance)
    assert kept.params == ("compliance_tilt_x_rad_per_Nm", "compliance_tilt_y_rad_per_Nm")
    ((param, note),) = kept.absorbed
    assert param == "compliance_twist_z_rad_per_Nm" and note.startswith(
        "absorbed into joint1 (R^2 = 1.00000)"
    )
    assert kept.columns(ctx, None).shape == (6 * len(ms), 2)
    others = candidates(ctx.kin, ("link_compliance", "joint_coupling"))
    assert identifiable(ctx, white, others, None) == others  # nothing of theirs is joint-like


def test_joint_1_comes_out_in_series_with_the_twist_and_the_tilts_are_the_worlds(foundation):
    ctx, white, k_true = foundation
    (base,) = candidates(ctx.kin, ("base_compliance",))
    kept = identifiable(ctx, white, [base], fit_model(ctx, white, []).compliance)
    fit = fit_model(ctx, white, kept)
    k_tilt_x, k_tilt_y, k_twist = BASE.stiffness_Nm_per_rad
    series = 1.0 / (1.0 / k_true[0] + 1.0 / k_twist)
    assert fit.stiffness[0] == pytest.approx(series, rel=1e-3)
    np.testing.assert_allclose(fit.stiffness[1:], k_true[1:], rtol=1e-3)
    tilts = fit.theta["base_compliance"]
    assert tilts["compliance_tilt_x_rad_per_Nm"] == pytest.approx(1 / k_tilt_x, rel=0.02)
    assert tilts["compliance_tilt_y_rad_per_Nm"] == pytest.approx(1 / k_tilt_y, rel=0.02)
    assert fit.chi2 < 1.0  # noise free: the two tilts and the six joints explain every test
    # the whole candidate: least squares splits joint 1 between it and the twist (minimum norm)
    split = fit_model(ctx, white, [base])
    assert abs(split.stiffness[0] / series - 1.0) > 0.05


def test_a_term_that_adds_no_direction_adds_no_degree_of_freedom(foundation):
    """Link 2 bending in its plane is a rotation about an axis parallel to joints 2 and 3 at a point
    between them: a combination of joint 2's and joint 3's rotations, so its compliance lies in the
    span of theirs and their coupling's (closed form below). With link 2 in the model, the
    coupling adds no direction: rank, not parameter count, is what the tests count."""
    ctx, white, _ = foundation
    link2 = next(c for c in candidates(ctx.kin, ("link_compliance",)) if c.label == "link_compliance(link 2)")
    coupling = next(c for c in candidates(ctx.kin, ("joint_coupling",)) if c.label == "joint_coupling(2,3)")
    ms = ctx.measurements
    a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
    in_plane = link2.columns(ctx, None)[:, :1]
    span = np.hstack([a[:, 1:3], coupling.columns(ctx, None)])
    coef, *_ = np.linalg.lstsq(span, in_plane, rcond=None)
    assert np.linalg.norm(span @ coef - in_plane) < 1e-9 * np.linalg.norm(in_plane)
    alone, both = fit_model(ctx, white, [link2]), fit_model(ctx, white, [link2, coupling])
    assert alone.rank == 6 + 3 and both.rank == alone.rank  # the search's df: both.rank - alone.rank = 0
    assert both.dof == alone.dof
    # named in the other order, the backward step drops the coupling: link 2 contains it (df 0)
    kept, _, dropped = _drop_redundant(ctx, white, [coupling, link2], both, 0.01, 14, 3)
    assert [t.label for t in kept] == ["link_compliance(link 2)"]
    assert dropped[0]["label"] == "joint_coupling(2,3)" and dropped[0]["df"] == 0
