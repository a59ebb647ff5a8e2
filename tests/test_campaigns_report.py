"""Campaign summaries and trend checks against trials with known error distributions, and the
report files of a real (tiny) campaign."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from quick_campaign import tiny

from vtestbed.campaigns.report import cell_summary, pose_choice, spread_check, trend_checks, write_report
from vtestbed.campaigns.runner import sweep


def test_noise_trend_and_report_files(tiny_sweep, tmp_path):
    ref, out = tiny_sweep
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
