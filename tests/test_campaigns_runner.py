"""Campaign execution: identical results on 1 / 2 processes / Dask, the rows against the
Monte Carlo trial they stand for, kill and resume, reruns."""

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from quick_campaign import BASE_TEXT, TINY_TOML, tiny

from vtestbed.campaigns import montecarlo
from vtestbed.campaigns.runner import SweepStats, sweep
from vtestbed.campaigns.spec import scaled_noise
from vtestbed.campaigns.store import TRIALS_DIR, SweepError, read_results
from vtestbed.lab import LabSetup
from vtestbed.world.scan_noise import ScanNoise
from vtestbed.world.sensors import ForceTorqueSensor


def test_same_parquet_results_on_one_and_two_processes_and_dask(tiny_sweep, tmp_path):
    ref, _ = tiny_sweep
    assert len(ref) == 24 and ref["trial_key"].is_unique and (ref["status"] == "ok").all()
    two = sweep(tiny(), tmp_path / "two", workers=2, progress=False, batch_trials=2)
    pd.testing.assert_frame_equal(ref, two, check_exact=True)
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster:  # fmt: skip
        stats = SweepStats()
        dask = sweep(
            tiny(), tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False, stats=stats
        )
    pd.testing.assert_frame_equal(ref, dask, check_exact=True)
    assert len(stats.pids) == 2 and os.getpid() not in stats.pids  # ran on the cluster's two workers
    files = read_results(tmp_path / "dask")
    assert len(files) == 24


def test_a_row_is_the_monte_carlo_trial_with_the_derived_seed(tiny_sweep):
    ref, _ = tiny_sweep
    c = tiny()
    row = ref[(ref["n_tests"] == 3) & (ref["scanner_noise_scale"] == 0.5) & (ref["trial"] == 4)].iloc[0]
    seed = int(np.random.SeedSequence(9, spawn_key=(0, 4)).generate_state(1, np.uint64)[0]) >> 1
    assert row["seed"] == seed
    prepared = montecarlo.prepare(c.scenario)  # all 20 tests: the first 3 are the same physics
    sensor = ForceTorqueSensor(
        LabSetup().sensor, c.scenario.force_sensor.noise_std, c.scenario.force_sensor.bias
    )
    result = montecarlo.trial(prepared, seed, 3, "fgls", scaled_noise(ScanNoise(), 0.5), sensor)
    for j, name in enumerate(result.joint_names):
        assert row[f"k_{name}"] == result.stiffness[j]
        assert row[f"k_std_{name}"] == result.stiffness_std[j]
        assert row[f"err_{name}"] == pytest.approx(
            result.stiffness[j] / prepared.stiffness_true[j] - 1, abs=1e-15
        )


def _count_rows(out: Path) -> tuple[int, int]:
    parts = list((out / TRIALS_DIR).glob("part-*.parquet"))
    keys = pd.concat([pd.read_parquet(p, columns=["trial_key"]) for p in parts])["trial_key"] if parts else []
    return len(keys), len(set(keys))


@pytest.mark.parametrize("sig, workers", [(signal.SIGKILL, 1), (signal.SIGINT, 2)])
def test_interrupted_campaign_resumes_without_loss_or_duplicates(tiny_sweep, tmp_path, sig, workers):
    ref, _ = tiny_sweep
    path = tmp_path / "tiny.toml"
    path.write_text(BASE_TEXT + TINY_TOML)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "vtestbed", "sweep", str(path), "--out", str(out), "--workers", str(workers),
           "--batch-trials", "1", "--no-report", "--quiet"]  # fmt: skip
    # A shell without job control starts background commands with SIGINT ignored, and an ignored
    # signal stays ignored across exec: a test run launched that way (`... &` in a script) would
    # start a sweep that cannot be interrupted. A handled signal is reset to the default by exec,
    # so the sweep gets Ctrl-C as from a terminal whatever this process inherited.
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    finally:
        signal.signal(
            signal.SIGINT, signal.SIG_DFL if inherited is None else inherited
        )  # None: set outside Python
    deadline = time.monotonic() + 120
    # count the finished batch files, not their rows: reading parquet between polls is slow enough
    # on a loaded machine for the sweep to finish before the signal
    while (
        time.monotonic() < deadline
        and proc.poll() is None
        and len(list((out / TRIALS_DIR).glob("part-*.parquet"))) < 4
    ):
        time.sleep(0.01)
    proc.send_signal(sig)
    code = proc.wait(timeout=60)
    assert code == (-signal.SIGKILL if sig == signal.SIGKILL else 130), proc.stderr.read().decode()[-2000:]
    rows, unique = _count_rows(out)
    assert 4 <= rows < 24 and rows == unique  # finished trials kept, the run really was cut short
    stats = SweepStats()
    resumed = sweep(path, out, workers=1, progress=False, stats=stats)
    assert stats.trials_run == 24 - rows  # only what was missing
    assert _count_rows(out) == (24, 24)  # nothing lost, nothing duplicated on disk
    pd.testing.assert_frame_equal(ref, resumed, check_exact=True)


