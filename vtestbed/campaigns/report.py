"""Summaries of a campaign's trials: table per cell and joint, trend checks, pose-choice comparison, PNGs.

Per cell and joint (relative errors ``e = k/k_true - 1`` of the trials that succeeded):

* ``median_abs_pct``: median |e| [%] (the typical error), ``rms_pct``: sqrt(mean e^2) [%],
* ``bias_pct``: median e [%], ``spread_pct``: std of e (ddof 1) [%], ``p16_pct``/``p84_pct``,
* ``predicted_pct``: the identification's own std(k)/k_true, RMS over the trials [%],
* ``ratio``: spread / predicted (1 when the reported uncertainty is honest).

The pose-choice comparison scores a pose set by the geometric mean over joints of the RMS
relative error at equal test counts and noise, and gives the ratio to ``kappa_regions`` with a
bootstrap 95 % interval (trials resampled, the same indices for both sets when the campaign
is paired): a ratio above 1 with its interval above 1 means the kappa-based choice is better.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..files import dumps
from ..plotting import pyplot, save_figure
from .spec import AXES

BOOTSTRAP = 2000
PARAMS = list(AXES)


def joint_names(df: pd.DataFrame) -> list[str]:
    return [c[4:] for c in df.columns if c.startswith("err_")]


def cell_summary(df: pd.DataFrame) -> pd.DataFrame:
    """One row per (cell, joint) with the statistics listed in the module docstring."""
    rows = []
    for params, g in df.groupby(PARAMS, sort=True):
        ok = g[g["status"] == "ok"]
        for j in joint_names(df):
            e = ok[f"err_{j}"].to_numpy()
            pred = (ok[f"k_std_{j}"] / ok[f"k_true_{j}"]).to_numpy()
            spread = float(np.std(e, ddof=1)) if len(e) > 1 else np.nan
            predicted = float(np.sqrt(np.mean(pred**2))) if len(pred) else np.nan
            rows.append({**dict(zip(PARAMS, params)), "joint": j, "trials": len(g), "failed": len(g) - len(ok),
                         "median_abs_pct": 100 * float(np.median(np.abs(e))) if len(e) else np.nan,
                         "rms_pct": 100 * float(np.sqrt(np.mean(e**2))) if len(e) else np.nan,
                         "bias_pct": 100 * float(np.median(e)) if len(e) else np.nan,
                         "spread_pct": 100 * spread,
                         "p16_pct": 100 * float(np.percentile(e, 16)) if len(e) else np.nan,
                         "p84_pct": 100 * float(np.percentile(e, 84)) if len(e) else np.nan,
                         "predicted_pct": 100 * predicted, "ratio": spread / predicted})  # fmt: skip
    return pd.DataFrame(rows)


def _slices(summary: pd.DataFrame, axis: str):
    """Groups of the summary that differ only in ``axis`` (and the joint), sorted along it."""
    others = [p for p in PARAMS if p != axis]
    for key, g in summary.groupby([*others, "joint"], sort=True):
        if g[axis].nunique() > 1:
            yield dict(zip([*others, "joint"], key)), g.sort_values(axis)


def trend_checks(summary: pd.DataFrame, metric: str = "rms_pct") -> dict:
    """Is ``metric`` increasing along the noise axis and decreasing along n_tests in every slice?

    Returns per axis the number of slices, the slices that break the trend and the worst step.
    """
    out = {}
    for axis, sign in (("scanner_noise_scale", 1), ("ft_noise_scale", 1), ("n_tests", -1)):
        slices = list(_slices(summary, axis))
        if not slices:
            continue
        broken = []
        for key, g in slices:
            steps = sign * np.diff(g[metric].to_numpy())
            if np.any(steps <= 0):
                broken.append({**key, "values": g[metric].round(4).tolist()})
        out[axis] = {"slices": len(slices), "monotonic": len(slices) - len(broken), "broken": broken}
    return out


def spread_check(summary: pd.DataFrame, factor: float = 1.5) -> dict:
    """How many (cell, joint) spreads agree with the predicted std within ``factor``."""
    r = summary["ratio"].dropna()
    inside = (r >= 1 / factor) & (r <= factor)
    by_n = {
        int(n): {
            "cells": int(len(g)),
            "inside": int(inside[g.index].sum()),
            "ratio_median": float(g.median()),
        }
        for n, g in r.groupby(summary.loc[r.index, "n_tests"])
    }
    outside = summary.loc[r.index[~inside], [*PARAMS, "joint", "ratio"]].to_dict("records")
    return {"factor": factor, "cells": int(len(r)), "inside": int(inside.sum()), "ratio_median": float(r.median()),
            "ratio_min": float(r.min()), "ratio_max": float(r.max()), "by_n_tests": by_n, "outside": outside}  # fmt: skip


def _score(errors: np.ndarray) -> float:
    """Geometric mean over joints of the RMS relative error; errors (trials, joints)."""
    return float(np.exp(np.mean(np.log(np.sqrt(np.mean(errors**2, axis=0))))))


def reference_value(values, target=1.0):
    values = sorted(values)
    return min(values, key=lambda v: (abs(np.log(v / target)) if v > 0 else np.inf, v))


def pose_choice(
    df: pd.DataFrame, paired: bool = True, seed: int = 0, quality: dict | None = None
) -> pd.DataFrame:
    """Each pose set against ``kappa_regions`` at every test count (reference noise, first method)."""
    if "kappa_regions" not in set(df["pose_set"]):
        return pd.DataFrame()
    joints = joint_names(df)
    ref = df[(df["scanner_noise_scale"] == reference_value(df["scanner_noise_scale"].unique()))
             & (df["ft_noise_scale"] == reference_value(df["ft_noise_scale"].unique()))
             & (df["method"] == sorted(df["method"].unique())[0])]  # fmt: skip
    rng = np.random.default_rng(seed)
    rows = []
    for n, g in ref.groupby("n_tests", sort=True):
        err = {}
        for p, h in g.groupby("pose_set"):
            h = h[h["status"] == "ok"].set_index("trial").sort_index()
            err[p] = h[[f"err_{j}" for j in joints]]
        if "kappa_regions" not in err:
            continue
        base = err["kappa_regions"]
        for p, e in sorted(err.items()):
            common = base.index.intersection(e.index) if paired else None
            a, b = (base.loc[common], e.loc[common]) if paired else (base, e)
            ratio = _score(b.to_numpy()) / _score(a.to_numpy())
            boot = []
            for _ in range(BOOTSTRAP):
                ia = rng.integers(len(a), size=len(a))
                ib = ia if paired else rng.integers(len(b), size=len(b))
                boot.append(_score(b.to_numpy()[ib]) / _score(a.to_numpy()[ia]))
            lo, hi = np.percentile(boot, [2.5, 97.5])
            row = {"n_tests": n, "pose_set": p, "trials": len(e), "score_pct": 100 * _score(e.to_numpy()),
                   "ratio_to_kappa": ratio, "ratio_lo95": lo, "ratio_hi95": hi,
                   "verdict": "same" if p == "kappa_regions" else
                   ("kappa better" if lo > 1 else "kappa worse" if hi < 1 else "no clear difference")}  # fmt: skip
            row.update({f"rms_{j}_pct": 100 * float(np.sqrt(np.mean(e[f"err_{j}"] ** 2))) for j in joints})
            if quality and f"{p}:{n}" in quality:
                row.update(quality[f"{p}:{n}"])
            rows.append(row)
    return pd.DataFrame(rows)


def markdown_table(summary: pd.DataFrame) -> str:
    """Cells as rows, joints as columns: ``median |e| % (spread % / predicted %)``."""
    swept = [p for p in PARAMS if summary[p].nunique() > 1] or PARAMS[:1]
    joints = list(dict.fromkeys(summary["joint"]))
    lines = ["| " + " | ".join(swept + joints) + " |", "|" + " --- |" * (len(swept) + len(joints))]
    for key, g in summary.groupby(swept, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        g = g.set_index("joint")
        cells = [f"{g.loc[j, 'median_abs_pct']:.3g} ({g.loc[j, 'spread_pct']:.3g} / {g.loc[j, 'predicted_pct']:.3g})"
                 for j in joints]  # fmt: skip
        lines.append("| " + " | ".join([str(k) for k in key] + cells) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- figures

COLORS = {"kappa_regions": "C0", "random": "C1", "design_optimal": "C2", "scenario": "C3"}


def _panels(summary: pd.DataFrame, axis: str, fixed: dict, path: Path, xlabel: str, title: str):
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    plt = pyplot()
    joints = list(dict.fromkeys(summary["joint"]))
    fig, axes = plt.subplots(2, 3, figsize=(10, 5.6), sharex=True)
    sel = summary
    for k, v in fixed.items():
        sel = sel[sel[k] == v]
    for ax, j in zip(axes.ravel(), joints):
        for p, g in sel[sel["joint"] == j].groupby("pose_set"):
            g = g.sort_values(axis)
            c = COLORS.get(p, None)
            ax.plot(g[axis], g["median_abs_pct"], "o-", color=c, label=f"{p}", ms=4)
            ax.plot(g[axis], g["spread_pct"], "--", color=c, alpha=0.6, lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(sorted(sel[axis].unique()))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(j, fontsize=9)
        ax.grid(alpha=0.3, which="both")
    for ax in axes[1]:
        ax.set_xlabel(xlabel)
    for ax in axes[:, 0]:
        ax.set_ylabel("relative error [%]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle(
        f"{title}\nsolid: median |k/k_true - 1| over the trials,  dashed: spread (std of k/k_true)",
        fontsize=9,
    )
    return save_figure(fig, path, dpi=80, rect=(0, 0.06, 1, 1))


def plot_spread(summary: pd.DataFrame, path: Path, factor: float = 1.5) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 4.6))
    ns = sorted(summary["n_tests"].unique())
    cmap = plt.get_cmap("viridis")
    for i, (n, g) in enumerate(summary.groupby("n_tests")):
        color = cmap(i / max(len(ns) - 1, 1))
        ax.loglog(g["predicted_pct"], g["spread_pct"], "o", ms=3, color=color, label=f"{n} tests", alpha=0.75)
    lim = np.array([summary["predicted_pct"].min() / 2, summary["predicted_pct"].max() * 2])
    ax.plot(lim, lim, "k-", lw=0.8)
    ax.fill_between(lim, lim / factor, lim * factor, color="k", alpha=0.08, label=f"within x{factor:g}")
    ax.set_xlabel("predicted std(k)/k [%] (RMS over the trials)")
    ax.set_ylabel("spread of k/k_true over the trials [%]")
    ax.set_title("one point per (cell, joint)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path, dpi=80)


def plot_pose_choice(choice: pd.DataFrame, path: Path) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for p, g in choice.groupby("pose_set"):
        g = g.sort_values("n_tests")
        ax.errorbar(g["n_tests"], g["ratio_to_kappa"], yerr=[g["ratio_to_kappa"] - g["ratio_lo95"],
                    g["ratio_hi95"] - g["ratio_to_kappa"]], fmt="o-", capsize=3, color=COLORS.get(p), label=p)  # fmt: skip
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("tests per identification")
    ax.set_ylabel("error score / kappa_regions' (95% bootstrap)")
    ax.set_title("pose choice: > 1 means the kappa-based choice is better", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path, dpi=80)


def write_report(df: pd.DataFrame, out: str | Path, manifest: dict | None = None) -> dict:
    """Write summary.csv, pose_choice.csv, report.json and the PNG figures into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = cell_summary(df)
    summary.to_csv(out / "summary.csv", index=False, float_format="%.6g")
    head = "Per cell and joint: median |k/k_true - 1| % (spread % / predicted std %)\n\n"
    (out / "summary.md").write_text(head + markdown_table(summary))
    paired = bool((manifest or {}).get("campaign", {}).get("paired", True))
    choice = pose_choice(df, paired=paired, quality=(manifest or {}).get("plan_quality"))
    files = {"summary": str(out / "summary.csv"), "summary_md": str(out / "summary.md")}
    if not choice.empty:
        choice.to_csv(out / "pose_choice.csv", index=False, float_format="%.6g")
        files["pose_choice"] = str(out / "pose_choice.csv")
        files["pose_choice_png"] = str(plot_pose_choice(choice, out / "pose_choice.png"))
    noise_ref = reference_value(df["scanner_noise_scale"].unique())
    ft_ref = reference_value(df["ft_noise_scale"].unique())
    method = sorted(df["method"].unique())[0]
    n_max = int(df["n_tests"].max())
    if df["scanner_noise_scale"].nunique() > 1:
        files["error_vs_noise"] = str(_panels(summary, "scanner_noise_scale", {"n_tests": n_max, "ft_noise_scale": ft_ref, "method": method},
                                              out / "error_vs_noise.png", "scanner noise scale",
                                              f"error against scanner noise, {n_max} tests"))  # fmt: skip
    if df["n_tests"].nunique() > 1:
        files["error_vs_tests"] = str(_panels(summary, "n_tests", {"scanner_noise_scale": noise_ref, "ft_noise_scale": ft_ref, "method": method},
                                              out / "error_vs_tests.png", "tests per identification",
                                              f"error against the number of tests, noise scale {noise_ref:g}"))  # fmt: skip
    files["spread_vs_predicted"] = str(plot_spread(summary, out / "spread_vs_predicted.png"))
    report = {"trials": len(df), "failed": int((df["status"] != "ok").sum()), "trends": trend_checks(summary),
              "spread_check": spread_check(summary), "pose_choice": choice.to_dict("records"), "files": files}  # fmt: skip
    (out / "report.json").write_text(dumps(report, indent=1, default=float))
    return report
