"""The bad-input tables of docs/errors.md, read as data, and the helpers that produce each row's
bad input for real (issue 13): a library call that must raise a VtestbedError, or the real
``vtestbed`` command (``vtestbed.cli.main.main`` in-process) that must exit 2 with one error line.

A table is one whose header is ``| id | bad input | message |``; the message is the row's first
backquoted text. In a documented message ``DIR`` and ``FILE`` stand for a path, ``...`` for any
text and a lone ``N`` for a whole number (or the unit N): :func:`pattern` turns them into
wildcards, everything else must match exactly (the whole message or error line).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from vtestbed.errors import VtestbedError

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "errors.md"
HEADER = ("id", "bad input", "message")


@dataclass(frozen=True)
class Row:
    key: str
    section: str  # the "## ..." heading above the table
    bad_input: str
    message: str  # the documented message, with placeholders


def _cells(line: str) -> list[str]:
    """The cells of a Markdown table row (``\\|`` is a literal bar inside a cell)."""
    cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))
    return [c.strip().replace("\\|", "|") for c in cells]


def read_rows(path: Path = DOC) -> list[Row]:
    """Every row of every ``| id | bad input | message |`` table in ``path``, in order."""
    rows, section, in_table = [], "", False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            section, in_table = line[3:].strip(), False
        if not line.startswith("|"):
            in_table = False
            continue
        cells = _cells(line)
        if tuple(c.lower() for c in cells) == HEADER:
            in_table = True
        elif in_table and not set("".join(cells)) <= set("-: "):
            assert len(cells) == 3, f"docs/errors.md: a row of {len(cells)} cells: {line}"
            found = re.search(r"`([^`]*)`", cells[2])
            assert found, f"docs/errors.md: row {cells[0]!r} has no `message`"
            rows.append(Row(cells[0].strip("`"), section, cells[1], found.group(1)))
    return rows


def pattern(message: str) -> re.Pattern:
    """The documented ``message`` as a regular expression matching the whole actual message."""
    text = re.escape(message).replace(r"\.\.\.", ".*?")
    text = re.sub(r"\b(?:DIR|FILE)\b", ".+?", text)
    text = re.sub(r"\bN\b", r"(?:N|\\d+)", text)
    return re.compile(text, re.DOTALL)


def section_rows(*sections: str) -> dict[str, Row]:
    """The documented rows of the tables under these headings, by id."""
    return {r.key: r for r in read_rows() if r.section in sections}


@dataclass
class Ctx:
    """What a case needs: a fresh folder and pytest's captured output."""

    tmp: Path
    capsys: object
    shared: Path | None = None  # a read-only input some modules share (copy it before editing)


Case = Callable[[Ctx], str]


def refused(call: Callable[[], object], kind: type[VtestbedError] = VtestbedError) -> str:
    """The message of the error that ``call()`` must raise (a VtestbedError subclass)."""
    try:
        call()
    except VtestbedError as exc:
        assert isinstance(exc, kind), f"{type(exc).__name__} is not a {kind.__name__}: {exc}"
        return str(exc)
    pytest.fail("no error: the bad input was accepted")


def cli(ctx: Ctx, argv: list, code: int = 2) -> str:
    """The one error line of the real ``vtestbed argv`` (run in-process): exit ``code``, no
    traceback, nothing on stdout but what argparse or the command printed before."""
    from vtestbed.cli.main import main

    ctx.capsys.readouterr()
    try:
        got = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse: usage line + error line
        got = exc.code
    err = ctx.capsys.readouterr().err
    lines = err.strip().splitlines()
    assert got == code, err
    assert "Traceback" not in err, err
    errors = [line for line in lines if ": error: " in line]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


def check(row: Row, actual: str) -> None:
    assert pattern(row.message).fullmatch(actual), (
        f"docs/errors.md row {row.key!r} says\n  {row.message}\nthe code says\n  {actual}"
    )


def run_row(cases: dict[str, Case], rows: dict[str, Row], key: str, ctx: Ctx) -> None:
    """Check one id: documented and with a case, and the case's message is the documented one."""
    assert key in rows, f"case {key!r} has no row in docs/errors.md (add one, or drop the case)"
    assert key in cases, f"docs/errors.md row {key!r} has no case in the tests (add one)"
    check(rows[key], cases[key](ctx))
