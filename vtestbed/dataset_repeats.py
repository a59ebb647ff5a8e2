"""Repeat scans in a dataset: ``repeats.csv`` (the unloaded block) and ``loaded_repeats.csv``.

Both files are optional and have the same columns, one row per scan: ``test_id`` (a test of
tests.csv), ``repeat`` (1, 2, ...; the test's own scan is number 0) and ``cloud`` (a PLY file in
the scanner frame, metres, path relative to the dataset folder). The block, the scanner and the
load did not change between a test's scan and its repeats, so their differences are measurement
noise:

- ``repeats.csv``: further scans of the **unloaded** block. They give the model-free noise floor
  (:mod:`vtestbed.researcher.noise_floor`) and the mean unloaded frame
  (:mod:`vtestbed.researcher.scan_mean`).
- ``loaded_repeats.csv``: further scans of the **loaded** block, wire still tensioned. The mean
  scan displacements average them too, unless the creep check rejects them
  (:mod:`vtestbed.researcher.loaded_scatter`); they do not enter the floor (a block under load
  may creep between scans, which the unloaded repeats cannot do).

A simulation writes a test's repeats before its tests.csv row, which marks the test finished.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from . import dataset_checks as checks
from .dataset import CLOUD_DIR, TESTS_FILE, _RowWriter, read_tests
from .errors import DatasetError, UnknownNameError

__all__ = [
    "LOADED_REPEATS_FILE",
    "REPEATS_FILE",
    "REPEAT_COLUMNS",
    "REPEAT_FILES",
    "REPEATS_RANGE",
    "LoadedRepeatWriter",
    "RepeatRecord",
    "RepeatWriter",
    "read_repeats",
    "repeat_cloud_path",
]

REPEATS_FILE = "repeats.csv"
LOADED_REPEATS_FILE = "loaded_repeats.csv"
REPEAT_FILES = {"unloaded": REPEATS_FILE, "loaded": LOADED_REPEATS_FILE}  # block state -> file
REPEAT_COLUMNS = ["test_id", "repeat", "cloud"]
# further scans per test and block state, simulated ([scanner] repeats, loaded_repeats) or imported
# (a manifest's repeat_clouds, loaded_repeat_clouds); 0: none, 2 or more recommended for a floor
REPEATS_RANGE = (0, 20)
_CLOUD_SUFFIX = {"unloaded": "repeat", "loaded": "loaded_repeat"}


@dataclass(frozen=True)
class RepeatRecord:
    """One repeat scan of a test's block (same block pose, same scanner pose).

    Attributes
    ----------
    test_id : str
        The test (a ``test_id`` of tests.csv) whose block was scanned again.
    repeat : int
        The repeat's number, 1, 2, ... (the test's own scan is number 0).
    cloud : Path
        The scan (PLY, scanner frame); inside the dataset folder.
    """

    test_id: str
    repeat: int
    cloud: Path

    def row(self, root: Path) -> list:
        root = Path(root).resolve()
        return [self.test_id, str(self.repeat), str(Path(self.cloud).resolve().relative_to(root))]


def _state_file(state: str) -> str:
    if state not in REPEAT_FILES:
        raise UnknownNameError("block state", state, REPEAT_FILES)
    return REPEAT_FILES[state]


def repeat_cloud_path(root: str | Path, test_id: str, repeat: int, state: str = "unloaded") -> Path:
    """Where a simulation writes repeat ``repeat`` of ``test_id``: ``clouds/T001_repeat1.ply``
    (``state="loaded"``: ``clouds/T001_loaded_repeat1.ply``)."""
    _state_file(state)
    return Path(root) / CLOUD_DIR / f"{test_id}_{_CLOUD_SUFFIX[state]}{repeat}.ply"


def _read_repeat_rows(root: Path, tests, check_files: bool, state: str = "unloaded") -> list[RepeatRecord]:
    """The repeats file of ``state`` as records; ``tests`` (test id -> TestRecord of tests.csv) is
    what each row is checked against: a test it lists, a cloud that is not that test's own scan
    (None: neither)."""
    path = root / _state_file(state)
    rows = checks.read_csv(path, REPEAT_COLUMNS, "repeat scans file")
    records, first_line = [], {}
    seen = {} if tests is None else _other_repeats(root, state)  # one scan is never both states' repeat
    scans = {} if tests is None else {
        checks.file_key(path): (t.test_id, k)
        for t in tests.values() for k, path in (("unloaded", t.cloud_unloaded), ("loaded", t.cloud_loaded))
    }  # fmt: skip
    for line, row in rows:
        tid = row.get("test_id") or ""
        where = f"{path} line {line} (test {tid!r})"
        if tests is not None and tid not in tests:
            raise DatasetError(f"{where}: test_id {tid!r} is not a test of {root / TESTS_FILE}")
        text = (row.get("repeat") or "").strip()
        try:
            repeat = int(text)
        except ValueError:
            repeat = 0
        if repeat < 1:
            raise DatasetError(f"{where}: repeat must be an integer >= 1 (1, 2, ...), got {text!r}")
        if (tid, repeat) in first_line:
            raise DatasetError(
                f"{where}: repeat {repeat} of test {tid!r} is listed twice (first on line {first_line[tid, repeat]})"
            )
        first_line[tid, repeat] = line
        example = f"{CLOUD_DIR}/{tid}_{_CLOUD_SUFFIX[state]}{repeat}.ply"
        cloud = checks.cloud_path(root, row["cloud"], where, "cloud", example)
        if check_files and not cloud.is_file():
            raise DatasetError(f"{where}: cloud: point cloud {cloud} is missing")
        if tests is not None:
            own = {"unloaded": tests[tid].cloud_unloaded, "loaded": tests[tid].cloud_loaded}
            checks.not_own_scan(cloud, own, root / TESTS_FILE, where, row["cloud"], example, state)
            checks.not_a_test_scan(cloud, scans, root / TESTS_FILE, where, row["cloud"], example, state)
        checks.not_listed_twice(seen, cloud, (tid, repeat, line), where, row["cloud"], example, state)
        records.append(RepeatRecord(tid, repeat, cloud))
    return records


def _other_repeats(root: Path, state: str) -> dict:
    """The clouds of the other block state's repeats file, as :func:`.dataset_checks.not_listed_twice`
    keeps them (file key -> (test id, repeat, "line N of FILE")); {} without that file. Rows that
    do not parse are left to that file's own read, which names them."""
    other = "loaded" if state == "unloaded" else "unloaded"
    path = root / _state_file(other)
    if not path.is_file():
        return {}
    seen = {}
    for line, row in checks.read_csv(path, REPEAT_COLUMNS, "repeat scans file"):
        try:
            cloud = checks.cloud_path(root, row["cloud"], str(path), "cloud", "")
        except DatasetError:
            continue
        seen[checks.file_key(cloud)] = (row.get("test_id"), row.get("repeat"), f"{line} of {path}")
    return seen


