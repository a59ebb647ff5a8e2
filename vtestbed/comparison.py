"""Estimates against the truth: the only place outside the world that reads ``truth.json``.

A simulated dataset carries the world's truth in a separate file; identification never opens it.
After identification, these functions compare: per-joint relative errors, the paper's Table 5
columns (error range and mean over the estimates from ``PAPER_FIRST_N`` tests on) and the table
itself. A lab's dataset has no truth file: :func:`read_truth` then returns None and the reports
skip the comparison. Stiffness in N*m/rad inside, N*mm/rad in the printed table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .dataset import TRUTH_FILE
from .errors import DatasetError
from .files import read_json
from .researcher.identify import IdentificationResult
from .researcher.report import PAPER_FIRST_N
from .truth_file import check_recorded

__all__ = ["PAPER_FIRST_N", "compare", "error_ranges", "read_truth", "table5", "true_stiffness"]


# The range of a true joint stiffness [N*m/rad] that truth.json may hold: a small arm's wrist
# (1 N*m rated torque at 2.5 mrad, robot_import's assumption) is 4e2, the KR60-3's joint 1 2.2e6.
# Outside it the number is not a stiffness in N*m/rad (1e-300, or N*mm/rad: 1e3 times too large,
# 2.2e9 for the KR60-3), and a rel_err against it would be inf or silently wrong.
TRUE_STIFFNESS_RANGE_NM_PER_RAD = (10.0, 1e9)
STIFFNESS_KEY = "stiffness_true_Nm_per_rad"


def read_truth(root: str | Path, dof: int | None = None) -> dict | None:
    """The truth file of a simulated dataset folder, or None when there is none (lab data).

    A corrupt or wrong-shaped file is a DatasetError naming the file and the field: the true
    stiffness must be ``dof`` numbers in :data:`TRUE_STIFFNESS_RANGE_NM_PER_RAD` (``dof`` None:
    one per name of the file's ``joint_names``, or as many as given), ``tests`` a table of tests.
    """
    path = Path(root) / TRUTH_FILE
    if not path.exists():
        return None
    truth = read_json(path, "truth file", DatasetError)
    if dof is None:
        names, values = truth.get("joint_names"), truth.get(STIFFNESS_KEY)
        dof = (
            len(names)
            if isinstance(names, list) and names
            else len(values)
            if isinstance(values, list)
            else None
        )
    true_stiffness(truth, dof, path)
    check_recorded(truth, path)
    return truth


def true_stiffness(truth: dict, dof: int | None, source: str | Path = TRUTH_FILE) -> np.ndarray:
    """(dof,) true joint stiffness [N*m/rad] from a truth mapping, or a DatasetError naming the
    file, the key, the count and the range (``dof`` None: any count, at least one)."""
    lo, hi = TRUE_STIFFNESS_RANGE_NM_PER_RAD
    count = "numbers" if dof is None else f"{dof} number{'s' * (dof != 1)}"
    valid = f"{count} (one per joint), each in [{lo:g}, {hi:g}] N*m/rad"
    if STIFFNESS_KEY not in truth:
        raise DatasetError(f"{source}: key {STIFFNESS_KEY!r} is missing; it must hold {valid}")
    values = truth[STIFFNESS_KEY]
    numbers = isinstance(values, list) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in values
    )
    k = np.asarray(values, dtype=float) if numbers else np.array([])
    shape_ok = k.size > 0 if dof is None else k.shape == (dof,)
    if not shape_ok or not np.all((k >= lo) & (k <= hi)):  # also refuses NaN
        raise DatasetError(f"{source}: {STIFFNESS_KEY} must be {valid}, got {values!r}")
    return k


def compare(result: IdentificationResult, truth: dict) -> list[dict]:
    """Per joint: name, k_true, k_est, k_std [N*m/rad] and rel_err = k_est/k_true - 1."""
    k_true = true_stiffness(truth, len(result.joint_names))
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
