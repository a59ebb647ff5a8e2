"""Reading and writing the project's files: TOML and JSON with errors that name the file,
and atomic writes that never leave a half-written file behind.

Every reader raises the error class its caller names (a :class:`~vtestbed.errors.ScenarioError`
for scenario and campaign files, a :class:`~vtestbed.errors.DatasetError` for dataset files),
with the file's path in the message: a missing file, text that is not UTF-8, text that does not
parse (or nests too deeply to parse), or a top level that is not a table.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import tomllib
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np

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
    except RecursionError:  # the parser recurses per level: no file of ours nests that deep
        raise error(f"{path}: not a {what}: its arrays or tables nest too deeply to parse") from None


def read_json(path: str | Path, what: str, error: type[VtestbedError], kind: type = dict):
    """The JSON value (of type ``kind``) in a file, or ``error`` saying what is wrong with it."""
    path = Path(path)
    try:
        value = json.loads(_text(path, what, error))
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None
    except RecursionError:  # the decoder recurses per level: no file of ours nests that deep
        raise error(f"{path}: not a {what}: its arrays or objects nest too deeply to parse") from None
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


def strict(data):
    """``data`` with every NaN or infinite number replaced by None (JSON null) and numpy values made
    plain Python, so that it is strict JSON (RFC 8259 has no NaN); finite numbers are unchanged."""
    if isinstance(data, dict):
        return {k: strict(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [strict(v) for v in data]
    if isinstance(data, np.ndarray):
        return strict(data.tolist())
    if isinstance(data, bool | np.bool_):
        return bool(data)
    if isinstance(data, int | np.integer):
        return int(data)
    if isinstance(data, float | np.floating):
        return float(data) if math.isfinite(data) else None
    return data


def dumps(data, indent: int | None = 1, default=None) -> str:
    """Strict JSON text of ``data`` (NaN and infinities as null, see :func:`strict`)."""
    if default is not None:  # objects json cannot write: convert them first, then make them strict
        data = json.loads(json.dumps(data, default=default, allow_nan=True))
    return json.dumps(strict(data), indent=indent, allow_nan=False)


LOCK_FILE = ".vtestbed.lock"


@contextmanager
def folder_lock(folder: str | Path, what: str, error: type[VtestbedError]):
    """Hold an exclusive lock on ``folder`` (a ``flock`` on ``folder/.vtestbed.lock``) while writing it.

    Non-blocking: a second writer gets ``error`` naming the folder and the first writer's process
    id at once, instead of both writing and leaving duplicate rows. The lock goes with the process
    (a killed writer leaves no stale lock); the file stays, empty, so that no two processes ever
    lock two different files of the same name.
    """
    path = Path(folder) / LOCK_FILE
    fh = path.open("a+")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        pid = fh.read().strip() or "unknown"
        fh.close()
        raise error(
            f"{what} {folder} is being written by another process (pid {pid}); "
            "wait for it to finish, or choose another folder"
        ) from None
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(str(os.getpid()))
        fh.flush()
        yield path
    finally:
        fh.truncate(0)
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


def write_json_atomic(path: str | Path, data, indent: int = 1) -> Path:
    """Write ``data`` as strict JSON to ``path`` atomically (see :func:`write_atomic`, :func:`strict`)."""
    return write_atomic(path, lambda tmp: tmp.write_text(dumps(data, indent=indent)))


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: tmp.write_text(text))