def read_repeats(root: str | Path, check_files: bool = True, state: str = "unloaded") -> list[RepeatRecord]:
    """Read repeats.csv (``state="loaded"``: loaded_repeats.csv), or [] when the dataset has none.

    Parameters
    ----------
    root : str or Path
        The dataset folder.
    check_files : bool
        Every referenced cloud must exist.
    state : {"unloaded", "loaded"}
        Which block's repeat scans.

    Raises
    ------
    DatasetError
        Naming the file, the line and the field: a test_id not in tests.csv, a repeat that is not
        an integer >= 1, a (test_id, repeat) listed twice, a cloud outside the folder or missing,
        a cloud that is any test's own unloaded or loaded scan, or another repeat's (of either
        block state: repeats.csv and loaded_repeats.csv never share a scan).
    """
    root = Path(root)
    if not (root / _state_file(state)).is_file():
        return []
    tests = {r.test_id: r for r in read_tests(root, check_files=False)}
    return _read_repeat_rows(root, tests, check_files, state)


class RepeatWriter(_RowWriter):
    """Appends repeat scans to repeats.csv (flushed per row), like :class:`~.dataset.TestWriter`.

    ``done`` holds the (test_id, repeat) pairs already recorded. A simulation writes a test's
    repeats before its tests.csv row, so the file may name tests that tests.csv does not list yet.
    """

    FILE, HEADER, STATE = REPEATS_FILE, REPEAT_COLUMNS, "unloaded"

    def _done_on_disk(self) -> set:
        return {(r.test_id, r.repeat) for r in _read_repeat_rows(self.root, None, False, self.STATE)}

    @staticmethod
    def _key(record):
        return (record.test_id, record.repeat)


class LoadedRepeatWriter(RepeatWriter):
    """Appends repeat scans of the loaded block to loaded_repeats.csv, as :class:`RepeatWriter`."""

    FILE, STATE = LOADED_REPEATS_FILE, "loaded"
