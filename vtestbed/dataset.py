"""Measurement datasets: what a lab records, in files a person can fill in by hand.

A dataset is a folder::

    setup.json     robot, angle convention, sensor mounting, block geometry (see DatasetSetup)
    tests.csv      one row per test: commanded pose, F/T readings unloaded and loaded, the two
                   point-cloud files; column ``group`` is ``identification`` or ``validation``
    clouds/*.ply   the scans, in the scanner frame, metres
    repeats.csv    optional: repeat scans of the unloaded block, one row per scan: ``test_id``,
                   ``repeat`` (1, 2, ...), ``cloud`` (path relative to the folder); the block and
                   the scanner did not move between them, so they measure the scanner's noise
    loaded_repeats.csv  optional: repeat scans of the loaded block, the same columns
                   (:mod:`vtestbed.dataset_repeats` reads and writes both)
    truth.json     only in simulated datasets; identification never reads it (the world writes
                   it, :mod:`vtestbed.comparison` reads it)

Units are in the column names (deg, N, Nm). Rows are appended as each test finishes, so an
interrupted simulation keeps every finished test (a test's repeat scans are written before its
tests.csv row, which marks it finished).
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import dataset_checks as checks
from .errors import DatasetError, SensorOverloadError
from .files import read_json
from .lab import WRENCH_AXES, ForceSensorSpec
from .transforms import homogeneous, matrix_from_rotation_vector, rotation_vector

FORMAT = "vtestbed-dataset/1"
SETUP_FILE, TESTS_FILE, TRUTH_FILE, CLOUD_DIR = "setup.json", "tests.csv", "truth.json", "clouds"
GROUPS = ("identification", "validation")
_UNIT = {"F": "N", "T": "Nm"}


def wrench_columns(prefix: str) -> list[str]:
    return [f"{prefix}_{axis}_{_UNIT[axis[0]]}" for axis in WRENCH_AXES]


def pose_columns(dof: int = 6) -> list[str]:
    return [f"q{i + 1}_deg" for i in range(dof)]


# The scanner's pose in the robot base frame (position, rotation vector). It only locates the
# block in the cloud (cloud.FitParams.crop_margin_m = 10 mm): the block's predicted position in
# the scanner frame must be right to a few mm, i.e. the pose to ~3 mm and ~0.3 deg at 0.6 m.
SCANNER_COLUMNS = [
    "scanner_x_m",
    "scanner_y_m",
    "scanner_z_m",
    "scanner_rx_rad",
    "scanner_ry_rad",
    "scanner_rz_rad",
]
COLUMNS = [
    "test_id",
    "group",
    *pose_columns(),
    *wrench_columns("unloaded"),
    *wrench_columns("loaded"),
    *SCANNER_COLUMNS,
    "cloud_unloaded",
    "cloud_loaded",
]


@dataclass(frozen=True)
class DatasetSetup:
    """The fixed part of an experiment (SI; 4x4 poses in the flange frame)."""

    robot: str
    angle_convention: str  # "dh" or "controller": how q*_deg in tests.csv are meant
    block_in_flange: np.ndarray  # (4, 4) block frame B (origin: the scanned corner)
    sensor_in_flange: np.ndarray  # (4, 4) force sensor measurement frame
    block_edge: float  # m
    sensor_name: str
    sensor_range: tuple[float, ...]  # |Fx|,|Fy|,|Fz| [N], |Tx|,|Ty|,|Tz| [N*m]
    notes: str = ""
    # What the flange carries above the sensor's measurement (plate, upper half): mass [kg] and
    # centre of mass [m] in the flange frame. The sensor does not read its weight, so the nominal
    # statics add it to the arm's (researcher.kinematics.ArmKinematics.for_setup); 0: none known.
    sensor_mount_mass: float = 0.0
    sensor_mount_com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # The std of one static F/T reading (Fx..Tz) [N, N*m]: the model's prediction carries it
    # (researcher.reading_noise); None: not known, as before 2026-12-02.
    sensor_noise_std: tuple[float, ...] | None = None
    # A mesh target (docs/targets.md): kind, file, sha256, extents_m, face_margin_m (the chamfer
    # width: > 0 makes the plane fits drop each face's boundary band), mass_kg; None: the plain box.
    target: dict | None = None

    @property
    def block_face_margin(self) -> float:
        """How far [m] the target's flat faces stop short of its bounding box's edges (0: a box)."""
        return float((self.target or {}).get("face_margin_m", 0.0))

    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "robot": self.robot,
            "angle_convention": self.angle_convention,
            "block_in_flange": np.asarray(self.block_in_flange).tolist(),
            "sensor_in_flange": np.asarray(self.sensor_in_flange).tolist(),
            "block_edge_m": self.block_edge,
            "force_sensor": {
                "name": self.sensor_name,
                "range_N_Nm": list(self.sensor_range),
                **(
                    {
                        "mount_side_mass_kg": self.sensor_mount_mass,
                        "mount_side_com_m": list(self.sensor_mount_com),
                    }
                    if self.sensor_mount_mass > 0
                    else {}
                ),
                **({} if self.sensor_noise_std is None else {"noise_std_N_Nm": list(self.sensor_noise_std)}),
            },
            "notes": self.notes,
            **({} if self.target is None else {"target": self.target}),
        }

    @property
    def sensor_spec(self) -> ForceSensorSpec:
        return ForceSensorSpec(name=self.sensor_name, wrench_range=tuple(self.sensor_range))


@dataclass(frozen=True)
class TestRecord:
    """One test as recorded: pose (in the setup's convention, deg), readings, cloud paths."""

    __test__ = False  # a dataset class, not a pytest test class

    test_id: str
    group: str
    q_deg: np.ndarray  # (6,)
    wrench_unloaded: np.ndarray  # (6,) N, N*m in the sensor frame
    wrench_loaded: np.ndarray  # (6,)
    scanner_pose: np.ndarray  # (4, 4) approximate pose of the scanner in the base frame
    cloud_unloaded: Path
    cloud_loaded: Path

    def row(self, root: Path) -> list:
        root = Path(root).resolve()
        rel = [str(Path(p).resolve().relative_to(root)) for p in (self.cloud_unloaded, self.cloud_loaded)]
        scanner = [*self.scanner_pose[:3, 3], *rotation_vector(self.scanner_pose[:3, :3])]
        numbers = [*self.q_deg, *self.wrench_unloaded, *self.wrench_loaded, *scanner]
        return [self.test_id, self.group, *[repr(float(v)) for v in numbers], *rel]  # round-trip exact


def scanner_pose_as_recorded(pose: np.ndarray) -> np.ndarray:
    """The scanner pose exactly as tests.csv stores it (position + rotation vector round trip)."""
    return homogeneous(matrix_from_rotation_vector(rotation_vector(pose[:3, :3])), pose[:3, 3])


SETUP_KEYS = ("format", "robot", "angle_convention", "block_in_flange", "sensor_in_flange", "block_edge_m",
              "force_sensor", "notes", "target")  # fmt: skip
TARGET_KEYS = ("kind", "file", "sha256", "extents_m", "face_margin_m", "mass_kg")  # target_mesh.setup_json


def read_setup(root: str | Path) -> DatasetSetup:
    """setup.json, each field checked (:mod:`vtestbed.dataset_checks`), or a DatasetError naming it."""
    path = Path(root) / SETUP_FILE
    return parse_setup(read_json(path, "dataset setup file", DatasetError), path)


def parse_setup(data: dict, path: str | Path) -> DatasetSetup:
    """A setup table (setup.json's keys) checked field by field; errors name ``path`` and the key."""
    for key in (
        "robot",
        "angle_convention",
        "block_in_flange",
        "sensor_in_flange",
        "block_edge_m",
        "force_sensor",
    ):
        if key not in data:
            raise DatasetError(f"{path}: key {key!r} is missing")
    unknown = sorted(set(data) - set(SETUP_KEYS))
    if unknown:  # a misspelt key would be ignored without a word (the scenario files refuse theirs too)
        raise DatasetError(f"{path}: unknown key {unknown[0]!r}; valid keys: {', '.join(SETUP_KEYS)}")
    if data["angle_convention"] not in ("dh", "controller"):
        raise DatasetError(
            f"{path}: angle_convention must be 'dh' or 'controller', got {data['angle_convention']!r}"
        )
    checks.dataset_format(data.get("format"), path, FORMAT)
    sensor_name, sensor_range = checks.force_sensor(data["force_sensor"], path)
    mount_mass, mount_com = checks.sensor_mount_side(data["force_sensor"], path)
    return DatasetSetup(
        robot=checks.robot_name(data["robot"], path),
        angle_convention=data["angle_convention"],
        block_in_flange=checks.rigid_transform(data["block_in_flange"], path, "block_in_flange"),
        sensor_in_flange=checks.rigid_transform(data["sensor_in_flange"], path, "sensor_in_flange"),
        block_edge=checks.number(data["block_edge_m"], path, "block_edge_m", *checks.BLOCK_EDGE_RANGE_M, "m"),
        sensor_name=sensor_name,
        sensor_range=sensor_range,
        notes=str(data.get("notes", "")),
        sensor_mount_mass=mount_mass,
        sensor_mount_com=mount_com,
        sensor_noise_std=checks.sensor_noise_std(data["force_sensor"], path, sensor_range),
        target=_target(data.get("target"), path),
    )


def _target(target, path) -> dict | None:
    """setup.json's optional ``target`` table; ``face_margin_m`` a length in [0, 0.1] m."""
    if target is None:
        return None
    if not isinstance(target, dict):
        raise DatasetError(f"{path}: target must be a table (kind, file, face_margin_m, ...), got {target!r}")
    if target.get("kind") != "mesh":
        raise DatasetError(f"{path}: target.kind must be 'mesh' (the one target besides the plain block, which "
                           f"has no target table), got {target.get('kind')!r}")  # fmt: skip
    unknown = sorted(set(target) - set(TARGET_KEYS))
    if unknown:
        raise DatasetError(
            f"{path}: target: unknown key {unknown[0]!r}; valid keys: {', '.join(TARGET_KEYS)}"
        )
    if "face_margin_m" in target:
        checks.number(target["face_margin_m"], path, "target.face_margin_m", 0.0, 0.1, "m")
    return target


def write_setup(root: str | Path, setup: DatasetSetup) -> None:
    root = Path(root)
    (root / CLOUD_DIR).mkdir(parents=True, exist_ok=True)
    (root / SETUP_FILE).write_text(json.dumps(setup.to_json(), indent=2))


class _RowWriter:
    """Appends rows to one CSV file of the dataset, flushed per row, so an interruption keeps them.

    Subclasses give the file name, the header, the rows already on disk and a row's key.
    """

    FILE, HEADER = "", ()

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.path = self.root / self.FILE
        new = not self.path.exists()
        self.done = set() if new else self._done_on_disk()
        self._file = self.path.open("a", newline="")
        self._csv = csv.writer(self._file)
        if new:
            self._csv.writerow(self.HEADER)
            self._file.flush()

    def _done_on_disk(self) -> set:
        raise NotImplementedError

    @staticmethod
    def _key(record):
        raise NotImplementedError

    def append(self, record) -> None:
        self._csv.writerow(record.row(self.root))
        self._file.flush()
        self.done.add(self._key(record))

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class TestWriter(_RowWriter):
    """Appends finished tests to tests.csv (flushed per row, so an interruption keeps them)."""

    __test__ = False  # a dataset class, not a pytest test class
    FILE, HEADER = TESTS_FILE, COLUMNS

    def _done_on_disk(self) -> set:
        return {r.test_id for r in read_tests(self.root, check_files=False)}

    @staticmethod
    def _key(record):
        return record.test_id


def _own_scans(scans: dict, clouds: tuple, test: tuple, where: str, row: dict) -> None:
    """Every loaded scan is one test's alone, and no scan is loaded in one place and unloaded in
    another: a test listed twice under two ids (or a loaded scan copied) would count its displacement
    twice, and a loaded scan given as unloaded measures no load. An unloaded scan may serve several
    tests at one pose (a lab that loads one pose at several tensions or hooks), not at two poses.
    ``scans``: :func:`~.dataset_checks.file_key` -> (state, test id, line, joint angles)."""
    tid, line, q = test
    for state, cloud in zip(("unloaded", "loaded"), clouds):
        key = checks.file_key(cloud)
        if key not in scans:
            scans[key] = (state, tid, line, q)
            continue
        first_state, first_tid, first_line, first_q = scans[key]
        if state == first_state == "unloaded" and np.allclose(q, first_q, rtol=0.0, atol=1e-9):
            continue
        why = ("that test's pose is another, and an unloaded scan serves only tests at its own pose"
               if state == first_state == "unloaded"
               else "each test needs its own scans of the block, unloaded and loaded")  # fmt: skip
        raise DatasetError(
            f"{where}: cloud_{state} {row[f'cloud_{state}']!r} is already cloud_{first_state} of test "
            f"{first_tid!r} (line {first_line}): {why} (e.g. {CLOUD_DIR}/{tid}_{state}.ply)"
        )


def read_tests(
    root: str | Path, check_files: bool = True, sensor_range=None, sensor_name: str = "force sensor"
) -> list[TestRecord]:
    """Read tests.csv; with ``check_files`` every referenced cloud must exist."""
    root = Path(root)
    path = root / TESTS_FILE
    rows = checks.read_csv(path, COLUMNS, "tests file")
    records, scans = [], {}
    for line, row in rows:
        where = f"{path} line {line} (test {row.get('test_id')!r})"
        if not row["test_id"].strip():
            raise DatasetError(f"{where}: test_id must be a non-empty name (e.g. T001)")
        q = checks.row_numbers(row, pose_columns(), where)
        wu = checks.row_numbers(row, wrench_columns("unloaded"), where)
        wl = checks.row_numbers(row, wrench_columns("loaded"), where)
        sc = checks.scanner_numbers(row, SCANNER_COLUMNS, where)
        if row["group"] not in GROUPS:
            raise DatasetError(f"{where}: group must be one of {', '.join(GROUPS)}, got {row['group']!r}")
        if sensor_range is not None:
            spec = ForceSensorSpec(name=sensor_name, wrench_range=tuple(sensor_range))
            for label, w in (("unloaded", wu), ("loaded", wl)):
                try:
                    spec.check(w, f"{where}: {label} wrench")
                except SensorOverloadError as exc:
                    raise DatasetError(str(exc)) from None
        tid = row["test_id"]
        clouds = tuple(
            checks.cloud_path(root, row[f"cloud_{k}"], where, f"cloud_{k}", f"{CLOUD_DIR}/{tid}_{k}.ply")
            for k in ("unloaded", "loaded")
        )
        if check_files:
            for c in clouds:
                if not c.is_file():
                    n_ply = len(list((root / CLOUD_DIR).glob("*.ply")))
                    raise DatasetError(
                        f"{where}: point cloud {c} is missing ({len(rows)} tests need {2 * len(rows)} clouds, "
                        f"{n_ply} found in {root / CLOUD_DIR})"
                    )
        _own_scans(scans, clouds, (tid, line, q), where, row)
        scanner_pose = homogeneous(matrix_from_rotation_vector(sc[3:]), sc[:3])
        records.append(TestRecord(row["test_id"], row["group"], q, wu, wl, scanner_pose, *clouds))
    ids = [r.test_id for r in records]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise DatasetError(f"{path}: duplicate test ids {dup}")
    return records
