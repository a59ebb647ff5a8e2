"""Displacements measured against the mean of a test's unloaded scans: the repeat scans used twice.

Why: a lab that records ``r`` repeat scans of the unloaded block for the noise floor
(:mod:`.noise_floor`) holds ``m = r + 1`` scans of that block per test. The paper measures a
displacement from one unloaded and one loaded scan, so its noise is that of two scans,
``2 S`` (``S`` one scan's frame covariance: the floor's covariance). Against the mean of the
``m`` unloaded scans it is ``S (1 + 1 / m)``: 0.625 of it with 3 repeats, 1.6 times the
information per test for every test the diagnosis makes (power, parameter std, validation
ratios), with the tests and the scans the dataset already holds.

The floor stays independent of the measurements: for Gaussian noise a sample's mean is
independent of its sample covariance, so the mean frame (what the displacement now uses) and
the repeats' scatter (what the floor uses) are independent, which the single unloaded scan, one
member of that scatter, is not quite.

A lab may scan the loaded block again too (``loaded_repeats.csv``, :mod:`vtestbed.dataset_repeats`):
then the loaded end is averaged as well, ``m'`` loaded scans, and the noise is ``S (1 / m + 1 / m')``,
0.25 of the paper's with 3 repeats at each end (4 times the information per test). The loaded
repeats do not enter the floor (a loaded block may creep between scans). They are checked for
creep (:mod:`.loaded_scatter`): when they scatter more than the unloaded scans at level
``creep_alpha`` (default :data:`CREEP_ALPHA`), the loaded end falls back to the test's own loaded
scan (the first, taken with the F/T reading; the floor scaled for ``m' = 1``), because the mean of
a creeping block's scans is a frame it reached only after the reading.

Which tests: every test of the dataset against the mean of its first ``m`` unloaded scans, ``m``
the fewest any test has (:func:`common_scan_count`), so that one floor, scaled by
:meth:`.NoiseFloor.for_scan_mean`, whitens every test (identification and validation alike). A
dataset in which some test has no repeat is measured as the paper does (``m = 1``).

Frames and units: a frame is (4, 4) in the scanner frame [m]; the mean of frames ``F_i`` is
``F_0`` moved by the mean of ``e_i = displacement_in_block_frame(F_0, F_i)`` (translation [m] and
rotation vector [rad] in ``F_0``'s axes), the Frechet mean to second order in the scatter
(micrometres and microradians: 1e-12 relative). Displacements in the unloaded block frame
[m, rad], as :mod:`.measure` defines them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..dataset import DatasetSetup, read_setup
from ..dataset_repeats import read_repeats
from ..errors import DatasetError, UnknownNameError
from ..transforms import displacement_in_block_frame, homogeneous, matrix_from_rotation_vector
from .diagnose import DEFAULT_ALPHA, require_floor
from .loaded_scatter import loaded_scatter
from .measure import TestMeasurement, fit_scan, load_measurements, read_scan
from .noise_floor import NoiseFloor, scan_deviations
from .reading_noise import with_reading_noise
from .repeat_scans import dataset_floor, repeat_scan_frames

__all__ = [
    "CREEP_ALPHA",
    "REFERENCES",
    "against_reference",
    "against_scan_mean",
    "common_scan_count",
    "load_with_floor",
    "loaded_repeat_frames",
    "loaded_scan_frames",
    "mean_frame",
]

# What each displacement is measured against: "scan", the test's own unloaded scan (the paper's
# method, and `vtestbed identify`'s default), or "mean", the mean of the test's unloaded scans
# (to the mean of its loaded scans when the dataset has loaded repeats).
REFERENCES = ("scan", "mean")

# The creep check's level: loaded repeats that scatter more than the unloaded scans at this level
# are left out of the displacements (:func:`against_scan_mean`). The workflow's own level.
CREEP_ALPHA = DEFAULT_ALPHA


def mean_frame(frames: Sequence[np.ndarray]) -> np.ndarray:
    """(4, 4) mean of nearby frames: the first moved by the mean of the others' deviations from it."""
    e = scan_deviations(frames).mean(axis=0)  # each frame's deviation from the first, averaged
    return np.asarray(frames[0], dtype=float) @ homogeneous(matrix_from_rotation_vector(e[3:]), e[:3])


def common_scan_count(
    measurements: Sequence[TestMeasurement], frames_by_test: Mapping[str, Sequence[np.ndarray]] | None
) -> int:
    """The fewest scans of a block (the test's own and its repeats) any measured test has (>= 1)."""
    if not measurements or not frames_by_test:
        return 1
    return min(max(len(frames_by_test.get(m.test_id, ())), 1) for m in measurements)


