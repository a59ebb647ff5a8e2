"""The command line: exit codes, the files each command writes and its one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from quick_campaign import BASE_TEXT, TINY_TOML

from vtestbed.cli.main import main
from vtestbed.design import kappa
from vtestbed.ply import read_ply
from vtestbed.world.rig import Rig

POSE_DEG = (0.0, -60.0, -20.0, 30.0, 50.0, 45.0)


def test_scan_command_writes_clouds_and_matching_displacements(tmp_path, capsys):
    from vtestbed.cli.main import main
    from vtestbed.transforms import displacement

    assert main(["scan", "--out", str(tmp_path), "--noise-free"]) == 0
    import json

    result = json.loads((tmp_path / "scan.json").read_text())
    measured, true = np.array(result["displacement_measured"]), np.array(result["displacement_true"])
    assert measured.shape == (6,) and np.abs(measured - true).max() < 1e-9
    # the truth restated from an independent rig run
    rig = Rig()
    rig.command(np.radians(POSE_DEG))
    rig.hook("hook_x", "ring_5")
    s0, s1 = rig.solve(), rig.tighten(200.0)
    np.testing.assert_allclose(true, displacement(s0.block_pose, s1.block_pose), atol=1e-12)
    points = read_ply(tmp_path / "loaded.ply")
    assert len(points) == result["clouds"]["points"][1] > 40000
    assert "measured" in capsys.readouterr().out
    assert main(["scan", "--out", str(tmp_path), "--view", "1,1"]) == 2
    assert "--view must be 3 finite numbers" in capsys.readouterr().err


def test_cli_criterion_and_optimize(robot, tmp_path, capsys):
    assert main(["poses", "criterion", "--q-deg", "0,-30,-20,40,60,45"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["inv_kappa"] == pytest.approx(
        kappa.criterion(robot, np.radians([0, -30, -20, 40, 60, 45])).inv_kappa
    )
    assert main(["poses", "criterion", "--q-deg", "0,-30,-20,40,160,45"]) == 2
    assert "joint5 = 160.000 deg" in capsys.readouterr().err
    assert main(["poses", "optimize", "--out", str(tmp_path), "--seed", "3"]) == 0
    saved = json.loads((tmp_path / "optimum.json").read_text())
    assert len(saved["q_deg"]) == 6 and saved["inv_kappa"] == pytest.approx(0.934786, abs=1e-6)


def test_invalid_campaign_errors_before_any_work(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    text = BASE_TEXT + TINY_TOML
    cases = (
        ("n_test = [3, 4]", "campaign.axes.n_test: unknown axis; valid axes: pose_set, n_tests"),
        ("n_tests = []", "campaign.axes.n_tests: is empty"),
        ("n_tests = [3, 1]", "campaign.axes.n_tests[1]: must be an integer in [2, 500], got 1"),
        ("n_tests = [3, 4]\nmethod = ['lsq']", "campaign.axes.method[0]: 'lsq' is not one of ols, fgls"),
    )
    for replacement, message in cases:
        path.write_text(text.replace("n_tests = [3, 4]", replacement))
        assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert message in err, err
    assert not (tmp_path / "out").exists()  # nothing was started


def test_identify_method_choices_are_the_scenario_methods():
    from vtestbed.cli.experiment import IDENTIFY_METHODS
    from vtestbed.scenario import METHODS

    assert IDENTIFY_METHODS == METHODS
