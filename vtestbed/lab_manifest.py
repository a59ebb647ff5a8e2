"""A lab's import manifest (TOML), checked field by field (docs/lab_data.md).

The manifest lists, per test, the commanded pose [deg], the scanner's rough pose (metres and a
rotation vector in radians, robot base frame), the two F/T stream files and the two cloud files,
and optionally further scans of the unloaded and of the loaded block (``repeat_clouds``,
``loaded_repeat_clouds``). Paths are relative to the manifest's folder. Every error is a
DatasetError that names the file and the field; :mod:`vtestbed.lab_import` reads what it lists.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import ft_stream
from .dataset import CLOUD_DIR, GROUPS, DatasetSetup, parse_setup
from .dataset_checks import SCANNER_POSITION_RANGE_M, SCANNER_ROTVEC_RANGE_RAD
from .dataset_repeats import REPEATS_RANGE, repeat_cloud_path
from .errors import DatasetError
from .files import read_json, read_toml
from .robots import load_robot
from .schema import Fields
from .transforms import homogeneous, matrix_from_rotation_vector

__all__ = [
    "CLOUD_UNITS",
    "DEFAULT_OPTIONS",
    "REPEAT_KEYS",
    "STATES",
    "ImportOptions",
    "dataset_cloud_path",
    "manifest_clouds",
    "read_manifest",
]

CLOUD_UNITS = ("m", "mm")
STATES = ("unloaded", "loaded")
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
    "repeat_clouds",
    "loaded_repeat_clouds",
)
# per block state, the optional list of further scans (repeats.csv, loaded_repeats.csv)
REPEAT_KEYS = {"unloaded": "repeat_clouds", "loaded": "loaded_repeat_clouds"}
OPTIONAL_TEST_KEYS = tuple(REPEAT_KEYS.values())  # and every window_<state>_s
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


DEFAULT_OPTIONS = ImportOptions()  # the manifest's own units and windows


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
        if key not in t and key not in OPTIONAL_TEST_KEYS and not key.startswith("window_"):
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
        out[REPEAT_KEYS[s]] = _repeat_clouds(
            f, base, t.get(REPEAT_KEYS[s], []), f"{where}.{REPEAT_KEYS[s]}", s
        )
    same = out["ft_unloaded"].resolve() == out["ft_loaded"].resolve()
    windows = [out[f"window_{s}_s"] for s in STATES]
    if same and (None in windows or windows[0] == windows[1]):
        # one stream through the whole test is fine, but only its windows tell the states apart: the
        # quietest window found would be one state's for both, and the load would read as zero
        raise f.error(
            f"{where}.ft_loaded",
            f"is the same stream as ft_unloaded ({out['ft_loaded']}): give each state its own window in it "
            "(window_unloaded_s and window_loaded_s, [start, end] in s), or each state its own file",
        )
    return out


def _repeat_clouds(f: Fields, base: Path, value, field: str, state: str) -> list[Path]:
    """Further scans of the test's ``state`` block, nothing moved in between (optional)."""
    low, high = REPEATS_RANGE
    if not isinstance(value, list) or not low <= len(value) <= high:
        raise f.error(
            field,
            f"must be a list of {low} to {high} cloud files, further scans of the {state} block at the "
            f"test's pose with nothing moved in between, got {value!r}",
        )
    return [_path(f, base, v, f"{field}[{k}]") for k, v in enumerate(value)]


def manifest_clouds(tests: list[dict]):
    """Every cloud a parsed manifest lists, as ``(index, test, state, k, path, field)``: per test
    and state its own scan (``k`` 0, field ``cloud_<state>``), then its repeats (``k`` 1, 2, ...)."""
    for i, t in enumerate(tests):
        for s in STATES:
            yield i, t, s, 0, t[f"cloud_{s}"], f"cloud_{s}"
            for k, path in enumerate(t[REPEAT_KEYS[s]], start=1):
                yield i, t, s, k, path, f"{REPEAT_KEYS[s]}[{k - 1}]"


def dataset_cloud_path(root: str | Path, test_id: str, state: str, repeat: int = 0) -> Path:
    """Where the import writes a cloud: the test's own scan of ``state`` (``repeat`` 0,
    ``clouds/<id>_<state>.ply``) or its repeat ``repeat`` (:func:`.dataset_repeats.repeat_cloud_path`)."""
    if repeat:
        return repeat_cloud_path(root, test_id, repeat, state)
    return Path(root) / CLOUD_DIR / f"{test_id}_{state}.ply"


def _clouds_once(f: Fields, tests: list[dict]) -> None:
    """Every cloud file is one scan, and one dataset file. A file listed twice would enter the
    noise floor as two scans that agree exactly, a floor too small and no error. Two clouds must
    not be written to one dataset file either: test ``X_loaded``'s repeat 1 and test ``X``'s
    loaded repeat 1 are both ``clouds/X_loaded_repeat1.ply``, and the second would replace the
    first in silence."""
    sources, files = {}, {}
    for i, t, s, k, path, name in manifest_clouds(tests):
        key, where = path.resolve(), f"tests[{i}].{name}"
        if key in sources:
            raise f.error(
                where,
                f"{path} is already {sources[key]}: each scan is its own file (a repeat scan "
                "listed as the test's own, or twice, would make the noise floor too small)",
            )
        sources[key] = where
        file = dataset_cloud_path("", t["id"], s, k).name
        if file in files:
            raise f.error(
                where,
                f"would be written to the dataset's {CLOUD_DIR}/{file}, as {files[file]} is: choose "
                "test ids that do not end in another test's id followed by '_loaded' or '_repeat'",
            )
        files[file] = where


def read_manifest(path: str | Path, options: ImportOptions = DEFAULT_OPTIONS) -> dict:
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
    _clouds_once(f, parsed)
    setup = _setup(f, base, data["setup"])
    load_robot(setup.robot)  # a known robot, or the valid names
    return {"setup": setup, "cloud_units": cloud_units, "torque_units": torque, "window_length": length,
            "tests": parsed}  # fmt: skip
