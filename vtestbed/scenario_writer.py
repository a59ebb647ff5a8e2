"""Scenario files written by ``discover``: the combined scenario of a round and the proposal.

One TOML writer (:func:`toml_text`): strings and keys quoted with JSON's escapes, which TOML's
basic strings share; floats written as their shortest exact round trip. Test poses in DH degrees,
tensions in N.
"""

from __future__ import annotations

import json

import numpy as np

from .design import discriminate as disc
from .errors import OutOfRangeError
from .scenario import Scenario


def _toml_key(k) -> str:
    k = str(k)
    return k if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k) else json.dumps(k)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))  # shortest exact round trip; inf and nan are valid TOML
    if isinstance(v, str):
        return json.dumps(v)  # ASCII, with TOML's basic-string escapes (\", \\, \n, \uXXXX)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise OutOfRangeError(f"cannot write {type(v).__name__} {v!r} to a scenario file")


def _toml_table(prefix: str, table: dict) -> list[str]:
    """Lines of one table: its values, then its sub-tables, then its arrays of tables."""
    plain = [(k, v) for k, v in table.items() if not _is_table(v) and not _is_tables(v)]
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in plain]
    out = ([f"[{prefix}]"] if prefix and (lines or not table) else []) + lines
    for k, v in table.items():
        name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
        if _is_table(v):
            out += ["", *_toml_table(name, v)]
        elif _is_tables(v):
            for item in v:
                out += ["", f"[[{name}]]", *(f"{_toml_key(a)} = {_toml_value(b)}" for a, b in item.items())]
    return out


def _is_table(v) -> bool:
    return isinstance(v, dict)


def _is_tables(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def toml_text(mapping: dict) -> str:
    """``mapping`` as a TOML document: the one scenario-file writer of ``discover`` (strings and
    keys quoted with JSON's escapes, which TOML's basic strings share; floats exact)."""
    return "\n".join(_toml_table("", mapping)) + "\n"


def _tests_tables(q, hooks, anchors, tensions) -> dict:
    """The ``[poses]`` (DH degrees) and ``[load]`` tables of a scenario file for these tests."""
    return {"poses": {"convention": "dh", "angles_deg": np.degrees(np.asarray(q, dtype=float)).tolist()},
            "load": {"hook": list(hooks), "anchor": list(anchors), "tension_N": [float(t) for t in tensions]}}  # fmt: skip


def scenario_text(scenario: Scenario, tests, name: str, description: str) -> str:
    """The scenario file of ``scenario`` with ``tests`` (CandidateTest) appended, in DH degrees.

    Every other table of the original file (lab, scanner, force sensor, identification,
    validation and the hidden world) is copied as it was.
    """
    raw = {k: v for k, v in scenario.raw.items() if k not in ("poses", "load", "campaign")}
    tests = list(tests)
    head = {"name": name, "description": description, "robot": scenario.robot_name, "seed": scenario.seed}
    body = _tests_tables(
        np.vstack([scenario.poses, *(t.q[None] for t in tests)]), [*scenario.load.hooks, *(t.hook for t in tests)],
        [*scenario.load.anchors, *(t.anchor for t in tests)], [*scenario.load.tensions, *(t.tension for t in tests)],
    )  # fmt: skip
    rest = {k: v for k, v in raw.items() if k not in head}
    return toml_text(head | body | rest)


def proposal_text(proposal: disc.Proposal, name: str, robot: str) -> str:
    """A scenario file of the extra tests alone (DH angles): the lab's to-do list."""
    c, ts = proposal.choice, proposal.tests
    description = (f"Extra tests that separate {', '.join(proposal.rivals)} ({proposal.reason}; "
                   f"{c.criterion}-optimal, separation {c.separation_before:.3g} -> {c.separation_after:.3g})")  # fmt: skip
    head = {"name": name, "description": description, "robot": robot}
    return toml_text(head | _tests_tables([t.q for t in ts], [t.hook for t in ts], [t.anchor for t in ts],
                                          [t.tension for t in ts]))  # fmt: skip
