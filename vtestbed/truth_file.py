"""``truth.json`` written after every simulated test, in time linear in the tests.

``simulate`` rewrites the truth file after each finished test, so that an interrupted run keeps
the truth of every test it finished (its tests.csv row is written after it). Serialising the
whole table each time grew as N^2 (about 0.17 s over the paper scenario's 25 tests, of a 4 s
demo); here each test's record is made strict JSON text once (:func:`vtestbed.files.dumps`) and
the file is joined from those pieces. The text is the same JSON (same keys, same numbers) as
``dumps(truth)`` gives, indented the same way; no unit or frame conversion happens here.
"""

from __future__ import annotations

import json
from pathlib import Path

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
