"""The rivals ``discover`` refits (vtestbed/discovery.py) are the models ``diagnose`` tests.

No simulation: the paper's 20 tests at their nominal wrench and Jacobian, displacements made
from the true compliances (Table 5) plus a base tilt. References: the true compliances, and
``numpy.linalg.matrix_rank`` of the whitened columns for the parameters BIC charges.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from vtestbed.dataset import DatasetSetup
from vtestbed.design import discriminate as disc
from vtestbed.design.priors import PAPER_TABLE5
from vtestbed.discovery import measured_separation, researcher_pool
from vtestbed.researcher.candidates import ModelContext, candidates
from vtestbed.researcher.diagnose import Whitener
from vtestbed.researcher.identify import stack
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import TestMeasurement
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.scenario import load_scenario

SIGMA = np.array([5.3e-6] * 3 + [8.5e-6] * 3)
TRUE_C = 1.0 / PAPER_TABLE5.stiffness


@pytest.fixture(scope="module")
def paper_tests():
    sc = load_scenario("scenarios/kr60_paper.toml")
    kin = ArmKinematics(sc.robot, sc.lab.block_in_flange)
    setup = DatasetSetup(sc.robot.name, "dh", sc.lab.block_in_flange, sc.lab.sensor_in_flange,
                         sc.lab.block.edge, sc.lab.sensor.name, sc.lab.sensor.wrench_range)  # fmt: skip
    tensions = np.broadcast_to(sc.load.tensions, (sc.n_tests,))
    tests = [SimpleNamespace(q=q, hook=hook, anchor=anchor, tension=float(t))
             for q, hook, anchor, t in zip(sc.poses, sc.load.hooks, sc.load.anchors, tensions)]  # fmt: skip
    ctx = disc.proposed_context(kin, setup, sc.lab, tests)
    white = Whitener(NoiseFloor(np.diag(SIGMA**2), n_samples=10**9, n_tests=20))
    return ctx, white, {c.label: c for c in candidates(kin)}


def _with(ctx, displacement):
    ms = [TestMeasurement(m.test_id, m.group, m.q, m.wrench, displacement[6 * i : 6 * i + 6], m.jacobian,
                          m.frame_unloaded, m.frame_loaded) for i, m in enumerate(ctx.measurements)]  # fmt: skip
    return ModelContext(ms, ctx.setup, ctx.kin, ctx.statics)


def test_the_base_twist_that_joint_1_explains_is_left_out(paper_tests):
    """With every base parameter in the fit, least squares split joint 1's compliance with the
    base's twist by minimum norm (joint 1 at 4.4e6 against 2.2e6 N*m/rad)."""
    ctx, white, terms = paper_tests
    ms = ctx.measurements
    ctx = _with(ctx, stack([m.jacobian for m in ms], [m.wrench for m in ms]) @ TRUE_C)
    pool = {c.label: c for c in researcher_pool(ctx, white)}
    assert len(pool["base_compliance"].params) == len(terms["base_compliance"].params) - 1
    (hyp,) = disc.fit_hypotheses(ctx, white, [], ["base_compliance"], list(pool.values()))
    np.testing.assert_allclose(hyp.compliance, TRUE_C, rtol=1e-6)


def test_bic_charges_the_independent_columns(paper_tests):
    ctx, white, terms = paper_tests
    ms = ctx.measurements
    a = stack([m.jacobian for m in ms], [m.wrench for m in ms])
    base = terms["base_compliance"]
    tilt = base.columns(ctx, TRUE_C) @ np.array([0.0, 2e-7, 0.0])
    ctx = _with(ctx, a @ TRUE_C + tilt)
    out = measured_separation(
        ctx, white, list(terms.values()), {"base_terms": [], "rivals": ["baseline", "base_compliance"]}
    )
    ln_n = np.log(6 * ctx.n_tests)
    rank = np.linalg.matrix_rank(white(np.hstack([a, base.columns(ctx, TRUE_C)])))
    assert rank == 8  # 6 compliances and the base's two tilts: its twist is joint 1's column
    assert out["bic"]["base_compliance"] == pytest.approx(
        out["chi2"]["base_compliance"] + rank * ln_n, rel=1e-12
    )
    assert out["bic"]["baseline"] == pytest.approx(out["chi2"]["baseline"] + 6 * ln_n, rel=1e-12)
