"""Physical plausibility of each test: readings that no wire load on this block could produce.

A least-squares fit accepts any numbers. These checks flag tests whose measurements contradict
the physics of the experiment itself, whatever the stiffness, so that a swapped pair of scans, a
wrench recorded with the wrong sign or unit, or a scan of the wrong object is reported instead
of silently moving the estimate:

``opposite``
    The block's translation points against the displacement the load predicts (cosine below
    :data:`OPPOSITE_COSINE`): the loaded and unloaded scans swapped, or the wrench's sign flipped.
``far``
    The block moved more than :data:`FAR_FACTOR` times what the model predicts for its load, in
    translation or in rotation: a scan of another object or pose, or a load far larger than the
    one recorded.

For both, the prediction comes from the paper's model fitted to the *other* tests
(:func:`screen`): a fit that includes a gross outlier is pulled towards it.
``off_block``
    The measured force's line of action passes farther than :data:`WIRE_LINE_MAX_M` from the
    block's origin. A wire hooked to the block pulls along a line through the hook, which lies
    on the block, so the moment about the block is at most about the block's size times the
    force; a larger moment means torques in the wrong unit (N*mm as N*m) or the wrong sensor frame.

The motionless check (a block that did not move at all) lives beside the identification in
:mod:`vtestbed.researcher.measure`. Each check returns the ids of the flagged tests; the caller
turns them into warnings on the result, or into a :class:`~vtestbed.errors.ImplausibleDataError`
with ``strict``.

Units: SI, block frame B (wrench at B's origin, displacement of B), as in
:class:`vtestbed.researcher.measure.TestMeasurement`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .identify import a_matrix

OPPOSITE_COSINE = -0.5  # translation against the predicted one by more than 120 deg
FAR_FACTOR = 10.0  # measured displacement beyond 10x the prediction
WIRE_LINE_MAX_M = 0.5  # m: the force's line of action within this distance of B's origin
MIN_PREDICTED = 1e-12  # m or rad: below this a prediction carries no direction


def predicted_displacements(tests: Sequence, compliance: np.ndarray) -> np.ndarray | None:
    """The paper model's displacement ``J C J^T F`` (T, 6) of each test, or None when the
    compliances (n,) [rad/(N*m)] are not all finite and positive (no trustworthy prediction)."""
    c = np.asarray(compliance, dtype=float)
    if not (np.all(np.isfinite(c)) and np.all(c > 0)):
        return None
    return np.array([a_matrix(m.jacobian, m.wrench) @ c for m in tests])


def _cosine(measured: np.ndarray, predicted: np.ndarray) -> float | None:
    """Cosine between the measured and the predicted translation; None when either has no direction."""
    meas_t, pred_t = measured[:3], predicted[:3]
    norm = np.linalg.norm(meas_t) * np.linalg.norm(pred_t)
    if np.linalg.norm(pred_t) > MIN_PREDICTED and norm > 0:
        return float(meas_t @ pred_t / norm)
    return None


def _ratio(measured: np.ndarray, predicted: np.ndarray) -> float:
    """The larger of |measured| / |predicted| in translation and in rotation (0 if nothing is predicted)."""
    ratios = [
        np.linalg.norm(got) / np.linalg.norm(want)
        for got, want in ((measured[:3], predicted[:3]), (measured[3:], predicted[3:]))
        if np.linalg.norm(want) > MIN_PREDICTED
    ]
    return float(max(ratios)) if ratios else 0.0


def _flagged(tests: Sequence, compliance: np.ndarray, is_bad) -> list[str]:
    """Ids of the tests for which ``is_bad(measured, predicted)`` holds, with the given compliances."""
    predicted = predicted_displacements(tests, compliance)
    if predicted is None:
        return []
    return [m.test_id for m, p in zip(tests, predicted) if is_bad(np.asarray(m.displacement, dtype=float), p)]


def opposite_tests(tests: Sequence, compliance: np.ndarray) -> list[str]:
    """Ids of the tests whose measured translation points against the predicted one."""

    def against(measured, predicted):
        cosine = _cosine(measured, predicted)
        return cosine is not None and cosine < OPPOSITE_COSINE

    return _flagged(tests, compliance, against)


def far_tests(tests: Sequence, compliance: np.ndarray) -> list[str]:
    """Ids of the tests that moved more than :data:`FAR_FACTOR` times the prediction."""
    return _flagged(tests, compliance, lambda measured, predicted: _ratio(measured, predicted) > FAR_FACTOR)


def wire_line_distance(wrench: np.ndarray) -> float:
    """Distance [m] from B's origin to the line of action of the wrench ``[f; tau]`` (6,) at B:
    ``|f x tau| / |f|^2`` (for a force f through a point r, tau = r x f, and this is the part of
    r perpendicular to f). Infinite for a pure moment."""
    wrench = np.asarray(wrench, dtype=float)
    force, torque = wrench[:3], wrench[3:]
    f2 = float(force @ force)
    return float(np.linalg.norm(np.cross(force, torque)) / f2) if f2 > 0 else float("inf")


def off_block_tests(tests: Sequence) -> list[str]:
    """Ids of the tests whose force's line of action misses the block (see the module doc)."""
    return [m.test_id for m in tests if not wire_line_distance(m.wrench) <= WIRE_LINE_MAX_M]


