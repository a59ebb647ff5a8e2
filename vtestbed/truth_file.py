"""``truth.json`` written after every simulated test, in time linear in the tests.

``simulate`` rewrites the truth file after each finished test, so that an interrupted run keeps
the truth of every test it finished (its tests.csv row is written after it). Serialising the
whole table each time grew as N^2 (about 0.17 s over the paper scenario's 25 tests, of a 4 s
demo); here each test's record is made strict JSON text once (:func:`vtestbed.files.dumps`) and
the file is joined from those pieces. The text is the same JSON (same keys, same numbers) as
``dumps(truth)`` gives, indented the same way; no unit or frame conversion happens here.
:func:`check_recorded` checks the keys a reader of the file uses beside the true stiffness.
"""

from __future__ import annotations

import json
from pathlib import Path

from .errors import DatasetError
from .files import dumps, write_text_atomic

INDENT = 1  # as write_json_atomic writes every other JSON file of a dataset


class TruthFile:
    """The truth mapping of one dataset with its ``tests`` table serialised incrementally.

    Parameters
    ----------
    path : Path
        The file to (re)write.
    truth : dict
        Every key but ``tests`` is the header (written as given); ``truth["tests"]`` (a mapping
        test id -> record, possibly from a resumed file) are the tests already recorded.
    """

    def __init__(self, path: str | Path, truth: dict):
        self.path = Path(path)
        self.truth = truth
        self.truth.setdefault("tests", {})
        self._pieces = {tid: self._piece(tid, record) for tid, record in self.truth["tests"].items()}

    @staticmethod
    def _piece(tid: str, record: dict) -> str:
        # a record sits two levels deep (file -> tests -> id): its lines get two levels of indent
        text = dumps(record, indent=INDENT).replace("\n", "\n" + " " * (2 * INDENT))
        return f"{' ' * (2 * INDENT)}{json.dumps(tid)}: {text}"

    def add(self, tid: str, record: dict) -> Path:
        """Record test ``tid`` and rewrite the file atomically; returns its path."""
        self.truth["tests"][tid] = record
        self._pieces[tid] = self._piece(tid, record)
        return self.write()

    def text(self) -> str:
        """The file's JSON text: the header, then the tests in the order they were recorded."""
        header = dumps({k: v for k, v in self.truth.items() if k != "tests"}, indent=INDENT)
        tests = ",\n".join(self._pieces.values())
        table = f'{" " * INDENT}"tests": ' + (f"{{\n{tests}\n{' ' * INDENT}}}" if tests else "{}")
        if header == "{}":
            return f"{{\n{table}\n}}"
        return f"{header[:-2]},\n{table}\n}}"  # header ends with "\n}"

    def write(self) -> Path:
        """Rewrite the file atomically (a reader sees the old file or the new one)."""
        return write_text_atomic(self.path, self.text())


def check_recorded(truth: dict, path: Path) -> None:
    """The keys of a truth file beside the true stiffness that a reader uses (resume, the run
    report; :func:`vtestbed.comparison.read_truth` checks the stiffness too), each optional: ``tests`` a table of
    tables by test id, ``scenario`` and ``scenario_fingerprint`` text, ``joint_names`` a list of
    text, ``effects`` a list of tables with a text ``name``. A DatasetError names the key."""
    tests = truth.get("tests", {})
    if not isinstance(tests, dict):
        raise DatasetError(f"{path}: tests must be a table of the simulated tests by id, got {tests!r}")
    bad = next((tid for tid, record in tests.items() if not isinstance(record, dict)), None)
    if bad is not None:
        raise DatasetError(f"{path}: tests.{bad} must be a table of the test's truth, got {tests[bad]!r}")
    for key in ("scenario", "scenario_fingerprint"):
        if key in truth and not isinstance(truth[key], str):
            raise DatasetError(f"{path}: {key} must be text, got {truth[key]!r}")
    names = truth.get("joint_names", [])
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise DatasetError(f"{path}: joint_names must be a list of joint names (text), got {names!r}")
    effects = truth.get("effects", [])
    named = isinstance(effects, list) and all(
        isinstance(e, dict) and isinstance(e.get("name"), str) for e in effects
    )
    if not named:
        raise DatasetError(
            f"{path}: effects must be a list of the hidden effects, each a table with a text 'name', "
            f"got {effects!r}"
        )
