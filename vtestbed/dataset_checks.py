"""Validation of the dataset files (setup.json, tests.csv, repeats.csv) as :mod:`vtestbed.dataset`
reads them.

Every check raises :class:`~vtestbed.errors.DatasetError` naming the file, the field (or the line)
and the valid values, so that a researcher who fills a dataset in by hand can fix it without a
traceback: a value of the wrong type or shape, a number that is not finite or outside its range,
a CSV row with too few or too many fields, text that is not UTF-8, a cloud path that leaves the
dataset folder.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from .errors import DatasetError

BLOCK_EDGE_RANGE_M = (1e-3, 1.0)  # a target block on a flange: 1 mm to 1 m
MOUNT_OFFSET_MAX_M = 2.0  # block or sensor frame within 2 m of the flange
SENSOR_RANGE_MAX = 1e6  # N or N*m: far above any 6-axis F/T sensor
SENSOR_MOUNT_MASS_RANGE_KG = (0.0, 100.0)  # what the flange carries above the measurement: plate, housing
# The scanner's rough pose in the robot base frame, per component. A scanner stands metres from the
# robot at most, so a position beyond 50 m is one in mm; a rotation vector's components lie within
# pi (4 allows a little past it), so a larger one is in degrees.
SCANNER_POSITION_RANGE_M = (-50.0, 50.0)
SCANNER_ROTVEC_RANGE_RAD = (-4.0, 4.0)


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def number(value, where: str, field: str, low: float, high: float, unit: str) -> float:
    """A finite number in ``[low, high]`` (JSON value), or a DatasetError naming ``field``."""
    if not _is_number(value) or not low <= value <= high:  # refuses NaN and inf
        raise DatasetError(f"{where}: {field} must be a number in [{low:g}, {high:g}] {unit}, got {value!r}")
    return float(value)


def string(value, where: str, field: str) -> str:
    if not isinstance(value, str) or not value:
        raise DatasetError(f"{where}: {field} must be a non-empty string, got {value!r}")
    return value


def dataset_format(value, where: str, current: str) -> None:
    """setup.json's ``format``: the version this vtestbed writes, or absent (a setup a lab wrote by
    hand). Another version's dataset may mean other units or columns: refused, not guessed."""
    if value is not None and value != current:
        raise DatasetError(
            f"{where}: format must be {current!r} (or absent, as in a setup written by hand), got {value!r}"
        )


def robot_name(value, where: str) -> str:
    """A robot vtestbed describes (a folder of models/ with a robot.toml), checked where the
    dataset names it, not later by the first reader that loads the robot."""
    from .robots import available_robots

    name, known = string(value, where, "robot"), available_robots()
    if name not in known:
        raise DatasetError(
            f"{where}: robot {name!r} is not a robot vtestbed describes; valid names: {', '.join(known)} "
            "(models/NAME/robot.toml; 'vtestbed robot import' adds one from a URDF)"
        )
    return name


def rigid_transform(value, where: str, field: str) -> np.ndarray:
    """A 4x4 rigid transform (rows of numbers, orthonormal rotation, last row 0 0 0 1, translation
    within :data:`MOUNT_OFFSET_MAX_M` of the flange) [m]."""
    ok = (
        isinstance(value, list)
        and len(value) == 4
        and all(isinstance(r, list) and len(r) == 4 and all(_is_number(v) for v in r) for r in value)
    )
    m = np.asarray(value, dtype=float) if ok else None
    if (
        m is None
        or not np.all(np.isfinite(m))
        or np.abs(m).max() > 1e3  # also keeps the products below from overflowing
        or not np.allclose(m[3], [0, 0, 0, 1])
        or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)
        or np.linalg.det(m[:3, :3]) < 0
        or np.linalg.norm(m[:3, 3]) > MOUNT_OFFSET_MAX_M
    ):
        raise DatasetError(
            f"{where}: {field} must be a 4x4 rigid transform (4 rows of 4 finite numbers, a rotation, "
            f"last row [0, 0, 0, 1], translation within {MOUNT_OFFSET_MAX_M:g} m of the flange), got {value!r}"
        )
    return m


