"""A lab's raw files (F/T streams in CSV, point clouds in PLY, PCD or XYZ) turned into a dataset.

A small TOML manifest (:mod:`vtestbed.lab_manifest`) lists, per test, the commanded pose, the
scanner's rough pose, the two F/T stream files (one per state: unloaded, loaded), the two cloud
files and, optionally, further scans of either block; :func:`import_dataset` reduces each stream
to its static reading (:mod:`vtestbed.ft_stream`) and converts each cloud to the dataset's format
(``clouds/<id>_<state>.ply``, ``clouds/<id>_repeat<k>.ply``, ``clouds/<id>_loaded_repeat<k>.ply``;
binary, metres), then writes setup.json, tests.csv and the repeats files, so the dataset reads,
identifies and diagnoses like a simulated one. ``ft_windows.csv``
records, per stream, the window, its length in samples and per axis the mean, std, standard
error and autocorrelation time (identification does not read it). docs/lab_data.md has the
manifest's fields.

Units and frames: poses in degrees (the setup's angle convention), the scanner pose in metres
and a rotation vector in radians (robot base frame), F/T readings in N and N*m in the sensor
frame (torques in N*mm converted on reading), clouds in the scanner frame, read in mm or m and
stored in m. Paths in the manifest are relative to the manifest's folder.
"""

from __future__ import annotations

import csv
import dataclasses
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import ft_stream
from .dataset import (
    CLOUD_DIR,
    SETUP_FILE,
    TESTS_FILE,
    DatasetSetup,
    TestRecord,
    TestWriter,
    read_setup,
    read_tests,
    write_setup,
)
from .dataset_checks import BLOCK_EDGE_RANGE_M
from .dataset_repeats import (
    REPEAT_FILES,
    LoadedRepeatWriter,
    RepeatRecord,
    RepeatWriter,
    read_repeats,
)
from .errors import DatasetError, VtestbedError
from .lab_manifest import (
    CLOUD_UNITS,
    DEFAULT_OPTIONS,
    REPEAT_KEYS,
    STATES,
    ImportOptions,
    dataset_cloud_path,
    manifest_clouds,
    read_manifest,
)
from .output_folders import require_own_kind
from .ply import MAX_CLOUD_COORDINATE_M, read_ply, write_ply
from .robots import load_robot

CLOUD_EXTENSIONS = (".ply", ".pcd", ".xyz")
WINDOWS_FILE = "ft_windows.csv"
MIN_CLOUD_EXTENT_M = 0.5 * BLOCK_EDGE_RANGE_M[0]  # smaller than any block: m read as mm
REPEAT_WRITERS = {"unloaded": RepeatWriter, "loaded": LoadedRepeatWriter}
_AXIS_UNITS = ("N", "N", "N", "Nm", "Nm", "Nm")


@dataclass(frozen=True)
class ImportResult:
    """What :func:`import_dataset` wrote.

    Attributes
    ----------
    root : Path
        The dataset folder.
    records : list of TestRecord
        The tests as tests.csv holds them.
    readings : dict
        ``(test_id, state) -> ft_stream.StaticReading`` for every stream.
    """

    root: Path
    records: list
    readings: dict


# ---------------------------------------------------------------------- clouds
def read_cloud(path: str | Path, units: str) -> np.ndarray:
    """(N, 3) points [m] of a PLY, PCD or XYZ file whose coordinates are in ``units`` ('m', 'mm').

    PLY is read by :func:`vtestbed.ply.read_ply`, PCD and XYZ by open3d (NaN and infinite points,
    an organized scanner's missing returns, are dropped; an XYZ line that is not three numbers is
    refused). The extent is checked against the unit: coordinates beyond
    :data:`MAX_CLOUD_COORDINATE_M` or a cloud smaller than :data:`MIN_CLOUD_EXTENT_M` mean the
    wrong unit.
    """
    path = Path(path)
    if units not in CLOUD_UNITS:
        raise DatasetError(f"cloud units {units!r} is not one of {', '.join(CLOUD_UNITS)} (for {path})")
    ext = path.suffix.lower()
    if ext not in CLOUD_EXTENSIONS:
        raise DatasetError(
            f"{path}: unknown point cloud extension {path.suffix!r}; valid: {', '.join(CLOUD_EXTENSIONS)}"
        )
    if not path.is_file():
        raise DatasetError(f"point cloud file {path} is missing")
    scale = 1e-3 if units == "mm" else 1.0
    points = read_ply(path, units) if ext == ".ply" else _read_open3d(path, ext) * scale
    if len(points) == 0:
        raise DatasetError(
            f"point cloud file {path} holds no points (an empty scan, or not a {ext[1:].upper()} file)"
        )
    reach = float(np.abs(points).max())
    extent = float(np.ptp(points, axis=0).max())
    if reach > MAX_CLOUD_COORDINATE_M:
        raise DatasetError(
            f"{path}: coordinates reach {reach:.4g} m read in {units}, beyond {MAX_CLOUD_COORDINATE_M:g} m: "
            "is the file in mm? (cloud units: m or mm)"
        )
    if extent < MIN_CLOUD_EXTENT_M:
        raise DatasetError(
            f"{path}: the cloud spans {extent * 1e3:.3g} mm read in {units}, less than any block "
            f"({MIN_CLOUD_EXTENT_M * 1e3:g} mm): is the file in m? (cloud units: m or mm)"
        )
    return points


