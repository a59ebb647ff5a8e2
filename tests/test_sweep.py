"""Campaign execution: identical results on 1 / 2 processes / Dask, kill and resume, summaries."""

import copy
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vtestbed.campaigns import montecarlo
from vtestbed.campaigns.report import cell_summary, pose_choice, spread_check, trend_checks, write_report
from vtestbed.campaigns.runner import SweepStats, sweep
from vtestbed.campaigns.spec import parse_campaign, scaled_noise
from vtestbed.campaigns.store import TRIALS_DIR, SweepError, read_results
from vtestbed.cli.main import main
from vtestbed.lab import LabSetup
from vtestbed.world.scan_noise import ScanNoise
from vtestbed.world.sensors import ForceTorqueSensor

ROOT = Path(__file__).resolve().parents[1]
QUICK = (ROOT / "scenarios" / "kr60_sweep_quick.toml").read_text()
BASE_TEXT = QUICK[: QUICK.index("\n[campaign]\n")]  # the quick campaign's base scenario, 20 tests
BASE = tomllib.loads(BASE_TEXT)
TINY = {"trials": 6, "seed": 9, "axes": {"n_tests": [3, 4], "scanner_noise_scale": [0.5, 1.0]}}
TINY_TOML = """
[campaign]
trials = 6
seed = 9
[campaign.axes]
n_tests = [3, 4]
scanner_noise_scale = [0.5, 1.0]
"""


def tiny(**changes):
    data = copy.deepcopy(BASE)
    data["campaign"] = copy.deepcopy(TINY) | changes
    return parse_campaign(data, "tiny")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "ref"
    return sweep(tiny(), out, workers=1, progress=False), out


def test_same_parquet_results_on_one_and_two_processes_and_dask(reference, tmp_path):
    ref, _ = reference
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


def test_a_row_is_the_monte_carlo_trial_with_the_derived_seed(reference):
    ref, _ = reference
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
def test_interrupted_campaign_resumes_without_loss_or_duplicates(reference, tmp_path, sig, workers):
    ref, _ = reference
    path = tmp_path / "tiny.toml"
    path.write_text(BASE_TEXT + TINY_TOML)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "vtestbed", "sweep", str(path), "--out", str(out), "--workers", str(workers),
           "--batch-trials", "1", "--no-report", "--quiet"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and _count_rows(out)[0] < 4:
        time.sleep(0.05)
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


def test_rerun_does_nothing_and_more_trials_add_only_the_new_ones(reference, tmp_path):
    ref, ref_out = reference
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


def test_noise_trend_and_report_files(reference, tmp_path):
    ref, out = reference
    summary = cell_summary(ref)
    trends = trend_checks(summary)
    # common random numbers: doubling the scanner noise raises every joint's RMS error
    assert trends["scanner_noise_scale"]["slices"] == 12 and trends["scanner_noise_scale"]["broken"] == []
    s = summary[(summary["n_tests"] == 4) & (summary["joint"] == "joint2")]
    ratio = s["rms_pct"].iloc[1] / s["rms_pct"].iloc[0]
    assert 1.5 < ratio < 2.5  # about 2 (the errors are nearly linear in the noise)
    report = write_report(ref, tmp_path / "report", json.loads((out / "campaign.json").read_text()))
    for key in ("error_vs_noise", "error_vs_tests", "spread_vs_predicted"):
        assert Path(report["files"][key]).stat().st_size < 300_000


def synthetic(seed=0, trials=400, broken=False):
    """Trials with known errors: e ~ N(0, s) with s = 1e-3 * noise / sqrt(n), predicted std = s."""
    rng = np.random.default_rng(seed)
    rows = []
    for pose_set, factor in (("kappa_regions", 1.0), ("random", 2.0)):
        for n in (5, 20):
            for noise in (0.5, 1.0, 2.0):
                s = 1e-3 * noise / np.sqrt(n) * (3.0 if broken and n == 20 else 1.0)
                z = np.random.default_rng(seed + 7).standard_normal((trials, 2))  # common draws (paired)
                for t in range(trials):
                    row = {"pose_set": pose_set, "n_tests": n, "scanner_noise_scale": noise, "ft_noise_scale": 1.0,
                           "method": "fgls", "trial": t, "status": "ok"}  # fmt: skip
                    for j, name in enumerate(("joint1", "joint2")):
                        row[f"k_true_{name}"] = 1e5
                        row[f"err_{name}"] = factor * s * z[t, j]
                        row[f"k_{name}"] = 1e5 * (1 + row[f"err_{name}"])
                        row[f"k_std_{name}"] = 1e5 * factor * s * rng.uniform(0.999, 1.001)
                    rows.append(row)
    return pd.DataFrame(rows)


def test_summary_statistics_against_known_distributions():
    df = synthetic()
    summary = cell_summary(df)
    check = spread_check(summary)
    assert check["inside"] == check["cells"] == 24 and abs(check["ratio_median"] - 1) < 0.1
    row = summary[(summary["pose_set"] == "kappa_regions") & (summary["n_tests"] == 20)
                  & (summary["scanner_noise_scale"] == 2.0) & (summary["joint"] == "joint1")].iloc[0]  # fmt: skip
    s = 100 * 2e-3 / np.sqrt(20)
    assert row["median_abs_pct"] == pytest.approx(0.6745 * s, rel=0.1)  # median |N(0, s)|
    assert row["spread_pct"] == pytest.approx(s, rel=0.1)
    trends = trend_checks(summary)
    assert trends["scanner_noise_scale"]["broken"] == [] and trends["n_tests"]["broken"] == []
    assert len(trend_checks(cell_summary(synthetic(broken=True)))["n_tests"]["broken"]) == 12
    choice = pose_choice(df, paired=True)
    rnd = choice[choice["pose_set"] == "random"]
    assert np.allclose(rnd["ratio_to_kappa"], 2.0) and np.allclose(rnd[["ratio_lo95", "ratio_hi95"]], 2.0)
    assert set(rnd["verdict"]) == {"kappa better"}


@pytest.mark.slow
def test_error_trends_and_honest_spread_on_a_real_campaign(tmp_path):
    """30 trials per cell, 4 cells: error grows with noise, shrinks with tests, spread = predicted."""
    c = tiny(trials=30, axes={"n_tests": [5, 20], "scanner_noise_scale": [0.5, 2.0]})
    df = sweep(c, tmp_path / "real", workers=2, progress=False)
    summary = cell_summary(df)
    trends = trend_checks(summary)
    print(
        summary[
            ["n_tests", "scanner_noise_scale", "joint", "rms_pct", "spread_pct", "predicted_pct", "ratio"]
        ]
    )
    assert trends["scanner_noise_scale"]["broken"] == [] and trends["n_tests"]["broken"] == []
    at20 = summary[summary["n_tests"] == 20]["ratio"]
    assert np.all((at20 > 1 / 1.5) & (at20 < 1.5))