def force_sensor(value, where: str) -> tuple[str, tuple[float, ...]]:
    """(name, range) from the ``force_sensor`` table: 6 positive finite numbers |Fx|..|Tz|."""
    if not isinstance(value, dict):
        raise DatasetError(
            f'{where}: force_sensor must be a table {{"name": ..., "range_N_Nm": [6 numbers]}}, got {value!r}'
        )
    name = value.get("name", "force sensor")
    if not isinstance(name, str):
        raise DatasetError(f"{where}: force_sensor.name must be a string, got {name!r}")
    rng = value.get("range_N_Nm")
    if (
        not isinstance(rng, list)
        or len(rng) != 6
        or not all(_is_number(v) and 0 < v <= SENSOR_RANGE_MAX for v in rng)
    ):
        raise DatasetError(
            f"{where}: force_sensor.range_N_Nm must be 6 numbers (Fx..Tz), each in (0, {SENSOR_RANGE_MAX:g}] "
            f"N or N*m (a NaN or zero range would switch the overload check off), got {rng!r}"
        )
    return name, tuple(float(v) for v in rng)


def sensor_mount_side(value: dict, where: str) -> tuple[float, tuple[float, float, float]]:
    """(mass [kg], centre of mass in the flange frame [m]) of what the flange carries above the
    sensor's measurement (its mounting plate and upper half): ``force_sensor.mount_side_mass_kg``
    (default 0: none) and ``force_sensor.mount_side_com_m`` (default the flange's centre)."""
    mass = number(value.get("mount_side_mass_kg", 0.0), where, "force_sensor.mount_side_mass_kg",
                  *SENSOR_MOUNT_MASS_RANGE_KG, "kg")  # fmt: skip
    com = value.get("mount_side_com_m", [0.0, 0.0, 0.0])
    if (
        not isinstance(com, list)
        or len(com) != 3
        or not all(_is_number(v) and abs(v) <= MOUNT_OFFSET_MAX_M for v in com)
    ):
        raise DatasetError(
            f"{where}: force_sensor.mount_side_com_m must be 3 numbers [m] in the flange frame, each within "
            f"{MOUNT_OFFSET_MAX_M:g} m of the flange, got {com!r}"
        )
    return mass, (float(com[0]), float(com[1]), float(com[2]))


def sensor_noise_std(value: dict, where: str, sensor_range) -> tuple[float, ...] | None:
    """The std of one static reading per axis (Fx..Tz) [N, N*m] from
    ``force_sensor.noise_std_N_Nm``: 6 numbers, each in [0, its axis's range]; None when absent
    (the reading noise is then not known and no model term carries it)."""
    std = value.get("noise_std_N_Nm")
    if std is None:
        return None
    if (
        not isinstance(std, list)
        or len(std) != 6
        or not all(_is_number(v) and 0 <= v <= r for v, r in zip(std, sensor_range))
    ):
        raise DatasetError(
            f"{where}: force_sensor.noise_std_N_Nm must be 6 numbers (Fx..Tz, the std of one static reading "
            f"[N, N*m]), each in [0, its axis's range_N_Nm {list(sensor_range)}], got {std!r}"
        )
    return tuple(float(v) for v in std)


# ---------------------------------------------------------------------- CSV files
def read_csv(path: Path, columns: list[str], what: str) -> list[tuple[int, dict]]:
    """The rows of a dataset CSV file as (line number, row); every row has exactly the header's
    fields, the header holds every column of ``columns``."""
    if not path.is_file():
        raise DatasetError(f"{what} {path} is missing")
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's byte order mark too
            reader = csv.reader(fh)
            header = next(reader, None) or []
            missing = [c for c in columns if c not in header]
            if missing:
                has = ", ".join(header)[:200] or "nothing (an empty file)"
                raise DatasetError(
                    f"{path}: columns missing: {', '.join(missing)} (columns: {', '.join(columns)}; "
                    f"comma-separated; the file's header has {has})"
                )
            twice = sorted({c for c in columns if header.count(c) > 1})  # the columns read; extras may repeat
            if twice:  # the last of two columns would win without a word
                raise DatasetError(
                    f"{path}: column {twice[0]!r} appears {header.count(twice[0])} times in the header; "
                    "each column once (columns: " + ", ".join(columns) + ")"
                )
            rows = []
            for fields in reader:
                line = reader.line_num
                if not fields:  # a blank line
                    continue
                if len(fields) != len(header):
                    raise DatasetError(
                        f"{path} line {line}: {len(fields)} fields, the header has {len(header)} "
                        f"(a row cut short or a stray comma?)"
                    )
                rows.append((line, dict(zip(header, fields))))
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not UTF-8 text (byte {exc.start}): is this the right {what}?") from None
    except csv.Error as exc:
        raise DatasetError(f"{path}: not a valid CSV file: {exc}") from None
    return rows