def _read_open3d(path: Path, ext: str) -> np.ndarray:
    from ._open3d import o3d

    pcd = o3d.io.read_point_cloud(
        str(path), format=ext[1:], remove_nan_points=True, remove_infinite_points=True
    )
    points = np.asarray(pcd.points, dtype=float).reshape(-1, 3)
    if ext == ".xyz" and len(points):
        with path.open("rb") as fh:
            lines = sum(1 for line in fh if line.strip())
        if lines != len(points):
            raise DatasetError(
                f"{path}: {lines - len(points)} of {lines} lines are not 3 numbers (x y z); an XYZ cloud has "
                "one point per line"
            )
    return points


# ---------------------------------------------------------------------- import
def import_dataset(
    manifest: str | Path, out: str | Path, options: ImportOptions = DEFAULT_OPTIONS
) -> ImportResult:
    """Build a dataset folder (setup.json, tests.csv, clouds/, ft_windows.csv) from a lab's files.

    Parameters
    ----------
    manifest : str or Path
        The TOML manifest (docs/lab_data.md, :func:`vtestbed.lab_manifest.read_manifest`).
    out : str or Path
        The dataset folder; it must not hold a tests.csv yet.
    options : ImportOptions
        Overrides of the manifest's units and windows.

    Returns
    -------
    ImportResult
        The records as read back from the written dataset, and every stream's static reading.

    Raises
    ------
    DatasetError
        Naming the file and the field or column: a manifest field, a stream (missing column,
        non-numeric value, window outside the stream, never settles), a cloud (unknown
        extension, empty, wrong unit, listed twice), a reading beyond the sensor's range, a cloud
        file already in ``out/clouds``. A refused input leaves no dataset behind: each cloud is
        converted as it is read (one cloud in memory at a time, however many scans the lab
        took), and the converted clouds, with the folders the import made for them, are removed
        again when a later file fails; setup.json, tests.csv, the repeats files and
        ft_windows.csv are written only after every file has been read, and when writing them
        fails (a full disk) they are removed too, with the clouds: an import either leaves a whole
        dataset or nothing it wrote.
    """
    spec = read_manifest(manifest, options)
    setup: DatasetSetup = spec["setup"]
    out = Path(out)
    if (out / TESTS_FILE).exists():
        raise DatasetError(f"{out} already holds a dataset ({TESTS_FILE}); choose an empty or new folder")
    for name in (SETUP_FILE, *REPEAT_FILES.values()):  # files a lab writes by hand, kept there
        if (out / name).exists():
            raise DatasetError(
                f"{out / name} already exists: dataset import writes only new files (it would replace it); "
                "choose a new or empty --out folder"
            )
    _require_poses_in_limits(spec, setup, manifest)
    require_own_kind(out, (), "vtestbed dataset import", DatasetError)  # a sweep's or a run's folder
    _require_new_clouds(spec, out)
    made = [d for d in (out / CLOUD_DIR, *(out / CLOUD_DIR).parents) if not d.exists()]
    written = [out / name for name in (SETUP_FILE, TESTS_FILE, *REPEAT_FILES.values(), WINDOWS_FILE)]
    written = [path for path in written if not path.exists()]  # what the import may write, and remove
    readings, clouds = _read_files(spec, out, setup, options.settle_z, made)
    try:
        return _write_dataset(spec, out, setup, readings, clouds)
    except BaseException:
        _remove([*written, *clouds.values()], made)
        raise


def _write_dataset(spec: dict, out: Path, setup: DatasetSetup, readings: dict, clouds: dict) -> ImportResult:
    """setup.json, tests.csv, the repeats files and ft_windows.csv for the converted ``clouds``,
    then the dataset's own checks on what was written. A setup that states no reading noise gets
    the windows' own: per axis the RMS over every reading of its standard error of the mean."""
    if setup.sensor_noise_std is None and readings:
        sem = np.sqrt(np.mean([r.sem**2 for r in readings.values()], axis=0))
        setup = dataclasses.replace(setup, sensor_noise_std=tuple(float(v) for v in sem))
    write_setup(out, setup)
    states = [s for s in STATES if any(t[REPEAT_KEYS[s]] for t in spec["tests"])]
    with ExitStack() as files:
        writer = files.enter_context(TestWriter(out))
        # repeats files only for the states the lab scanned again
        repeat_writers = {s: files.enter_context(REPEAT_WRITERS[s](out)) for s in states}
        for t in spec["tests"]:
            for s, repeats in repeat_writers.items():  # before the test's row, as a simulation
                for k in range(1, len(t[REPEAT_KEYS[s]]) + 1):
                    repeats.append(RepeatRecord(t["id"], k, clouds[t["id"], s, k]))
            record = TestRecord(t["id"], t["group"], t["q_deg"], readings[t["id"], "unloaded"].mean,
                                readings[t["id"], "loaded"].mean, t["scanner"],
                                *(clouds[t["id"], s] for s in STATES))  # fmt: skip
            writer.append(record)
    _write_windows(out / WINDOWS_FILE, spec["tests"], readings)
    read_setup(out)
    for s in states:
        read_repeats(out, state=s)  # the dataset's own checks on what was written
    return ImportResult(out, read_tests(out, sensor_range=setup.sensor_range), readings)