def against_scan_mean(
    measurements: Sequence[TestMeasurement],
    frames_by_test: Mapping[str, Sequence[np.ndarray]],
    floor: NoiseFloor,
    loaded_frames: Mapping[str, Sequence[np.ndarray]] | None = None,
    creep_alpha: float | None = CREEP_ALPHA,
) -> tuple[list[TestMeasurement], NoiseFloor]:
    """Every test's displacement from the mean of its first ``m`` unloaded scans (to the mean of
    its first ``m'`` loaded scans, with loaded repeats that pass the creep check), and the floor for it.

    Parameters
    ----------
    measurements : sequence of TestMeasurement
        The dataset's reduced tests (:func:`.measure.load_measurements`).
    frames_by_test : mapping test_id -> sequence of (4, 4) arrays
        Per test, the frames of its unloaded scan (first, ``TestMeasurement.frame_unloaded``) and
        its repeats (:func:`.repeat_scans.repeat_scan_frames`).
    floor : NoiseFloor
        The floor of single-scan displacements, from the same frames.
    loaded_frames : mapping test_id -> sequence of (4, 4) arrays, optional
        Per test, the frames of its loaded scan (first, ``TestMeasurement.frame_loaded``) and its
        loaded repeats (:func:`loaded_scan_frames`); None: the loaded scan alone.
    creep_alpha : float or None
        The creep check's level: loaded repeats whose scatter it rejects at this level are left
        out (``m' = 1``, the test's own loaded scan). None: averaged whatever the check says.

    Returns
    -------
    measurements : list of TestMeasurement
        ``frame_unloaded`` and ``frame_loaded`` the mean frames, ``displacement`` between them;
        the measurements themselves when ``m = m' = 1``.
    floor : NoiseFloor
        ``floor.for_scan_mean(m, m')``: covariance times ``(1 / m + 1 / m') / 2``; with loaded
        repeats its ``loaded_scatter`` says whether the loaded scans scatter as the unloaded ones
        (:func:`.loaded_scatter.loaded_scatter`) and whether they were left out for it.
    """
    m = common_scan_count(measurements, frames_by_test)
    m_loaded = common_scan_count(measurements, loaded_frames)
    check = loaded_scatter(frames_by_test, loaded_frames) if m_loaded > 1 else None
    if check is not None and creep_alpha is not None and check.moved(creep_alpha):
        check, m_loaded = replace(check, left_out=True), 1  # the block crept: its own loaded scan
    if m == 1 and m_loaded == 1:
        return list(measurements), floor if check is None else replace(floor, loaded_scatter=check)
    out = []
    for t in measurements:
        ref = mean_frame(list(frames_by_test[t.test_id])[:m]) if m > 1 else t.frame_unloaded
        loaded = mean_frame(list(loaded_frames[t.test_id])[:m_loaded]) if m_loaded > 1 else t.frame_loaded
        moved = displacement_in_block_frame(ref, loaded)
        out.append(replace(t, frame_unloaded=ref, frame_loaded=loaded, displacement=moved))
    return out, replace(floor.for_scan_mean(m, m_loaded), loaded_scatter=check)


def loaded_repeat_frames(
    frame_loaded: np.ndarray, clouds: Sequence[np.ndarray], setup: DatasetSetup, labels: Sequence[str]
) -> list[np.ndarray]:
    """The frames (4, 4) of a test's loaded scan (``frame_loaded``, the measurement's) and of each
    loaded repeat (``clouds``, (N, 3) [m] in the scanner frame), each fitted from ``frame_loaded``
    as the loaded scan is fitted from the unloaded one (:func:`.measure.measure_arrays`); ``labels``
    name the repeats in errors. The dataset's and the campaign trial's loaded repeats both come
    through here, as their unloaded repeats come through :func:`.repeat_scans.scan_frames`."""
    return [frame_loaded] + [fit_scan(c, frame_loaded, setup, label) for c, label in zip(clouds, labels)]


