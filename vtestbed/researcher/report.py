"""Compare estimates with the truth, print the paper's Table 5, draw Figures 10 and 11.

Only this module (and the experiment runner) reads the truth, and only after identification.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .identify import IdentificationResult
from .measure import TestMeasurement, identify_measurements, predict_displacement

PAPER_FIRST_N = 6  # the paper's Table 5 uses the estimates from 6 to 20 tests


def compare(result: IdentificationResult, truth: dict) -> list[dict]:
    """Per joint: name, k_true, k_est, k_std [N*m/rad] and rel_err = k_est/k_true - 1."""
    k_true = np.asarray(truth["stiffness_true_Nm_per_rad"])
    return [
        {
            "name": name,
            "k_true": float(kt),
            "k_est": float(ke),
            "k_std": float(ks),
            "rel_err": float(ke / kt - 1.0),
        }
        for name, kt, ke, ks in zip(result.joint_names, k_true, result.stiffness, result.stiffness_std)
    ]


def convergence(measurements: list[TestMeasurement], method: str, joint_names) -> dict:
    """Estimates using the first n identification tests, n = 1..N (paper Figure 10)."""
    tests = [m for m in measurements if m.group == "identification"]
    rows = {"n": [], "stiffness": [], "stiffness_std": []}
    for n in range(1, len(tests) + 1):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify_measurements(tests[:n], method=method, joint_names=joint_names)
        rows["n"].append(n)
        rows["stiffness"].append(res.stiffness.tolist())
        rows["stiffness_std"].append(res.stiffness_std.tolist())
    return rows


def error_ranges(conv: dict, k_true: np.ndarray, first_n: int = PAPER_FIRST_N) -> dict:
    """Paper Table 5 columns: relative error range and mean over the estimates with n >= first_n."""
    n = np.asarray(conv["n"])
    est = np.asarray(conv["stiffness"])[n >= first_n]
    if len(est) == 0:
        est = np.asarray(conv["stiffness"])[-1:]
    rel = est / k_true - 1.0
    return {
        "min": rel.min(axis=0).tolist(),
        "max": rel.max(axis=0).tolist(),
        "mean": rel.mean(axis=0).tolist(),
    }


def validation(measurements: list[TestMeasurement], stiffness: np.ndarray) -> list[dict]:
    """Predicted (identified model) against measured displacement on validation tests (Figure 11)."""
    out = []
    for m in measurements:
        if m.group != "validation":
            continue
        pred = predict_displacement(m, stiffness)
        out.append(
            {
                "test_id": m.test_id,
                "measured": m.displacement.tolist(),
                "predicted": pred.tolist(),
                "rel_err_translation": float(
                    np.linalg.norm(pred[:3] - m.displacement[:3]) / np.linalg.norm(m.displacement[:3])
                ),
                "rel_err_rotation": float(
                    np.linalg.norm(pred[3:] - m.displacement[3:]) / np.linalg.norm(m.displacement[3:])
                ),
            }
        )
    return out


def table5(joints: list[dict], ranges: dict, first_n: int = PAPER_FIRST_N, n_tests: int | None = None) -> str:
    """The paper's Table 5 layout, stiffness in N*mm/rad, errors in %."""
    span = f"n={first_n}..{n_tests}" if n_tests else f"n>={first_n}"
    lines = [
        f"{'joint':8}{'k_true [N*mm/rad]':>19}{'k_est [N*mm/rad]':>18}{'k_std':>12}{'error [%]':>11}"
        f"{'error range ' + span + ' [%]':>30}{'mean [%]':>10}",
    ]
    for i, j in enumerate(joints):
        lo, hi, mean = ranges["min"][i] * 100, ranges["max"][i] * 100, ranges["mean"][i] * 100
        lines.append(
            f"{j['name']:8}{j['k_true'] * 1e3:19.4e}{j['k_est'] * 1e3:18.4e}{j['k_std'] * 1e3:12.2e}"
            f"{j['rel_err'] * 100:11.3f}{f'{lo:.2f} ~ {hi:.2f}':>30}{mean:10.3f}"
        )
    return "\n".join(lines)


def plot_convergence(conv: dict, k_true: np.ndarray, joint_names, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.asarray(conv["n"])
    est = np.asarray(conv["stiffness"])
    std = np.asarray(conv["stiffness_std"], dtype=float)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    for j, ax in enumerate(axes.flat):
        rel = (est[:, j] / k_true[j] - 1) * 100
        band = std[:, j] / k_true[j] * 100
        ok = np.isfinite(band)
        ax.fill_between(n[ok], (rel - band)[ok], (rel + band)[ok], alpha=0.25, label="±1 std (estimated)")
        ax.plot(n, rel, "o-", ms=3, label="k_est / k_true - 1")
        ax.axhline(0, color="k", lw=0.8)
        lim = max(5.0, float(np.nanmax(np.abs(rel[n >= min(PAPER_FIRST_N, n.max())]))) * 1.5)
        ax.set_ylim(-lim, lim)
        ax.set_title(f"{joint_names[j]}  (k_true = {k_true[j] * 1e3:.4g} N*mm/rad)", fontsize=9)
        ax.grid(alpha=0.3)
        if j >= 3:
            ax.set_xlabel("number of tests n")
        if j % 3 == 0:
            ax.set_ylabel("error [%]")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Convergence of the identified joint stiffness with the number of tests (paper Fig. 10)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_validation(rows: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(12, 4.5))
    width = 0.38
    for ax, sl, unit, scale, key in (
        (ax_t, slice(0, 3), "mm", 1e3, "rel_err_translation"),
        (ax_r, slice(3, 6), "mrad", 1e3, "rel_err_rotation"),
    ):
        meas = np.array([np.linalg.norm(r["measured"][sl]) for r in rows]) * scale
        pred = np.array([np.linalg.norm(r["predicted"][sl]) for r in rows]) * scale
        x = np.arange(len(rows))
        ax.bar(x - width / 2, pred, width, color="#1f4e79", label="calculated (identified model)")
        ax.bar(x + width / 2, meas, width, color="#9dc3e6", label="measured (scanner)")
        ax.set_xticks(x, [r["test_id"] for r in rows])
        ax.set_ylabel(f"|displacement| [{unit}]")
        twin = ax.twinx()
        twin.plot(x, [r[key] * 100 for r in rows], "r.-", label="relative error")
        twin.set_ylabel("relative error [%]", color="r")
        ax.set_title("translation" if unit == "mm" else "rotation")
        ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(
        "Calculated against measured block displacement on validation poses (paper Fig. 11, Table 6)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
