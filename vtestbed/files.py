"""Reading and writing the project's files: TOML and JSON with errors that name the file,
and atomic writes that never leave a half-written file behind.

Every reader raises the error class its caller names (a :class:`~vtestbed.errors.ScenarioError`
for scenario and campaign files, a :class:`~vtestbed.errors.DatasetError` for dataset files),
with the file's path in the message: a missing file, text that is not UTF-8, text that does not
parse, or a top level that is not a table.
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Callable
from pathlib import Path

from .errors import VtestbedError


def _text(path: Path, what: str, error: type[VtestbedError]) -> str:
    if not path.is_file():
        raise error(
            f"{what} {path} is missing (the file does not exist)"
            if not path.exists()
            else f"{what} {path} is not a file"
        )
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}): is this the right {what}?") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror}") from None


def read_toml(path: str | Path, what: str, error: type[VtestbedError]) -> dict:
    """The table in a TOML file, or ``error`` saying what is wrong with it."""
    path = Path(path)
    try:
        return tomllib.loads(_text(path, what, error))
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from None


def read_json(path: str | Path, what: str, error: type[VtestbedError], kind: type = dict):
    """The JSON value (of type ``kind``) in a file, or ``error`` saying what is wrong with it."""
    path = Path(path)
    try:
        value = json.loads(_text(path, what, error))
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(value, kind):
        raise error(f"{path}: the {what} must hold a JSON {kind.__name__}, got {type(value).__name__}")
    return value


def write_atomic(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it onto ``path``.

    A reader (or a resumed run after a kill) sees the old file or the new one, never a part.
    """
    path = Path(path)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_json_atomic(path: str | Path, data, indent: int = 1) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (see :func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: tmp.write_text(json.dumps(data, indent=indent)))


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: tmp.write_text(text))