def loaded_scan_frames(
    root: str | Path, measurements: Sequence[TestMeasurement]
) -> dict[str, list[np.ndarray]] | None:
    """Per test with loaded repeats, the frames (4, 4) of its loaded scan (the measurement's) and of
    each loaded repeat (scanner frame), or None when the dataset has no ``loaded_repeats.csv``.

    Each repeat is fitted by :func:`loaded_repeat_frames`. Errors name the test, the repeat and the file.
    """
    root = Path(root)
    repeats = read_repeats(root, state="loaded")
    if not repeats:
        return None
    setup = read_setup(root)
    by_test: dict[str, list] = {}
    for rep in sorted(repeats, key=lambda r: r.repeat):
        by_test.setdefault(rep.test_id, []).append(rep)
    frames = {}
    for m in measurements:  # a test not measured here is skipped (read_repeats checked its id)
        reps = by_test.get(m.test_id, [])
        if reps:
            labels = [f"test {m.test_id}, loaded repeat {r.repeat} cloud" for r in reps]
            clouds = [read_scan(r.cloud, label) for r, label in zip(reps, labels)]
            named = [f"{label} {r.cloud}" for r, label in zip(reps, labels)]  # a fit's error names the file
            frames[m.test_id] = loaded_repeat_frames(m.frame_loaded, clouds, setup, named)
    return frames


def load_with_floor(
    root: str | Path, creep_alpha: float | None = CREEP_ALPHA, edges: bool = False
) -> tuple[DatasetSetup, list[TestMeasurement], NoiseFloor]:
    """A dataset as the discrepancy workflow measures it: (setup, measurements, floor).

    The tests reduced (:func:`.measure.load_measurements`), the repeat scans' noise floor
    (required: :func:`.diagnose.require_floor` says how to record them), and every displacement
    against its test's mean unloaded frame (to its mean loaded frame when the dataset has
    loaded repeats that pass the creep check at ``creep_alpha``) with the floor for it
    (:func:`against_scan_mean`), the F/T readings' noise added to that floor where setup.json gives
    it (:func:`.reading_noise.with_reading_noise`). ``edges``: with each test's apparent block edges
    (the scale check's, :mod:`.block_size`).
    """
    setup, measurements = load_measurements(root, edges=edges)
    frames = repeat_scan_frames(root, measurements)
    floor = require_floor(dataset_floor(root, frames), root)
    loaded = loaded_scan_frames(root, measurements)
    measurements, floor = against_scan_mean(measurements, frames, floor, loaded, creep_alpha)
    return setup, measurements, with_reading_noise(floor, measurements, setup)


def against_reference(
    reference: str,
    measurements: Sequence[TestMeasurement],
    frames_by_test: Mapping[str, Sequence[np.ndarray]] | None,
    floor: NoiseFloor | None,
    source: str | Path = "the dataset",
    loaded_frames: Mapping[str, Sequence[np.ndarray]] | None = None,
    creep_alpha: float | None = CREEP_ALPHA,
    *,
    setup: DatasetSetup | None = None,
) -> tuple[list[TestMeasurement], NoiseFloor | None]:
    """The measurements and floor for ``reference`` (one of :data:`REFERENCES`).

    ``"scan"`` returns them unchanged (the paper's: one scan at each end). ``"mean"`` is
    :func:`against_scan_mean` (with ``loaded_frames``, the loaded end averaged too unless the
    creep check rejects them at ``creep_alpha``), asked for
    explicitly: a dataset without repeat scans (``frames_by_test`` None), or with a test that has
    none, raises a DatasetError naming ``source`` and those tests, instead of falling back to
    the single scan as the discrepancy workflow does. With ``setup`` the floor returned carries
    the F/T readings' noise it states (:func:`.reading_noise.with_reading_noise`), as
    :func:`load_with_floor`'s does.
    """
    if reference not in REFERENCES:
        raise UnknownNameError("displacement reference", reference, REFERENCES)
    if reference == "scan":
        measurements = list(measurements)
    else:
        asked = (
            f"{source}: reference 'mean' measures each displacement against the mean of its test's "
            "unloaded scans (the test's own and its repeats)"
        )
        if frames_by_test is None or floor is None:
            raise DatasetError(
                f"{asked}, and the dataset has no repeat scans (repeats.csv): record 1 or more further scans "
                "of the unloaded block per test (a simulated scenario: [scanner] repeats = 3), or use "
                "reference 'scan' (the paper's)"
            )
        lacking = [m.test_id for m in measurements if len(frames_by_test.get(m.test_id, ())) < 2]
        if lacking:
            raise DatasetError(
                f"{asked}, and test{'s' * (len(lacking) > 1)} {', '.join(lacking[:10])}"
                f"{' ...' if len(lacking) > 10 else ''} ha{'ve' if len(lacking) > 1 else 's'} no repeat "
                "scan in repeats.csv: record at least one for every test, or use reference 'scan' (the paper's)"
            )
        measurements, floor = against_scan_mean(
            measurements, frames_by_test, floor, loaded_frames, creep_alpha
        )
    if setup is None or floor is None:
        return measurements, floor
    return measurements, with_reading_noise(floor, measurements, setup)
