"""The discrepancy report's figures: ``gap.png``, ``effect.png``, ``patterns.png``.

Each reads a :func:`.discrepancy.diagnose` report (its JSON form) and nothing else, so a report
written earlier draws again. Residuals are whitened by the noise floor (1 = as large as the noise).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plotting import pyplot, save_figure

__all__ = ["plot_effect", "plot_gap", "plot_patterns"]


def plot_gap(report: dict, path: Path) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.6))
    fit, val = report["identification_fit"], report["validation"]
    before, after, ids = report["detect"]["per_test"], fit["per_test_after"], list(fit["test_ids"])
    x = np.arange(len(before))
    ax.bar(x - 0.2, before, 0.4, color="#9dc3e6", label="identification, paper's model")
    ax.bar(x + 0.2, after, 0.4, color="#1f4e79", label="identification, with the named terms")
    if val["before"]:
        xv = np.arange(len(before), len(before) + len(val["before"]["per_test"]))
        ax.bar(
            xv - 0.2, val["before"]["per_test"], 0.4, color="#f4b183", label="validation (predicted), before"
        )
        ax.bar(
            xv + 0.2, val["after"]["per_test"], 0.4, color="#c00000", label="validation (predicted), after"
        )
        ids += list(val["before"]["test_ids"])
        if "expected_ratio" in val["after"]:  # what a correct model with the named terms reaches
            ax.hlines(val["after"]["expected_ratio"], xv[0] - 0.5, xv[-1] + 0.5, colors="#c00000",
                      linestyles="--", lw=0.9, label="a correct model's validation error (mean)")  # fmt: skip
    ax.axhline(1.0, color="k", lw=0.8, label="noise floor")
    ax.set_xticks(np.arange(len(ids)), ids, rotation=90, fontsize=7)
    ax.set_ylabel("RMS whitened residual / floor")
    ax.set_title("named: " + (", ".join(report["named"]) or "nothing"), fontsize=9)
    ax.legend(fontsize=7)
    return save_figure(fig, path, dpi=90)


def plot_effect(report: dict, path: Path) -> Path:
    """The named effect: each test's whitened residual under the baseline against the part the
    named terms explain. On the diagonal, the terms account for the gap; a cloud around zero of
    unit spread is the noise left."""
    plt = pyplot()
    effect = report["effect"]
    before, explained = np.asarray(effect["baseline_whitened"]), np.asarray(effect["explained_whitened"])
    fig, ax = plt.subplots(figsize=(4.8, 4.4))
    for k in range(before.shape[1]):
        ax.scatter(explained[:, k], before[:, k], s=12, label=f"whitened component {k + 1}")
    lim = max(1.0, float(np.abs(before).max()), float(np.abs(explained).max())) * 1.05
    ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.8, label="explained = residual")
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_xlabel("explained by the named terms (whitened)")
    ax.set_ylabel("baseline residual (whitened)")
    named = ", ".join(effect["terms"]) or "nothing"
    ax.set_title(
        f"named: {named}\nexplains {effect['explained_fraction']:.0%} of the baseline's chi^2", fontsize=9
    )
    ax.legend(fontsize=6)
    return save_figure(fig, path, dpi=90)


def plot_patterns(report: dict, path: Path) -> Path:
    """The per-test residual of the baseline (and with the named terms) against the pose features."""
    plt = pyplot()
    feats = report["detect"]["features"]
    names = [n for n in feats if report["detect"]["patterns"][n]["rho"] is not None]
    cols = 4
    rows = max(1, -(-len(names) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 2.4 * rows), squeeze=False)
    before, after = report["detect"]["per_test"], report["identification_fit"]["per_test_after"]
    for ax, name in zip(axes.flat, names):
        pat = report["detect"]["patterns"][name]
        ax.plot(feats[name], before, "o", ms=4, color="#9dc3e6", label="paper's model")
        ax.plot(feats[name], after, "o", ms=3, color="#1f4e79", label="with the named terms")
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_xlabel(name, fontsize=8)
        ax.set_title(f"rho = {pat['rho']:+.2f} (p = {pat['p_value']:.2g})", fontsize=8)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    axes.flat[0].set_ylabel("RMS residual / floor")
    axes.flat[0].legend(fontsize=6)
    fig.suptitle("Where the model disagrees: per-test residual against the pose and the load", fontsize=9)
    return save_figure(fig, path, dpi=80)