def _loo_compliances(a: np.ndarray, d: np.ndarray, active: list[int]) -> dict[int, np.ndarray]:
    """Per active test, the compliances fitted (least squares, rows scaled per component) to the
    other active tests: each test judged by a model it did not shape."""
    scale = np.median(np.abs(d[active]), axis=0)
    scale = 1.0 / np.where(scale > 0, scale, 1.0)
    aw, dw = a * scale[None, :, None], d * scale[None, :]
    normal = np.einsum("tki,tkj->tij", aw, aw)
    rhs = np.einsum("tki,tk->ti", aw, dw)
    total_n, total_b = normal[active].sum(axis=0), rhs[active].sum(axis=0)
    out = {}
    for t in active:
        try:
            out[t] = np.linalg.solve(total_n - normal[t], total_b - rhs[t])
        except np.linalg.LinAlgError:
            continue  # the others alone do not determine every compliance
    return out


def screen(tests: Sequence) -> dict[str, str]:
    """Tests that contradict the physics whatever the stiffness: ``{test_id: "opposite" | "far"}``.

    A fit to all tests is pulled towards a gross outlier (its compliances may even turn negative),
    so each test is judged against the compliances fitted to the *other* tests, the worst
    offender is set aside and the rest judged again, until every remaining test passes. Needs at
    least two tests more than a fit needs (the paper's 6 unknowns: 3 tests). Tests whose force
    misses the block (:func:`off_block_tests`) are left out: their wrench is not a wire load.
    """
    a = np.array([a_matrix(m.jacobian, m.wrench) for m in tests])  # (T, 6, n)
    d = np.array([np.asarray(m.displacement, dtype=float) for m in tests])  # (T, 6)
    # a wrench that misses the block is not a wire load: it would only spoil the references
    off = set(off_block_tests(tests))
    active, flagged = [t for t, m in enumerate(tests) if m.test_id not in off], {}
    while 6 * (len(active) - 1) >= a.shape[2] + 6:
        worst, worst_score, worst_kind = None, 0.0, ""
        for t, c in _loo_compliances(a, d, active).items():
            if not (np.all(np.isfinite(c)) and np.all(c > 0)):
                continue
            kind, score = _violation(d[t], a[t] @ c)
            if kind and score > worst_score:
                worst, worst_score, worst_kind = t, score, kind
        if worst is None:
            break
        flagged[tests[worst].test_id] = worst_kind
        active.remove(worst)
    return flagged


def _violation(measured: np.ndarray, predicted: np.ndarray) -> tuple[str, float]:
    """("opposite" or "far" or "", how badly): the score ranks offenders across tests."""
    cosine = _cosine(measured, predicted)
    if cosine is not None and cosine < OPPOSITE_COSINE:
        return "opposite", FAR_FACTOR * (1.0 - cosine)
    ratio = _ratio(measured, predicted)
    return ("far", ratio) if ratio > FAR_FACTOR else ("", 0.0)


def plausibility_notes(tests: Sequence) -> list[str]:
    """One sentence per failed check, naming the tests and what to look at; empty if all pass.
    The opposite and far checks use :func:`screen` (leave-one-out references)."""
    notes = []
    flagged = screen(tests)
    ids = [i for i, kind in flagged.items() if kind == "opposite"]
    if ids:
        notes.append(
            f"tests {', '.join(ids)}: the block moved against the load (translation more than 120 deg from "
            "what the other tests' fit predicts): loaded and unloaded scans swapped, or the wrench's sign flipped?"
        )
    ids = [i for i, kind in flagged.items() if kind == "far"]
    if ids:
        notes.append(
            f"tests {', '.join(ids)}: the block moved more than {FAR_FACTOR:g} times what the other tests' fit "
            "predicts for the recorded load: a scan of another pose or object, or a load larger than recorded?"
        )
    ids = off_block_tests(tests)
    if ids:
        notes.append(
            f"tests {', '.join(ids)}: the measured force's line of action passes more than "
            f"{WIRE_LINE_MAX_M:g} m from the block, which a wire hooked to the block cannot do: torques in "
            "the wrong unit (N*mm as N*m) or the wrong sensor frame (sensor_in_flange)?"
        )
    return notes