def test_rerun_does_nothing_and_more_trials_add_only_the_new_ones(tiny_sweep, tmp_path):
    ref, ref_out = tiny_sweep
    out = tmp_path / "copy"
    shutil.copytree(ref_out, out)
    stats = SweepStats()
    again = sweep(tiny(), out, progress=False, stats=stats)
    assert stats.trials_run == 0 and stats.generate_s < 1.0
    pd.testing.assert_frame_equal(ref, again, check_exact=True)
    stats = SweepStats()
    more = sweep(tiny(trials=7), out, progress=False, stats=stats)
    assert stats.trials_run == 4 and len(more) == 28
    pd.testing.assert_frame_equal(ref, more[more["trial"] < 6].reset_index(drop=True), check_exact=True)
    with pytest.raises(SweepError, match="another campaign"):
        sweep(tiny(seed=10), out, progress=False)
    manifest = json.loads((out / "campaign.json").read_text())
    (out / "campaign.json").write_text(json.dumps(manifest | {"code_fingerprint": "0" * 16}))
    with pytest.raises(SweepError, match="other vtestbed code"):
        sweep(tiny(), out, progress=False)
    assert len(sweep(tiny(), out, progress=False, allow_code_change=True)) == 24


def test_code_fingerprint_covers_the_campaigns_robot_only(tmp_path, monkeypatch):
    from vtestbed import robots
    from vtestbed.campaigns.store import code_fingerprint

    models = tmp_path / "models"
    shutil.copytree(robots.MODELS_DIR, models)
    monkeypatch.setattr(robots, "MODELS_DIR", models)
    kr60, ur10 = code_fingerprint("kuka_kr60_3"), code_fingerprint("ur10")
    assert kr60 != ur10
    # another robot imported (or edited): the KR60-3's sweeps still resume
    shutil.copytree(models / "ur10", models / "imported_arm")
    (models / "ur10" / "truth.toml").write_text((models / "ur10" / "truth.toml").read_text() + "\n# edited\n")
    assert code_fingerprint("kuka_kr60_3") == kr60 and code_fingerprint("ur10") != ur10
    # the campaign's own robot edited: its folder holds results of other code
    (models / "kuka_kr60_3" / "truth.toml").write_text(
        (models / "kuka_kr60_3" / "truth.toml").read_text() + "\n"
    )
    assert code_fingerprint("kuka_kr60_3") != kr60


def test_a_sweeps_overloaded_test_is_named_as_simulate_names_it(tmp_path):
    """A campaign's physics (``montecarlo.prepare``) refuses an overloaded test in the scenario
    file's terms, word for word as ``vtestbed simulate`` does: the file, ``load.tension_N[1]``,
    the test's id and the largest tension the truth world's sensor measures there (the reference:
    ``run_test_physics``' own ``max_tension``, floored to 0.1 N)."""
    import math

    from conftest import paper_scenario_data

    from vtestbed.campaigns.montecarlo import prepare
    from vtestbed.errors import SensorOverloadError
    from vtestbed.scenario import parse_scenario
    from vtestbed.world.physics import run_test_physics
    from vtestbed.world.rig import Rig
    from vtestbed.world.truth import load_truth

    data = paper_scenario_data(2, 1, "overload", 1)
    data["load"]["tension_N"] = [200.0, 500.0]
    scenario = parse_scenario(data, tmp_path / "sweep.toml")
    with pytest.raises(SensorOverloadError) as swept:
        prepare(scenario)
    rig = Rig(scenario.robot, scenario.lab, truth=load_truth(scenario.robot_name))
    with pytest.raises(SensorOverloadError) as direct:
        load = scenario.load
        run_test_physics(
            rig, scenario.poses[1], load.hooks[1], load.anchors[1], 500.0, scenario.scanner.distance
        )
    top = math.floor(direct.value.max_tension * 10) / 10
    message = str(swept.value)
    assert message.startswith(f"{tmp_path / 'sweep.toml'}: load.tension_N[1] (test T002): sensor wrench")
    assert message.endswith(f"valid for this test: [1, {top:g}] N (the largest tension whose wrench the "
                            "sensor measures at this pose, hook and anchor)")  # fmt: skip
