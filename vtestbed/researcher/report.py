"""The researcher's report of one identification: convergence with the number of tests
(paper Fig. 10) and predicted against measured displacement on validation tests (Fig. 11).

Truth-free: the comparison with a simulated dataset's truth lives in :mod:`vtestbed.comparison`;
:func:`plot_convergence` only draws a reference stiffness when its caller gives one.
Stiffness in N*m/rad, displacements in m and rad.

Cost of the convergence study: row n is exactly the identification on the first n tests (same
estimator, same covariance: analytic below the jackknife's 8 tests, jackknife from 8 on). The
tests are checked and stacked once (:func:`~vtestbed.researcher.identify.identify_prefixes`) and
each row is a fit on a prefix of the stacked system, linear in n (row-scaled whitening, jackknife
refits as normal-equation downdates), so N rows cost O(N^2), not the O(N^4) of a dense whitening
matrix rebuilt per row and per refit.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..plotting import pyplot, save_figure
from .identify import identify_prefixes
from .measure import TestMeasurement, predict_displacement, stacked

PAPER_FIRST_N = 6  # the paper's Table 5 uses the estimates from 6 to 20 tests


def convergence(measurements: list[TestMeasurement], method: str, joint_names, displacement_cov=None) -> dict:
    """Estimates using the first n identification tests, n = 1..N (paper Figure 10).

    ``displacement_cov``: the given covariance of ``"wls"`` and ``"gls_floor"`` (the result's).

    Returns ``{"n": [1..N], "stiffness": N lists of (n_joints,) [N*m/rad], "stiffness_std": the
    same}``; validation tests are ignored. O(N^2) in time (module docstring).
    """
    tests = [m for m in measurements if m.group == "identification"]
    rows = {"n": [], "stiffness": [], "stiffness_std": []}
    if not tests:
        return rows
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # small-n fits are expected to be ill-conditioned
        fits = identify_prefixes(
            *stacked(tests), method=method, displacement_cov=displacement_cov, joint_names=joint_names,
            test_ids=tuple(m.test_id for m in tests),
        )  # fmt: skip
    for n, res in enumerate(fits, start=1):
        rows["n"].append(n)
        rows["stiffness"].append(res.stiffness.tolist())
        rows["stiffness_std"].append(res.stiffness_std.tolist())
    return rows


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


def plot_convergence(
    conv: dict, joint_names, path: Path, reference: np.ndarray | None = None, reference_name: str = "k_true"
) -> Path:
    """Figure 10: each joint's estimate against the number of tests, relative to ``reference``
    (N*m/rad, e.g. the truth of a simulated dataset) or, without one, to the final estimate."""
    plt = pyplot()
    n = np.asarray(conv["n"])
    est = np.asarray(conv["stiffness"])
    std = np.asarray(conv["stiffness_std"], dtype=float)
    if reference is None:
        reference, reference_name = est[-1], "k_final"
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    for j, ax in enumerate(axes.flat):
        rel = (est[:, j] / reference[j] - 1) * 100
        band = std[:, j] / reference[j] * 100
        ok = np.isfinite(band)
        ax.fill_between(n[ok], (rel - band)[ok], (rel + band)[ok], alpha=0.25, label="±1 std (estimated)")
        ax.plot(n, rel, "o-", ms=3, label=f"k_est / {reference_name} - 1")
        ax.axhline(0, color="k", lw=0.8)
        lim = max(5.0, float(np.nanmax(np.abs(rel[n >= min(PAPER_FIRST_N, n.max())]))) * 1.5)
        ax.set_ylim(-lim, lim)
        ax.set_title(f"{joint_names[j]}  ({reference_name} = {reference[j] * 1e3:.4g} N*mm/rad)", fontsize=9)
        ax.grid(alpha=0.3)
        if j >= 3:
            ax.set_xlabel("number of tests n")
        if j % 3 == 0:
            ax.set_ylabel("error [%]")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Convergence of the identified joint stiffness with the number of tests (paper Fig. 10)")
    return save_figure(fig, path)


def plot_validation(rows: list[dict], path: Path) -> Path:
    """Figure 11: calculated against measured displacement magnitude per validation test."""
    plt = pyplot()
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
    return save_figure(fig, path)