def row_numbers(row: dict, columns: list[str], where: str) -> np.ndarray:
    """The finite numbers in ``columns`` of a CSV row."""
    values = []
    for c in columns:
        try:
            value = float(row[c])
        except ValueError:
            raise DatasetError(
                f"{where}: {c} must be a number (pose, wrench and scanner columns must be numbers), "
                f"got {row[c]!r}"
            ) from None
        if not math.isfinite(value):
            raise DatasetError(
                f"{where}: {c} = {row[c]!r}: pose, wrench and scanner columns must be finite numbers"
            )
        values.append(value)
    return np.array(values)


def scanner_numbers(row: dict, columns: list[str], where: str) -> np.ndarray:
    """The scanner pose's six columns of a CSV row (``x, y, z`` in m, then the rotation vector in
    rad), each finite and in :data:`SCANNER_POSITION_RANGE_M` or :data:`SCANNER_ROTVEC_RANGE_RAD`."""
    values = row_numbers(row, columns, where)
    for i, (c, value) in enumerate(zip(columns, values, strict=True)):
        (low, high), hint = (
            (SCANNER_POSITION_RANGE_M, "m, not mm") if i < 3 else (SCANNER_ROTVEC_RANGE_RAD, "rad, not deg")
        )
        if not low <= value <= high:
            raise DatasetError(
                f"{where}: {c} = {row[c]!r} is outside [{low:g}, {high:g}]: the scanner's pose in the "
                f"robot base frame is in {hint}"
            )
    return values


def cloud_path(root: Path, text: str, where: str, field: str, example: str) -> Path:
    """``root / text`` if ``text`` is a relative path that stays inside the dataset folder."""
    rel = (text or "").strip()
    path = root / rel
    if not rel or "\0" in rel or Path(rel).is_absolute() or not path.resolve().is_relative_to(root.resolve()):
        raise DatasetError(
            f"{where}: {field} {rel!r} must be a path inside the dataset folder {root}, relative to it "
            f"(e.g. {example})"
        )
    return path


def _same_file(a: Path, b: Path) -> bool:
    return file_key(a) == file_key(b)


def not_own_scan(
    cloud: Path, own: dict, tests_file: Path, where: str, text: str, example: str, block: str = "unloaded"
) -> None:
    """A repeat scan (``cloud``) of the ``block`` (unloaded or loaded) must not be its test's own
    scan (``own``: state -> path): the unloaded scan would enter the noise floor as an exact zero,
    the loaded one as the load's displacement (a floor 10-40 times too large), and neither looks
    wrong as a number."""
    for state, path in own.items():
        if _same_file(cloud, path):
            raise DatasetError(
                f"{where}: cloud {text!r} is the test's own {state} scan (cloud_{state} in {tests_file}); "
                f"a repeat must be another scan of the {block} block, in its own file (e.g. {example})"
            )


def not_a_test_scan(
    cloud: Path, scans: dict, tests_file: Path, where: str, text: str, example: str, block: str = "unloaded"
) -> None:
    """A repeat scan (``cloud``) must not be any test's own scan (``scans``: :func:`file_key` ->
    (test id, state)): another test's scan of the block at another pose, or under load, would enter
    the noise floor as if it were this test's repeat."""
    hit = scans.get(file_key(cloud))
    if hit is not None:
        tid, state = hit
        raise DatasetError(
            f"{where}: cloud {text!r} is the {state} scan of test {tid!r} (cloud_{state} in {tests_file}); a "
            f"repeat must be another scan of its own test's {block} block, in its own file (e.g. {example})"
        )


def not_listed_twice(
    seen: dict, cloud: Path, row: tuple, where: str, text: str, example: str, block: str = "unloaded"
) -> None:
    """A repeat scan (``cloud``; ``row``: its test id, repeat and line) must not be another
    repeat's file too (``seen``: the files so far -> their row): two repeats of one scan enter the
    noise floor as an exact zero, which shrinks it without looking wrong as a number."""
    key = file_key(cloud)
    if key in seen:
        tid, repeat, line = seen[key]
        raise DatasetError(
            f"{where}: cloud {text!r} is already repeat {repeat} of test {tid!r} (line {line}); every "
            f"repeat must be its own scan of the {block} block, in its own file (e.g. {example})"
        )
    seen[key] = row


def file_key(path: Path):
    """What identifies a file on disk (device and inode: a hard link is the same file; a missing
    file: its resolved path)."""
    try:
        stat = path.stat()  # a hard link to the same scan is the same file
        return stat.st_dev, stat.st_ino
    except OSError:  # missing: the file checks name it
        return path.resolve()
