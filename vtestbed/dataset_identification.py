"""The researcher's job on any dataset: reduce it, identify the stiffness, with its noise floor.

Reads a dataset folder (setup.json, tests.csv, the clouds, the repeat scans when asked) and
nothing of the world: it imports neither :mod:`vtestbed.world` nor mujoco
(``tests/test_architecture.py``), so ``vtestbed identify`` runs on a lab's dataset without the
physics engine. :mod:`vtestbed.experiment` (simulate, run) calls it after simulating.
Units: SI inside; stiffness in N*m/rad.
"""

from __future__ import annotations

import time
from pathlib import Path

from .errors import UnknownNameError
from .researcher.measure import identify_measurements, load_measurements
from .robots import load_robot
from .run_record import Timings

__all__ = ["identify_dataset", "identify_dataset_with_floor"]


def identify_dataset(
    root: str | Path,
    method: str = "fgls",
    progress: bool = False,
    timings: Timings | None = None,
    strict: bool = False,
    reference: str = "scan",
):
    """The researcher's job on any dataset: returns (setup, measurements, IdentificationResult).

    ``strict``: implausible tests (a block that did not move, moved against or far beyond its
    load, a force that misses the block) raise instead of warning. ``reference``: what each
    displacement is measured against, the test's own unloaded scan (``"scan"``, the paper's) or
    the mean of its unloaded scans (``"mean"``, needs repeat scans;
    :mod:`vtestbed.researcher.scan_mean`).
    """
    setup, measurements, result, _ = identify_dataset_with_floor(
        root, method, progress, timings, strict, floor=method == "gls_floor", reference=reference
    )
    return setup, measurements, result


def identify_dataset_with_floor(
    root: str | Path,
    method: str = "fgls",
    progress: bool = False,
    timings: Timings | None = None,
    strict: bool = False,
    floor: bool = True,
    reference: str = "scan",
):
    """:func:`identify_dataset` plus the dataset's repeat-scan noise floor, estimated once.

    Returns (setup, measurements, IdentificationResult, NoiseFloor or None); the floor is None
    without repeat scans or with ``floor=False`` (unless ``method`` weights with it, "gls_floor",
    or ``reference="mean"`` scales it). With ``reference="mean"`` the measurements and the floor
    are those of displacements against each test's mean unloaded frame (to its mean loaded frame
    when the dataset has loaded repeats).
    """
    from .researcher.scan_mean import REFERENCES, against_reference, loaded_scan_frames

    if reference not in REFERENCES:  # before any cloud is read
        raise UnknownNameError("displacement reference", reference, REFERENCES)
    timings = timings or Timings()
    bar = None

    def tick(done, total):
        nonlocal bar
        if progress and bar is None:  # once the dataset's files have been read: an error in them
            from tqdm import tqdm  # is then one line, not appended to an empty bar

            bar = tqdm(desc="process clouds", unit="test", total=total)
        if bar is not None:
            bar.total = total
            bar.update(done - bar.n)

    t0 = time.perf_counter()
    try:
        setup, measurements = load_measurements(root, progress=tick)
    finally:
        if bar:
            bar.close()  # ends the bar's line before an error is printed
    t1 = time.perf_counter()
    noise_floor = None
    if floor or method == "gls_floor" or reference != "scan":  # None without repeats: gls_floor says so
        from .researcher.repeat_scans import dataset_floor, repeat_scan_frames

        frames = repeat_scan_frames(root, measurements)
        noise_floor = dataset_floor(root, frames)
        loaded = loaded_scan_frames(root, measurements) if reference != "scan" else None
        measurements, noise_floor = against_reference(  # with the F/T readings' noise setup.json states
            reference, measurements, frames, noise_floor, root, loaded, setup=setup
        )
    result = identify_measurements(
        measurements, method, load_robot(setup.robot).joint_names, strict=strict, noise_floor=noise_floor,
        source=str(root),
    )  # fmt: skip
    timings.process += t1 - t0
    timings.identify += time.perf_counter() - t1
    return setup, measurements, result, noise_floor