def _require_poses_in_limits(spec: dict, setup: DatasetSetup, manifest) -> None:
    """Every test's pose within the robot's joint limits (identify would refuse the dataset later,
    after every cloud was converted)."""
    robot = load_robot(setup.robot)
    for i, t in enumerate(spec["tests"]):
        q = np.radians(t["q_deg"])
        q = robot.controller_to_dh(q) if setup.angle_convention == "controller" else q
        robot.check_pose(
            q, field=f"{manifest}: tests[{i}] (test {t['id']!r}) pose ({setup.angle_convention} angles)"
        )


def _require_new_clouds(spec: dict, out: Path) -> None:
    """The import writes only new cloud files: one already there may be a lab's own scan, or an
    earlier import's, and an error would remove it with the clouds this import wrote."""
    for _, t, s, k, _, _ in manifest_clouds(spec["tests"]):
        if (path := dataset_cloud_path(out, t["id"], s, k)).exists():
            raise DatasetError(
                f"{path} already exists: dataset import writes only new files (it would replace "
                "a cloud, or a scan kept there); choose a new or empty --out folder"
            )


def _read_files(spec: dict, out: Path, setup: DatasetSetup, settle_z: float, made: list) -> tuple[dict, dict]:
    """Every stream reduced and every cloud converted into ``out/clouds`` as it is read.

    Returns ``readings`` ``{(id, state): StaticReading}`` and the written clouds' paths
    ``{(id, state): Path}``, ``{(id, state, k): Path}`` for repeat ``k``. On any error (or an
    interruption) the clouds written so far (none of them there before:
    :func:`_require_new_clouds`), a half-written one included, and the folders ``made`` for them
    (those that did not exist before the import, innermost first) are removed.
    """
    readings, clouds = {}, {}
    try:
        (out / CLOUD_DIR).mkdir(parents=True, exist_ok=True)
        for _, t, s, k, path, _ in manifest_clouds(spec["tests"]):
            if k == 0:  # the state's F/T stream, then its clouds
                stream = ft_stream.read_ft_csv(t[f"ft_{s}"], spec["torque_units"])
                window = t[f"window_{s}_s"]
                r = ft_stream.static_reading(stream, window, spec["window_length"], settle_z)
                try:
                    setup.sensor_spec.check(r.mean, f"{stream.path}: the static reading")
                except VtestbedError as exc:
                    raise DatasetError(str(exc)) from None
                readings[t["id"], s] = r
            points = read_cloud(path, spec["cloud_units"])
            key = (t["id"], s, k) if k else (t["id"], s)
            clouds[key] = dataset_cloud_path(out, t["id"], s, k)  # recorded first: a half-written one too
            write_ply(clouds[key], points)
    except BaseException:
        _remove(clouds.values(), made)
        raise
    return readings, clouds


def _remove(files, made: list) -> None:
    """Remove the import's ``files`` and then the folders it ``made`` (innermost first; only if
    empty, so nothing the import did not write goes with them)."""
    for path in files:
        path.unlink(missing_ok=True)
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            pass


def window_columns() -> list[str]:
    """The columns of ft_windows.csv (per axis: mean, std, sem [N or Nm], tau [samples])."""
    cols = ["test_id", "state", "file", "window_start_s", "window_end_s", "automatic", "n_samples"]
    for a, u in zip(ft_stream.AXES, _AXIS_UNITS):
        cols += [f"{a}_mean_{u}", f"{a}_std_{u}", f"{a}_sem_{u}", f"{a}_tau_samples"]
    return cols


def _write_windows(path: Path, tests, readings) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(window_columns())
        for t in tests:
            for s in STATES:
                r = readings[t["id"], s]
                row = [
                    t["id"],
                    s,
                    str(t[f"ft_{s}"]),
                    repr(r.start),
                    repr(r.end),
                    str(r.automatic).lower(),
                    r.n,
                ]
                for i in range(6):
                    row += [repr(float(v[i])) for v in (r.mean, r.std, r.sem, r.tau)]
                w.writerow(row)
