"""Loading a result folder: which kind it is (run, campaign, diagnosis, discovery) and what it holds.

A folder is recognised by the files the commands write:

* ``vtestbed run`` / ``demo``: ``result.json`` (with ``joints`` and ``table5``) and ``dataset/``;
* ``vtestbed sweep``: ``campaign.json`` and ``trials/part-*.parquet``;
* ``vtestbed diagnose --out``: ``report.json`` with a ``detect`` table (its ``dataset`` field
  names the dataset it diagnosed);
* ``vtestbed discover --out``: ``discover.json`` (its rounds' diagnoses in ``round<k>/diagnose``).

Anything else is refused with a :class:`ReportError` that lists the files looked for.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import VtestbedError
from ..files import read_json

KINDS = ("run", "campaign", "diagnosis", "discovery")
RUN_FILE = "result.json"
CAMPAIGN_FILE = "campaign.json"
DIAGNOSIS_FILE = "report.json"
DISCOVERY_FILE = "discover.json"
LOOKED_FOR = (
    f"{RUN_FILE} (vtestbed run), {CAMPAIGN_FILE} with trials/*.parquet (vtestbed sweep), "
    f"{DIAGNOSIS_FILE} with a 'detect' table (vtestbed diagnose --out), {DISCOVERY_FILE} (vtestbed discover --out)"
)


class ReportError(VtestbedError, ValueError):
    """A folder that holds no result a report can be made of, or a malformed result file."""


@dataclass
class ResultFolder:
    """One result folder, loaded.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    root : Path
        The folder.
    data : dict
        ``result.json`` (run), ``campaign.json`` (campaign), ``report.json`` (diagnosis) or
        ``discover.json`` (discovery).
    dataset : Path or None
        The dataset folder the result was computed from, if it is on disk (not for a campaign).
    trials : pandas.DataFrame or None
        One row per trial (campaign only).
    """

    kind: str
    root: Path
    data: dict
    dataset: Path | None = None
    trials: object = None
    extra: dict = field(default_factory=dict)


def _require(data: dict, path: Path, keys: tuple[str, ...]) -> dict:
    missing = [k for k in keys if k not in data]
    if missing:
        raise ReportError(f"{path}: missing field {missing[0]!r}; a {path.name} holds {', '.join(keys)}")
    return data


# What the run sections read from result.json (vtestbed/reports/sections_run.py and figures.py)
RUN_FIELDS = ("scenario", "seed", "method", "n_tests", "joints", "table5", "identification", "convergence",
              "validation")  # fmt: skip
JOINT_FIELDS = ("name", "k_true", "k_est", "k_std", "rel_err")
TABLE5_FIELDS = ("first_n", "min", "max", "mean")
IDENTIFICATION_FIELDS = ("component_std", "condition_number", "chi2_reduced")
CONVERGENCE_FIELDS = ("n", "stiffness", "stiffness_std")
VALIDATION_FIELDS = ("test_id", "measured", "predicted", "rel_err_translation", "rel_err_rotation")


def _is_number(value, none_ok: bool = False) -> bool:
    if value is None:
        return none_ok
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _bad(path: Path, where: str, what: str) -> ReportError:
    return ReportError(f"{path}: field {where!r} {what}")


def _numbers(value, path: Path, where: str, length: int | None = None, none_ok: bool = False) -> None:
    if not isinstance(value, list) or not all(_is_number(v, none_ok) for v in value):
        raise _bad(path, where, "must be a list of numbers")
    if length is not None and len(value) != length:
        raise _bad(path, where, f"must hold {length} values, one per joint or component; got {len(value)}")


def _table(value, path: Path, where: str, keys: tuple[str, ...]) -> dict:
    if not isinstance(value, dict):
        raise _bad(path, where, f"must be a table holding {', '.join(keys)}; got {type(value).__name__}")
    missing = [k for k in keys if k not in value]
    if missing:
        raise ReportError(f"{path}: missing field '{where}.{missing[0]}'; {where} holds {', '.join(keys)}")
    return value


def check_run(data: dict, path: Path) -> dict:
    """``data`` (a run's ``result.json``) if it holds every field the run report reads, in its shape.

    Raises
    ------
    ReportError
        Naming the file and the first missing or malformed field (``joints[2].k_est``, ...).
    """
    _require(data, path, RUN_FIELDS)
    if not _is_number(data["n_tests"]) or not _is_number(data["seed"]):
        raise _bad(path, "n_tests" if not _is_number(data["n_tests"]) else "seed", "must be a number")
    if not isinstance(data["method"], str) or not isinstance(data["scenario"], str):
        raise _bad(path, "method" if not isinstance(data["method"], str) else "scenario", "must be a string")
    joints = data["joints"]
    if not isinstance(joints, list) or not joints:
        raise _bad(path, "joints", "must be a non-empty list of joint rows")
    for i, row in enumerate(joints):
        where = f"joints[{i}]"
        if not isinstance(row, dict):
            raise _bad(
                path, where, f"must be a table holding {', '.join(JOINT_FIELDS)}; got {type(row).__name__}"
            )
        _table(row, path, where, JOINT_FIELDS)
        if not isinstance(row["name"], str):
            raise _bad(path, f"{where}.name", "must be a string")
        for key in JOINT_FIELDS[1:]:  # null: a NaN written as strict JSON (not for the truth)
            if not _is_number(row[key], none_ok=key != "k_true"):
                raise _bad(path, f"{where}.{key}", f"must be a number, got {row[key]!r}")
    n = len(joints)
    t5 = _table(data["table5"], path, "table5", TABLE5_FIELDS)
    for key in TABLE5_FIELDS[1:]:
        _numbers(t5[key], path, f"table5.{key}", n, none_ok=True)
    if not _is_number(t5["first_n"]):
        raise _bad(path, "table5.first_n", "must be a number")
    ident = _table(data["identification"], path, "identification", IDENTIFICATION_FIELDS)
    _numbers(ident["component_std"], path, "identification.component_std", 6, none_ok=True)
    for key in IDENTIFICATION_FIELDS[1:]:
        if not _is_number(ident[key], none_ok=True):
            raise _bad(path, f"identification.{key}", f"must be a number, got {ident[key]!r}")
    conv = _table(data["convergence"], path, "convergence", CONVERGENCE_FIELDS)
    _numbers(conv["n"], path, "convergence.n")
    for key in ("stiffness", "stiffness_std"):
        rows = conv[key]
        if not isinstance(rows, list) or len(rows) != len(conv["n"]):
            raise _bad(path, f"convergence.{key}", "must hold one row per entry of convergence.n")
        for i, row in enumerate(rows):
            _numbers(row, path, f"convergence.{key}[{i}]", n, none_ok=True)
    if not isinstance(data["validation"], list):
        raise _bad(path, "validation", "must be a list of validation rows")
    for i, row in enumerate(data["validation"]):
        row = _table(row, path, f"validation[{i}]", VALIDATION_FIELDS)
        for key in ("measured", "predicted"):
            _numbers(row[key], path, f"validation[{i}].{key}", 6)
    return data


# What the diagnosis sections read from report.json, and the JSON type of each (sections_diagnosis.py)
DIAGNOSIS_FIELDS = {"dataset": str, "alpha": float, "noise_floor": dict, "detect": dict, "named": list,
                    "rounds": list, "baseline": dict, "model": dict, "validation": dict,
                    "identification_fit": dict}  # fmt: skip
CAMPAIGN_FIELDS = {"scenario": str, "joint_names": list, "campaign": dict}
# ... and from discover.json (sections_discovery.py)
DISCOVERY_FIELDS = {"scenario": str, "seed": float, "alpha": float, "named_before": list, "rounds": list}
_JSON_NAMES = {str: "a string", float: "a number", dict: "a table", list: "a list"}


def _json_value(value) -> str:
    """``value`` as JSON would show it, with its JSON type (for an error message)."""
    if value is None:
        return "null"
    if isinstance(value, bool):  # before the numbers: a bool is an int in Python, not in JSON
        kind = "a boolean"
    else:
        kind = (
            "a number"
            if _is_number(value)
            else next((name for t, name in _JSON_NAMES.items() if isinstance(value, t)), "a value")
        )
    text = json.dumps(value)
    return f"{kind} {text[:40]}{'...' if len(text) > 40 else ''}"


def _typed(data: dict, path: Path, fields: dict) -> dict:
    """``data`` if it holds every key of ``fields`` with a value of its JSON type (the first wrong
    one is named); a number may be an int, and lists of names must hold strings."""
    _require(data, path, tuple(fields))
    for key, kind in fields.items():
        value = data[key]
        ok = _is_number(value) if kind is float else isinstance(value, kind)
        if not ok:
            raise _bad(path, key, f"must be {_JSON_NAMES[kind]}, got {_json_value(value)}")
    for key in ("named", "named_before", "joint_names"):
        if key in fields and not all(isinstance(v, str) for v in data[key]):
            raise _bad(path, key, "must be a list of strings")
    if "rounds" in fields and not all(isinstance(r, dict) for r in data["rounds"]):
        raise _bad(path, "rounds", "must be a list of tables, one per round")
    return data


def detect_kind(root: str | Path) -> str:
    """The kind of result in ``root``: one of :data:`KINDS`.

    Raises
    ------
    ReportError
        ``root`` is not a folder, or holds none of the files listed in ``LOOKED_FOR``.
    """
    root = Path(root)
    if not root.is_dir():
        raise ReportError(f"{root}: not a folder; give a result folder holding {LOOKED_FOR}")
    if (root / CAMPAIGN_FILE).is_file():
        return "campaign"
    if (root / RUN_FILE).is_file():
        return "run"
    if (root / DISCOVERY_FILE).is_file():
        return "discovery"
    if (root / DIAGNOSIS_FILE).is_file():
        data = read_json(root / DIAGNOSIS_FILE, "diagnosis report", ReportError)
        if "detect" in data:
            return "diagnosis"
    raise ReportError(f"{root} holds no result: looked for {LOOKED_FOR}")


def load_result(root: str | Path) -> ResultFolder:
    """Detect the kind of ``root`` and load its files (see the module docstring)."""
    root = Path(root)
    kind = detect_kind(root)
    if kind == "run":
        path = root / RUN_FILE
        data = check_run(read_json(path, "run result", ReportError), path)
        dataset = root / "dataset"
        return ResultFolder(kind, root, data, dataset if (dataset / "tests.csv").is_file() else None)
    if kind == "campaign":
        from ..campaigns.store import results

        path = root / CAMPAIGN_FILE
        data = _typed(read_json(path, "campaign manifest", ReportError), path, CAMPAIGN_FIELDS)
        trials = results(root)
        if trials.empty:
            raise ReportError(
                f"{root}: the campaign has no finished trial in {root / 'trials'} (part-*.parquet); "
                "run 'vtestbed sweep' into it first"
            )
        return ResultFolder(kind, root, data, None, trials)
    if kind == "discovery":
        path = root / DISCOVERY_FILE
        return ResultFolder(
            kind, root, _typed(read_json(path, "discover result", ReportError), path, DISCOVERY_FIELDS)
        )
    path = root / DIAGNOSIS_FILE
    data = _typed(read_json(path, "diagnosis report", ReportError), path, DIAGNOSIS_FIELDS)
    # a relative path was written from another working directory: `diagnose DATA --out DATA/diagnose`
    # is the usual layout, so the folder above is the next guess
    found = [d for d in (Path(data["dataset"]), root.parent) if (d / "tests.csv").is_file()]
    return ResultFolder(kind, root, data, found[0] if found else None)
