"""Hidden effects the world cannot hold: refused with the effect's field, not run into numbers.

A softening joint spring (``nonlinear_joint`` with k3 < 0) has the torque ``k dq + k3 dq^3``,
which peaks at ``dq* = sqrt(k / (3 |k3|))`` at ``2/3 k dq*`` (closed form): past it there is no
stable equilibrium. A joint coupling must keep the stiffness matrix positive definite,
``|k_ij| < sqrt(k_i k_j)``. Both are checked against those closed forms here.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import paper_scenario_data

from vtestbed.errors import ConvergenceError, OutOfRangeError, ScenarioError
from vtestbed.experiment import check_world_effects, simulate
from vtestbed.scenario import load_scenario
from vtestbed.scenario_writer import toml_text
from vtestbed.world.effects import NonlinearJoint
from vtestbed.world.rig import Rig
from vtestbed.world.truth import load_truth

POSE = np.radians([0.0, -60.0, -20.0, 30.0, 50.0, 45.0])


def _rig(k3: float) -> Rig:
    rig = Rig(effects=(NonlinearJoint(joint=2, k3_Nm_per_rad3=k3),))
    rig.command(POSE)
    rig.hook("hook_x", "ring_5")
    return rig


def test_a_spring_softened_past_its_peak_is_refused_with_its_cap():
    k = float(load_truth("kuka_kr60_3").stiffness_true[1])
    k3 = -1e13
    cap = 2.0 / 3.0 * k * np.sqrt(k / (3.0 * -k3))  # closed form: 103.8 N*m for the KR60's joint 2
    with pytest.raises((OutOfRangeError, ConvergenceError)) as info:
        _rig(k3).solve()
    message = str(info.value)
    assert "world.effects[0] (nonlinear_joint).k3_Nm_per_rad3 = -1e+13" in message
    assert float(message.split("spring torque at ")[1].split(" N*m")[0]) == pytest.approx(cap, rel=1e-3)


def test_a_mild_softening_spring_keeps_a_stable_equilibrium():
    """k3 = -1e9: the cap is 10.4 kN*m, far above joint 2's gravity load; the equilibrium holds
    with a positive tangent stiffness, below the linear spring's (softening)."""
    k = float(load_truth("kuka_kr60_3").stiffness_true[1])
    effect = NonlinearJoint(joint=2, k3_Nm_per_rad3=-1e9)
    rig = _rig(effect.k3_Nm_per_rad3)
    state = rig.solve()
    dq = float(state.deflection[1])
    assert abs(dq) > 1e-5  # loaded: the check looked at a real deflection
    assert 0.0 < effect.tangent_stiffness(k, dq) < k


def test_a_coupling_that_breaks_positive_definiteness_is_refused_before_anything_is_written(tmp_path):
    truth = load_truth("kuka_kr60_3").stiffness_true
    limit = np.sqrt(truth[4] * truth[5])  # |k56| < sqrt(k5 k6)
    data = paper_scenario_data(2, 1, "coupled", 1)
    path = tmp_path / "coupled.toml"
    data["world"] = {
        "effects": [{"name": "joint_coupling", "joints": [5, 6], "stiffness_Nm_per_rad": -1.01 * limit}]
    }
    path.write_text(toml_text(data))
    with pytest.raises(ScenarioError) as info:
        simulate(load_scenario(path), tmp_path / "out")
    message = str(info.value)
    assert message.startswith(f"{path}: world.effects[0] (joint_coupling).stiffness_Nm_per_rad")
    assert f"sqrt(k_i k_j) = {limit:.4g} N*m/rad" in message
    assert not (tmp_path / "out").exists()
    data["world"]["effects"][0]["stiffness_Nm_per_rad"] = -0.99 * limit  # inside: the rig builds
    path.write_text(toml_text(data))
    sc = load_scenario(path)
    check_world_effects(sc)
    assert Rig(sc.robot, sc.lab, effects=sc.effects).effects[0].stiffness_Nm_per_rad == pytest.approx(
        -0.99 * limit
    )


def test_an_effect_that_makes_the_arm_sag_is_refused():
    """A balancer 10^7 N/m with no free length pulls joint 2 by tens of mrad at rest (fuzz review:
    a 27 deg sag went into a dataset). The clean arm deflects by about 1 mrad; the limit is 50."""
    from vtestbed.world.effects import GravityCompensator
    from vtestbed.world.rig import MAX_DEFLECTION_RAD

    clean = Rig()
    clean.command(POSE)
    assert np.max(np.abs(clean.solve().deflection)) < MAX_DEFLECTION_RAD / 20
    rig = Rig(effects=(GravityCompensator(spring_rate_N_per_m=1e7, free_length_m=0.0),))
    rig.command(POSE)
    with pytest.raises(
        OutOfRangeError, match=r"joint2 deflects -?[\d.]+ mrad .* beyond 50 mrad: .*gravity_compensator"
    ):
        rig.solve()


def test_the_sag_check_looks_at_effects_on_the_statics_only():
    """A robot soft on purpose (the joint springs 100 times softer: the clean arm then sags by tens
    of mrad, as the solver's own tests use it) with an effect on the sensors alone is the clean
    rig's statics and is not refused; an effect on the statics beside it is, and is the only one
    the message names."""
    import dataclasses

    from vtestbed.world.effects import LinkCompliance, ScannerScale
    from vtestbed.world.rig import MAX_DEFLECTION_RAD

    truth = load_truth("kuka_kr60_3")
    soft = dataclasses.replace(truth, stiffness=tuple(k / 100.0 for k in truth.stiffness))
    sensors_only = Rig(truth=soft, effects=(ScannerScale(),))
    sensors_only.command(POSE)
    sensors_only.hook("hook_x", "ring_5")
    clean = Rig(truth=soft)
    clean.command(POSE)
    clean.hook("hook_x", "ring_5")
    sag = sensors_only.solve().deflection
    assert np.max(np.abs(sag)) > MAX_DEFLECTION_RAD  # the soft arm's own sag, past the limit
    np.testing.assert_array_equal(sag, clean.solve().deflection)  # the scale leaves the statics
    both = Rig(truth=soft, effects=(ScannerScale(), LinkCompliance()))
    both.command(POSE)
    both.hook("hook_x", "ring_5")
    with pytest.raises(OutOfRangeError, match=r"beyond 50 mrad: .*\(world.effects: link_compliance\)"):
        both.solve()


def test_an_effect_is_named_by_its_place_in_the_file_when_a_null_one_comes_first(tmp_path):
    """A zero-size effect is off (dropped from the world), not renumbered: the coupling after it is
    world.effects[1], as in the file."""
    data = paper_scenario_data(2, 1, "numbered", 1)
    data["world"] = {"effects": [{"name": "gravity_compensator", "spring_rate_N_per_m": 0.0},
                                 {"name": "joint_coupling", "joints": [5, 6], "stiffness_Nm_per_rad": -1e8}]}  # fmt: skip
    path = tmp_path / "numbered.toml"
    path.write_text(toml_text(data))
    with pytest.raises(ScenarioError, match=r"numbered.toml: world.effects\[1\] \(joint_coupling\)"):
        check_world_effects(load_scenario(path))
    sc = load_scenario(path)
    with pytest.raises(OutOfRangeError, match=r"^world.effects\[1\] \(joint_coupling\)"):
        Rig(sc.robot, sc.lab, effects=sc.effects)
