"""A lab's raw files (F/T streams in CSV, point clouds in PLY, PCD or XYZ) turned into a dataset.

A small TOML manifest lists, per test, the commanded pose, the scanner's rough pose, the two F/T
stream files (one per state: unloaded, loaded) and the two cloud files; :func:`import_dataset`
reduces each stream to its static reading (:mod:`vtestbed.ft_stream`) and converts each cloud
to the dataset's format (``clouds/<id>_<state>.ply``, binary, metres), then writes setup.json
and tests.csv, so the dataset reads and identifies like a simulated one. ``ft_windows.csv``
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
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import ft_stream
from .dataset import (
    CLOUD_DIR,
    GROUPS,
    TESTS_FILE,
    DatasetSetup,
    TestRecord,
    TestWriter,
    parse_setup,
    read_setup,
    read_tests,
    write_setup,
)
from .dataset_checks import BLOCK_EDGE_RANGE_M, SCANNER_POSITION_RANGE_M, SCANNER_ROTVEC_RANGE_RAD
from .errors import DatasetError, VtestbedError
from .files import read_json, read_toml
from .output_folders import require_own_kind
from .ply import MAX_CLOUD_COORDINATE_M, read_ply, write_ply
from .robots import load_robot
from .schema import Fields
from .transforms import homogeneous, matrix_from_rotation_vector

CLOUD_UNITS = ("m", "mm")
CLOUD_EXTENSIONS = (".ply", ".pcd", ".xyz")
STATES = ("unloaded", "loaded")
WINDOWS_FILE = "ft_windows.csv"
MIN_CLOUD_EXTENT_M = 0.5 * BLOCK_EDGE_RANGE_M[0]  # smaller than any block: m read as mm
TOP_KEYS = ("setup", "units", "ft", "tests")
TEST_KEYS = (
    "id",
    "group",
    "q_deg",
    "scanner_position_m",
    "scanner_rotvec_rad",
    *(f"ft_{s}" for s in STATES),
    *(f"cloud_{s}" for s in STATES),
    *(f"window_{s}_s" for s in STATES),
)
_AXIS_UNITS = ("N", "N", "N", "Nm", "Nm", "Nm")
_ID = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*")


class _ManifestFields(Fields):
    """The scenario validators, raising DatasetError (a manifest describes a dataset)."""

    def error(self, field_name: str, message: str) -> DatasetError:
        return DatasetError(f"{self.source}: {field_name}: {message}")


@dataclass(frozen=True)
class ImportOptions:
    """Choices that override the manifest's ``[units]`` and ``[ft]`` tables (None: the manifest's).

    Attributes
    ----------
    cloud_units : {'m', 'mm'} or None
        Length unit of every cloud file.
    torque_units : {'Nm', 'Nmm'} or None
        Unit of the streams' torque columns.
    window : (float, float) or None
        Static window [s] of every stream without its own ``window_<state>_s``.
    window_length : float or None
        Length [s] of the automatic (quietest) window.
    settle_z : float
        The settle check's threshold: half-window means this many standard errors apart are a
        stream that has not settled (:func:`vtestbed.ft_stream.settle_check`).
    """

    cloud_units: str | None = None
    torque_units: str | None = None
    window: tuple[float, float] | None = None
    window_length: float | None = None
    settle_z: float = ft_stream.SETTLE_Z


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


# ---------------------------------------------------------------------- manifest
def _window(f: Fields, value, field: str) -> tuple[float, float]:
    start, end = f.vector(value, field, 2, -1e9, 1e9)
    if not start < end:
        raise f.error(field, f"must be [start, end] in s with start < end, got {value!r}")
    return start, end


def _path(f: Fields, base: Path, value, field: str) -> Path:
    text = f.string(value, field, allow_empty=False)
    return base / text


def _setup(f: Fields, base: Path, value) -> DatasetSetup:
    if isinstance(value, str):
        path = _path(f, base, value, "setup")
        return parse_setup(read_json(path, "dataset setup file", DatasetError), path)
    return parse_setup(f.table(value, "setup"), f"{f.source}: [setup]")


def _test(f: Fields, base: Path, value, i: int, window) -> dict:
    where = f"tests[{i}]"
    t = f.table(value, where, TEST_KEYS)
    for key in TEST_KEYS:
        if key not in t and not key.startswith("window_"):
            raise f.error(f"{where}.{key}", "is missing")
    tid = f.string(t["id"], f"{where}.id", allow_empty=False)
    if not _ID.fullmatch(tid):
        raise f.error(f"{where}.id", f"{tid!r} must be letters, digits, '_', '-', '.' (it names cloud files)")
    rotvec = np.array(
        f.vector(t["scanner_rotvec_rad"], f"{where}.scanner_rotvec_rad", 3, *SCANNER_ROTVEC_RANGE_RAD)
    )
    position = np.array(
        f.vector(t["scanner_position_m"], f"{where}.scanner_position_m", 3, *SCANNER_POSITION_RANGE_M)
    )
    out = {
        "id": tid,
        "group": f.choice(t["group"], f"{where}.group", GROUPS),
        "q_deg": np.array(f.vector(t["q_deg"], f"{where}.q_deg", 6, -720.0, 720.0)),
        "scanner": homogeneous(matrix_from_rotation_vector(rotvec), position),
    }
    for s in STATES:
        out[f"ft_{s}"] = _path(f, base, t[f"ft_{s}"], f"{where}.ft_{s}")
        out[f"cloud_{s}"] = _path(f, base, t[f"cloud_{s}"], f"{where}.cloud_{s}")
        key = f"window_{s}_s"
        out[key] = _window(f, t[key], f"{where}.{key}") if key in t else window
    return out


def read_manifest(path: str | Path, options: ImportOptions = ImportOptions()) -> dict:
    """The manifest checked field by field, options applied (see docs/lab_data.md).

    Returns ``{"setup": DatasetSetup, "cloud_units", "torque_units", "window_length", "tests":
    [dict per test]}``; raises a DatasetError naming the file and the field.
    """
    path = Path(path)
    data = read_toml(path, "lab manifest", DatasetError)
    f = _ManifestFields(path)
    f.table(data, "", TOP_KEYS)
    base = path.parent
    if "setup" not in data:
        raise f.error("setup", 'is missing: a setup.json path (setup = "setup.json") or a [setup] table')
    units = f.table(data.get("units", {}), "units", ("cloud", "torque"))
    ft = f.table(data.get("ft", {}), "ft", ("window_s", "window_length_s"))
    cloud_units = options.cloud_units or units.get("cloud")
    if cloud_units is None:
        raise f.error("units.cloud", "is missing: the clouds' unit, 'm' or 'mm' (or --cloud-units m|mm)")
    cloud_units = f.choice(cloud_units, "units.cloud (or --cloud-units)", CLOUD_UNITS)
    torque = f.choice(
        options.torque_units or units.get("torque", "Nm"), "units.torque", tuple(ft_stream.TORQUE_UNITS)
    )
    window = options.window or (_window(f, ft["window_s"], "ft.window_s") if "window_s" in ft else None)
    length = options.window_length or f.number(
        ft.get("window_length_s", ft_stream.DEFAULT_WINDOW_LENGTH_S), "ft.window_length_s", 1e-3, 1e4
    )
    tests = data.get("tests")
    if not isinstance(tests, list) or not tests:
        raise f.error("tests", "must list at least one test ([[tests]] tables)")
    parsed = [_test(f, base, t, i, window) for i, t in enumerate(tests)]
    ids = [t["id"] for t in parsed]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise f.error("tests", f"duplicate ids {dup}")
    setup = _setup(f, base, data["setup"])
    load_robot(setup.robot)  # a known robot, or the valid names
    return {"setup": setup, "cloud_units": cloud_units, "torque_units": torque, "window_length": length,
            "tests": parsed}  # fmt: skip


# ---------------------------------------------------------------------- import
def import_dataset(
    manifest: str | Path, out: str | Path, options: ImportOptions = ImportOptions()
) -> ImportResult:
    """Build a dataset folder (setup.json, tests.csv, clouds/, ft_windows.csv) from a lab's files.

    Parameters
    ----------
    manifest : str or Path
        The TOML manifest (docs/lab_data.md).
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
        extension, empty, wrong unit), a reading beyond the sensor's range. Nothing is written
        before every file has been read.
    """
    spec = read_manifest(manifest, options)
    setup: DatasetSetup = spec["setup"]
    out = Path(out)
    if (out / TESTS_FILE).exists():
        raise DatasetError(f"{out} already holds a dataset ({TESTS_FILE}); choose an empty or new folder")
    require_own_kind(out, (), "vtestbed dataset import", DatasetError)  # a sweep's or a run's folder
    sensor = setup.sensor_spec
    readings, clouds = {}, {}
    for t in spec["tests"]:
        for s in STATES:
            stream = ft_stream.read_ft_csv(t[f"ft_{s}"], spec["torque_units"])
            r = ft_stream.static_reading(stream, t[f"window_{s}_s"], spec["window_length"], options.settle_z)
            try:
                sensor.check(r.mean, f"{stream.path}: the static reading")
            except VtestbedError as exc:
                raise DatasetError(str(exc)) from None
            readings[t["id"], s] = r
            clouds[t["id"], s] = read_cloud(t[f"cloud_{s}"], spec["cloud_units"])
    write_setup(out, setup)
    with TestWriter(out) as writer:
        for t in spec["tests"]:
            paths = []
            for s in STATES:
                paths.append(write_ply(out / CLOUD_DIR / f"{t['id']}_{s}.ply", clouds[t["id"], s]))
            record = TestRecord(t["id"], t["group"], t["q_deg"], readings[t["id"], "unloaded"].mean,
                                readings[t["id"], "loaded"].mean, t["scanner"], *paths)  # fmt: skip
            writer.append(record)
    _write_windows(out / WINDOWS_FILE, spec["tests"], readings)
    read_setup(out)
    return ImportResult(out, read_tests(out, sensor_range=setup.sensor_range), readings)


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
