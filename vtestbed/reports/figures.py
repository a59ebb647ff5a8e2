"""The report's static figures, drawn by the project's own plotting code and embedded as PNG data.

Each figure is drawn from the result files again (not copied from the PNGs beside them), so a
report is complete even for a run written with ``--no-figures`` and never shows a stale picture.
The figures are embedded as ``data:image/png;base64`` URIs: the page needs no other file.
"""

from __future__ import annotations

import base64
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..plotting import pyplot, save_figure
from ..researcher.discrepancy import COMPONENTS


def data_uri(png: bytes) -> str:
    """``data:image/png;base64,...`` of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def drawn(draw: Callable[[Path], Path]) -> str:
    """The data URI of the PNG that ``draw(path)`` writes (into a temporary folder)."""
    with tempfile.TemporaryDirectory(prefix="vtestbed-report-") as tmp:
        return data_uri(Path(draw(Path(tmp) / "figure.png")).read_bytes())


# ---------------------------------------------------------------------- run


def recorded(result: dict, root: Path | None, name: str) -> str | None:
    """The PNG the run itself wrote for this result (``result.json: figures[name]``), embedded as
    it is: no second drawing. None when the result records none (``--no-figures``) or it is gone."""
    path = result.get("figures", {}).get(name) if root is not None else None
    if not path:
        return None
    path = root / Path(path).name  # written beside result.json (the folder may have moved since)
    return data_uri(path.read_bytes()) if path.is_file() else None


def convergence(result: dict, root: Path | None = None) -> str:
    """Paper Fig. 10 from ``result.json``: estimates against the number of tests, relative to the truth."""
    from ..researcher.report import plot_convergence

    if (png := recorded(result, root, "convergence")) is not None:
        return png
    k_true = np.array([j["k_true"] for j in result["joints"]])
    conv = result["convergence"]
    conv = {  # strict JSON writes NaN as null
        **conv,
        **{
            k: [[np.nan if v is None else v for v in row] for row in conv[k]]
            for k in ("stiffness", "stiffness_std")
        },
    }
    names = [j["name"] for j in result["joints"]]
    return drawn(lambda p: plot_convergence(conv, names, p, reference=k_true))


def validation(result: dict, root: Path | None = None) -> str | None:
    """Paper Fig. 11 from ``result.json`` (None without validation tests)."""
    from ..researcher.report import plot_validation

    if result["validation"] and (png := recorded(result, root, "validation")) is not None:
        return png
    rows = result["validation"]
    return drawn(lambda p: plot_validation(rows, p)) if rows else None


def residuals(result: dict) -> str:
    """Per component: the identification's residual std, and each validation test's measured minus
    predicted displacement (um, urad)."""
    plt = pyplot()
    std = np.array(result["identification"]["component_std"], dtype=float) * 1e6
    rows = result["validation"]
    fig, axes = plt.subplots(1, 2 if rows else 1, figsize=(11 if rows else 5.5, 3.6), squeeze=False)
    ax = axes[0, 0]
    ax.bar(COMPONENTS, std, color="#1f4e79")
    ax.set_ylabel("residual std [um | urad]")
    ax.set_title("identification: residual std per component", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    if rows:
        ax = axes[0, 1]
        x = np.arange(6)
        width = 0.8 / len(rows)
        for i, r in enumerate(rows):
            diff = (np.array(r["measured"]) - np.array(r["predicted"])) * 1e6
            ax.bar(x - 0.4 + (i + 0.5) * width, diff, width, label=r["test_id"])
        ax.set_xticks(x, COMPONENTS)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_ylabel("measured - predicted [um | urad]")
        ax.set_title("validation tests: prediction residual per component", fontsize=9)
        ax.legend(fontsize=7, ncol=min(len(rows), 5))
        ax.grid(alpha=0.3, axis="y")
    return drawn(lambda p: save_figure(fig, p, dpi=90))


# ---------------------------------------------------------------------- campaign


def campaign(trials, manifest: dict) -> tuple[dict, object, dict]:
    """The campaign's summary, computed and drawn by :mod:`vtestbed.campaigns.report`.

    Returns ``(report, summary, figures)``: the report dict (trends, spread check, pose choice),
    the per (cell, joint) summary DataFrame and ``{name: data URI}`` of the figures it drew.
    """
    from ..campaigns.report import cell_summary, write_report

    with tempfile.TemporaryDirectory(prefix="vtestbed-report-") as tmp:
        report = write_report(trials, Path(tmp), manifest)
        figures = {
            name: data_uri(Path(path).read_bytes())
            for name, path in report["files"].items()
            if str(path).endswith(".png")
        }
    return report, cell_summary(trials), figures


# ---------------------------------------------------------------------- diagnosis


def gap(report: dict) -> str:
    """Per-test residual before and after the named terms (``vtestbed diagnose``'s gap.png)."""
    from ..researcher.discrepancy_plots import plot_gap

    return drawn(lambda p: plot_gap(report, p))


def patterns(report: dict) -> str | None:
    """The per-test residual against the pose features (None if no feature varies)."""
    from ..researcher.discrepancy_plots import plot_patterns

    if not any(v["rho"] is not None for v in report["detect"]["patterns"].values()):
        return None
    return drawn(lambda p: plot_patterns(report, p))


def effect(report: dict) -> str | None:
    """The baseline's residual against what the named terms explain (``effect.png``); None for a
    report written before it existed or when nothing was named."""
    from ..researcher.discrepancy_plots import plot_effect

    if not report.get("effect", {}).get("terms"):
        return None
    return drawn(lambda p: plot_effect(report, p))


# ---------------------------------------------------------------------- discovery


def discovery_gap(stages: list[tuple[str, float, float]]) -> str:
    """Bars of the validation error over the noise floor at each stage of ``vtestbed discover``:
    the paper's model beside the named terms (``sections_discovery.gap_stages``), a line at 1."""
    plt = pyplot()
    x = np.arange(len(stages))
    fig, ax = plt.subplots(figsize=(1.8 + 1.6 * len(stages), 3.2))
    ax.bar(x - 0.2, [s[1] for s in stages], 0.4, label="paper's model", color="0.65")
    ax.bar(x + 0.2, [s[2] for s in stages], 0.4, label="named terms", color="tab:blue")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise floor")
    ax.set_xticks(x, [s[0] for s in stages], fontsize=8)
    ax.set_ylabel("validation error / noise floor")
    ax.set_ylim(0.0, max(1.1, *(max(s[1], s[2]) for s in stages)) * 1.1)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3)
    ax.grid(alpha=0.3, axis="y")
    return drawn(lambda p: save_figure(fig, p, dpi=90))
