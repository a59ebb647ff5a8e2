"""Bad option values and broken pipes on the command line (issue 13): one error line naming the
option and its valid values, exit 2, no traceback, nothing written; strict JSON output."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from quick_campaign import QUICK

from vtestbed.cli.args import join_negative_lists
from vtestbed.cli.main import main
from vtestbed.files import dumps, write_json_atomic

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "scenarios" / "kr60_paper.toml")


def _refused(argv, capsys) -> str:
    """The one error line of ``vtestbed argv`` (exit 2, argparse's usage line aside)."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: usage line + error line
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert "Traceback" not in "\n".join(err)
    return err[-1]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["poses", "optimize", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
        (["scan", "--out", "{tmp}/s", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
        (["poses", "regions", "--wrist-jitter-deg", "nan"], "argument --wrist-jitter-deg: must be a finite number in [0, 180] deg, got 'nan'"),
        (["poses", "optimize", "--q6-deg", "nan"], "argument --q6-deg: must be a finite number in [-360, 360] deg, got 'nan'"),
        (["poses", "optimize", "--q6-deg", "1e9"], "argument --q6-deg: must be a finite number in [-360, 360] deg, got '1e9'"),
        (["poses", "optimize", "--q6-deg", "355"], "vtestbed: error: --q6-deg = 355 deg is outside the valid range [-350, 350] deg"),
        (["sweep", "x.toml", "--out", "{tmp}/sw", "--batch-trials", "-5"], "argument --batch-trials: must be an integer >= 1, got '-5'"),
        (["sweep", "x.toml", "--out", "{tmp}/sw", "--workers", "0"], "argument --workers: must be an integer [1, 1024], got '0'"),
        (["simulate", PAPER, "--out", "{tmp}/afile"], "argument --out: {tmp}/afile is a file, not a folder: choose a folder path"),
        (["run", PAPER, "--out", "{tmp}/afile/sub"], "argument --out: {tmp}/afile/sub: {tmp}/afile is a file, so the folder cannot be created"),
        (["poses", "optimize", "--out", "/proc/vtestbed/x"], "argument --out: /proc/vtestbed/x: cannot write in this folder (its parent /proc is not writable, so it cannot be created)"),
        (["demo", "--out", "{tmp}/afile"], "argument --out: {tmp}/afile is a file, not a folder: choose a folder path"),
        (["diagnose", "{tmp}", "--out", "{tmp}/afile"], "argument --out: {tmp}/afile is a file, not a folder: choose a folder path"),
        (["report", "{tmp}", "--out", "{tmp}"], "argument --out: {tmp} is a folder, not a file: give the file to write, e.g. {tmp}/report.html"),
        (["report", "{tmp}", "--out", "{tmp}/afile/r.html"], "argument --out: {tmp}/afile/r.html: cannot write the file: {tmp}/afile is a file, not a folder: choose a folder path"),
        (["report", "{tmp}", "--out", "/proc/r.html"], "argument --out: /proc/r.html: cannot write the file: /proc: cannot write in this folder"),
        (["load", "--tension", "inf"], "argument --tension: must be a finite number in [0, 100000] N, got 'inf'"),
        (["scan", "--out", "{tmp}/s", "--distance-mm", "0"], "argument --distance-mm: must be a finite number in (0, 10000] mm, got '0'"),
        (["poses", "design", "--stiffness-prior", "paper_table5", "--poses", "{tmp}/none.json"], "vtestbed: error: poses file (from 'vtestbed poses regions') {tmp}/none.json is missing (the file does not exist)"),
        (["poses", "design", "--stiffness-prior", "paper_table5", "--poses", "{tmp}/afile"], "vtestbed: error: {tmp}/afile: not valid JSON: Expecting value: line 1 column 1 (char 0)"),
        (["poses", "design", "--stiffness-prior", "paper_table5", "--poses", "{tmp}/ragged.json"], "vtestbed: error: {tmp}/ragged.json: q_deg must be a non-empty list of poses, each 6 finite DH angles in degrees, got [[0, -60, -20, 30, 50, 45], [0, 1]]"),
    ],
)  # fmt: skip
def test_bad_option_values_give_one_line_and_exit_2(tmp_path, capsys, argv, message):
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "ragged.json").write_text(json.dumps({"q_deg": [[0, -60, -20, 30, 50, 45], [0, 1]]}))
    line = _refused([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys)
    assert line.endswith(message.replace("{tmp}", str(tmp_path))), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "ragged.json"]  # nothing written


@pytest.mark.parametrize(
    "argv, message",
    [  # two ways of saying one thing: one would silently win, so both together are refused
        (["load", "--q-deg", "0,-60,-20,30,50,45", "--controller-deg", "0,-60,-20,30,50,45"],
         "vtestbed load: error: argument --controller-deg: not allowed with argument --q-deg"),
        (["scan", "--out", "{tmp}/s", "--controller-deg", "0,-60,-20,30,50,45", "--q-deg=-10,-60,-20,30,50,45"],
         "vtestbed scan: error: argument --q-deg: not allowed with argument --controller-deg"),
        (["poses", "criterion", "--q-deg", "0,-60,-20,30,50,45", "--controller-deg", "0,-60,-20,30,50,45"],
         "vtestbed poses criterion: error: argument --controller-deg: not allowed with argument --q-deg"),
        (["dataset", "import", "{tmp}/manifest.toml", "--out", "{tmp}/ds", "--window", "0.5:1.5", "--window-length", "1"],
         "vtestbed dataset import: error: argument --window-length: not allowed with argument --window"),
    ],
)  # fmt: skip
def test_conflicting_options_are_refused(tmp_path, capsys, argv, message):
    assert _refused([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys) == message
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_poses_design_names_the_poses_file_the_pose_and_gives_a_hint_only_where_it_helps(tmp_path, capsys):
    design = ["poses", "design", "--stiffness-prior", "paper_table5", "--no-bound", "--tests", "1"]
    limits = tmp_path / "limits.json"  # pose 1: joint 5 past the KR60's +-119 deg (datasheet)
    limits.write_text(json.dumps({"q_deg": [[0, -60, -20, 30, 50, 45], [0, -60, -20, 30, 130, 45]]}))
    assert _refused([*design, "--poses", str(limits)], capsys) == (
        f"vtestbed: error: {limits}: q_deg[1]: joint5 = 130.000 deg (DH; controller A5 = 130.000 deg)"
        " is outside its limits [-119.0, 119.0] deg (DH)"
    )
    assert _refused([*design, "--hooks", "hook_x,hook_z"], capsys) == (
        "vtestbed: error: unknown --hooks hook 'hook_z'; valid names: hook_edge, hook_x, hook_y"
    )
    assert _refused([*design, "--anchors", "ring_99"], capsys).startswith(
        "vtestbed: error: unknown --anchors anchor 'ring_99'; valid names: ring_1, ring_2,"
    )
    singular = tmp_path / "singular.json"  # theta5 = 0: refused from the pool, so no test is left
    singular.write_text(json.dumps({"q_deg": [[0, -60, -20, 30, 0, 45]]}))
    line = _refused([*design, "--poses", str(singular)], capsys)
    assert line.startswith("vtestbed: error: no feasible test among 1 poses")
    assert line.endswith("(robot 'kuka_kr60_3'; try other poses, --hooks/--anchors, or --no-clearance)")


@pytest.mark.parametrize(
    "argv, message",
    [  # plain numbers and the option's name, not numpy reprs and internal names
        (["poses", "regions", "--out", "{tmp}/r", "--box", "1,1,1,0,0,0"],
         "vtestbed: error: --box must be x_min,y_min,z_min,x_max,y_max,z_max [m] with each min below its max, got '1,1,1,0,0,0'"),
        (["poses", "regions", "--out", "{tmp}/r", "--box", "0,0,0,1,-1,1"],
         "vtestbed: error: --box must be x_min,y_min,z_min,x_max,y_max,z_max [m] with each min below its max, got '0,0,0,1,-1,1'"),
        (["scan", "--out", "{tmp}/s", "--view", "0,0,0"],
         "vtestbed: error: --view must be a non-zero direction in the block frame, got '0,0,0'"),
    ],
)  # fmt: skip
def test_inverted_box_and_zero_view_name_the_option(tmp_path, capsys, argv, message):
    assert _refused([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys) == message
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_library_range_messages_print_plain_numbers():
    from vtestbed.design.regions import PoseConstraints
    from vtestbed.errors import OutOfRangeError

    with pytest.raises(OutOfRangeError) as exc:
        PoseConstraints(box_min=(np.float64(1.0), 1.0, 1.0), box_max=(0.0, 0.0, np.float64(0.0)))
    assert str(exc.value) == "box_min [1.0, 1.0, 1.0] must be below box_max [0.0, 0.0, 0.0] on every axis [m]"


def test_an_unreachable_or_malformed_scheduler_is_one_line(tmp_path, capsys):
    path = tmp_path / "quick.toml"
    path.write_text(QUICK)
    line = _refused(
        ["sweep", str(path), "--out", str(tmp_path / "out"), "--scheduler", "not a url", "--quiet"], capsys
    )
    assert line.startswith("vtestbed: error: --scheduler 'not a url': cannot reach the Dask scheduler")
    assert line.endswith("give an address such as tcp://127.0.0.1:8786")


def test_a_corrupt_sweep_folder_is_named(tiny_sweep, tmp_path):
    from quick_campaign import tiny

    from vtestbed.campaigns.runner import sweep
    from vtestbed.campaigns.store import SweepError, read_results

    df, ref = tiny_sweep
    out = tmp_path / "copy"
    (out / "trials").mkdir(parents=True)
    (out / "campaign.json").write_text((ref / "campaign.json").read_text())
    parts = sorted((ref / "trials").glob("part-*.parquet"))
    for p in parts:
        (out / "trials" / p.name).write_bytes(p.read_bytes())
    assert len(read_results(out)) == len(df) == 24
    victim = out / "trials" / parts[0].name
    victim.write_bytes(parts[0].read_bytes()[:100])  # truncated
    with pytest.raises(SweepError, match=rf"{victim}: not a readable Parquet part .*delete it and rerun"):
        read_results(out)
    pd.DataFrame({"x": [1]}).to_parquet(victim)
    with pytest.raises(SweepError, match=r"a Parquet part without the trial_key column"):
        read_results(out)
    (out / "campaign.json").write_text('{"fingerprint": 1')
    with pytest.raises(SweepError, match=r"campaign\.json: not valid JSON"):
        sweep(tiny(), out, progress=False)
    manifest = json.loads((ref / "campaign.json").read_text()) | {"plans": [1]}
    (out / "campaign.json").write_text(json.dumps(manifest))
    with pytest.raises(SweepError, match=r"campaign\.json: plans must be a table \(a corrupt manifest\)"):
        sweep(tiny(), out, progress=False)
    with pytest.raises(SweepError, match=r"batch_trials = -5 must be an integer >= 1"):
        sweep(tiny(), out, progress=False, batch_trials=-5)


def test_negative_lists_work_as_option_values(robot, capsys):
    assert join_negative_lists(["poses", "criterion", "--q-deg", "-10,-30,-20,40,60,45", "--seed", "-1"]) == [
        "poses", "criterion", "--q-deg=-10,-30,-20,40,60,45", "--seed", "-1"]  # fmt: skip
    assert main(["poses", "criterion", "--q-deg", "-10,-30,-20,40,60,45"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert main(["poses", "criterion", "--q-deg=-10,-30,-20,40,60,45"]) == 0
    second = json.loads(capsys.readouterr().out)
    assert first["inv_kappa"] == second["inv_kappa"] and first["q_deg"][0] == pytest.approx(-10.0, abs=1e-12)


def test_a_closed_stdout_pipe_exits_0_silently(tmp_path):
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "vtestbed", "poses", "criterion", "--q-deg", "0,-30,-20,40,60,45"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)  # fmt: skip
    proc.stdout.close()  # the reader is gone before the command prints (like `| head` after line 1)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert err == ""


def test_json_output_is_strict_nan_and_inf_are_null(tmp_path):
    data = {"k": np.array([1.5, np.nan]), "std": [float("inf"), 2], "n": np.int64(3), "ok": np.bool_(True)}
    assert dumps(data, indent=None) == '{"k": [1.5, null], "std": [null, 2], "n": 3, "ok": true}'
    write_json_atomic(tmp_path / "r.json", {"chi2": float("nan"), "x": 0.1 + 0.2})
    text = (tmp_path / "r.json").read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}")) == {
        "chi2": None, "x": 0.30000000000000004}  # fmt: skip
    assert dumps({"a": 1.0}, default=float) == '{\n "a": 1.0\n}'


def test_design_out_writes_a_scenario_simulate_accepts(tmp_path, capsys):
    from vtestbed.scenario import load_scenario

    poses = tmp_path / "poses.json"
    poses.write_text(
        json.dumps(
            {"q_deg": [[0, -60, -20, 30, 50, 45], [20, -40, -30, -40, 60, 45], [-20, -70, 0, 60, 40, 0]]}
        )
    )
    argv = ["poses", "design", "--poses", str(poses), "--tests", "3", "--stiffness-prior", "paper_table5",
            "--out", str(tmp_path / "d")]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    scenario = load_scenario(tmp_path / "d" / "design_scenario.toml")
    assert (
        scenario.name == "design_minimax_3" and scenario.n_tests == 3 and scenario.robot_name == "kuka_kr60_3"
    )


def test_ctrl_c_inside_a_lock_release_ends_as_an_interruption(tmp_path, capsys, monkeypatch):
    """CPython may turn a Ctrl-C that lands while a threading.Condition releases its lock (a sweep
    waiting on its workers) into ``RuntimeError: release unlocked lock`` raised during the
    KeyboardInterrupt's handling: exit 130 and one line, as for a plain Ctrl-C. Any other
    RuntimeError still propagates."""
    import vtestbed.cli.sweep as sweep_cli

    def interrupted_in_lock(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise RuntimeError("release unlocked lock")  # noqa: B904 (its __context__ is the interrupt)

    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "kr60_paper.toml"
    argv = ["sweep", str(scenario), "--out", str(tmp_path / "o")]
    monkeypatch.setattr(sweep_cli, "_cmd_sweep", interrupted_in_lock)
    assert main(argv) == 130
    assert capsys.readouterr().err == "vtestbed: interrupted\n"

    def plain_runtime_error(args):
        raise RuntimeError("a bug, not an interruption")

    monkeypatch.setattr(sweep_cli, "_cmd_sweep", plain_runtime_error)
    with pytest.raises(RuntimeError, match="a bug, not an interruption"):
        main(argv)
