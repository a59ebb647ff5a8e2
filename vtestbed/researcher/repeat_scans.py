"""A dataset's repeat scans, fitted: the block frames of each test's unloaded scan and its repeats.

Frames and units: every scan is reduced by the researcher's own pipeline
(:func:`vtestbed.researcher.measure.nominal_block_frame`, :func:`~.measure.fit_scan`): each
repeat exactly as the test's unloaded scan, from the kinematic nominal pose, so identical clouds
give bitwise identical frames. Frames are (4, 4) homogeneous transforms in the scanner frame [m].
:func:`.noise_floor.noise_floor_from_frames` pools them into the noise floor.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..dataset import DatasetSetup, TestRecord, read_setup, read_tests
from ..dataset_repeats import REPEATS_FILE, read_repeats
from .kinematics import ArmKinematics
from .measure import TestMeasurement, fit_scan, nominal_block_frame, read_scan
from .noise_floor import NoiseFloor, noise_floor_from_frames

__all__ = ["dataset_floor", "estimate_noise_floor", "repeat_scan_frames", "scan_frames", "scan_labels"]


def scan_frames(
    record: TestRecord,
    cloud_unloaded: np.ndarray | None,
    repeat_clouds: Sequence[np.ndarray],
    setup: DatasetSetup,
    kin: ArmKinematics,
    frame_unloaded: np.ndarray | None = None,
    labels: Sequence[str] | None = None,
) -> list[np.ndarray]:
    """The fitted block frames (4, 4) of one test's unloaded scan and its repeats (scanner frame).

    Every scan of the unloaded block, the test's own and each repeat, is fitted exactly as
    :func:`~.measure.measure_arrays` fits the unloaded scan: from the kinematic nominal pose
    (so identical clouds give bitwise identical frames). ``frame_unloaded`` (e.g. a
    ``TestMeasurement.frame_unloaded``, the same numbers) saves fitting the unloaded scan again;
    ``cloud_unloaded`` may then be None. ``labels`` only name the scans in errors: the unloaded
    scan's, then each repeat's (default ``test T, unloaded cloud``, ``test T, repeat k cloud`` with
    k = 1, 2, ...; a dataset's also name the files).
    """
    if labels is None:
        labels = scan_labels(record.test_id, range(1, len(repeat_clouds) + 1))
    _, nominal = nominal_block_frame(record, setup, kin)
    if frame_unloaded is None:
        frame_unloaded = fit_scan(cloud_unloaded, nominal, setup, labels[0])
    frames = [np.asarray(frame_unloaded, dtype=float)]
    for label, points in zip(labels[1:], repeat_clouds):
        frames.append(fit_scan(points, nominal, setup, label))
    return frames


def scan_labels(test_id: str, repeats: Sequence[int]) -> list[str]:
    """How errors name a test's unloaded scan, then its repeats numbered ``repeats``."""
    return [f"test {test_id}, unloaded cloud", *(f"test {test_id}, repeat {k} cloud" for k in repeats)]


def estimate_noise_floor(
    root: str | Path,
    measurements: Sequence[TestMeasurement] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> NoiseFloor | None:
    """The noise floor of a dataset from its repeat scans, or None when it has no ``repeats.csv``.

    ``noise_floor_from_frames(repeat_scan_frames(...))``; the arguments and errors are
    :func:`repeat_scan_frames`'.
    """
    return dataset_floor(root, repeat_scan_frames(root, measurements, progress))


def dataset_floor(root: str | Path, frames) -> NoiseFloor | None:
    """:func:`noise_floor_from_frames` of a dataset's repeat frames (:func:`repeat_scan_frames`),
    its errors naming the dataset's repeats file; None when it has none (``frames`` None)."""
    return None if frames is None else noise_floor_from_frames(frames, str(Path(root) / REPEATS_FILE))


def repeat_scan_frames(
    root: str | Path,
    measurements: Sequence[TestMeasurement] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, list[np.ndarray]] | None:
    """Per test with repeats, the fitted frames (4, 4) of its unloaded scan and of each repeat
    (scanner frame), or None when the dataset has no ``repeats.csv``.

    Parameters
    ----------
    root : str or Path
        The dataset folder.
    measurements : sequence of TestMeasurement, optional
        This dataset's reduced tests (``load_measurements``): their unloaded frames are reused
        instead of fitting the unloaded clouds again (the same numbers).
    progress : callable(done, total), optional
        Called after each test.

    Raises
    ------
    DatasetError, ScanError
        A malformed repeats.csv (file, line, field) or a cloud the pipeline cannot fit.
    """
    root = Path(root)
    repeats = read_repeats(root)
    if not repeats:
        return None
    setup = read_setup(root)
    records = {
        r.test_id: r
        for r in read_tests(
            root, check_files=False, sensor_range=setup.sensor_range, sensor_name=setup.sensor_name
        )
    }
    kin = ArmKinematics.for_setup(setup)
    known = {m.test_id: m.frame_unloaded for m in measurements or ()}
    by_test: dict[str, list] = {}
    for rep in sorted(repeats, key=lambda r: r.repeat):
        by_test.setdefault(rep.test_id, []).append(rep)
    frames = {}
    for done, (tid, reps) in enumerate(by_test.items(), start=1):
        record = records[tid]
        labels = scan_labels(tid, [r.repeat for r in reps])
        files = [record.cloud_unloaded, *(r.cloud for r in reps)]
        clouds = [read_scan(f, label) for f, label in zip(files[1:], labels[1:])]
        cloud0 = None if tid in known else read_scan(files[0], labels[0])
        # a fit's error names the file too, as read_scan's does
        named = [f"{label} {f}" for label, f in zip(labels, files)]
        frames[tid] = scan_frames(record, cloud0, clouds, setup, kin, known.get(tid), named)
        if progress:
            progress(done, len(by_test))
    return frames
