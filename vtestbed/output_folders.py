"""What an output folder already holds, so that a command resumes only a folder of its own kind.

``simulate``, ``run`` and ``sweep`` complete an interrupted folder when rerun into it. Rerun into a
folder another command made, they would mix two results (a lab's tests taken as finished and a
partial truth.json; a campaign's report.html over a run's), so each refuses such a folder at
once, before writing anything, naming the folder and what it holds. Only file names are looked
at here (no file is parsed); the dataset-level checks (a tests.csv row that truth.json does not
record) are in :func:`vtestbed.experiment.simulate`.

The markers (the files each command writes first or always):

* ``vtestbed simulate``: ``truth.json`` (written before any other file of the dataset)
* a dataset without ``truth.json`` (``vtestbed dataset import``, or a lab's files copied in):
  ``setup.json``, ``tests.csv``, ``repeats.csv``, when a CSV file holds a row (a simulation
  killed before its first test by older code left a header only: nothing to mix, it may resume)
* ``vtestbed run``: ``result.json``, or its simulated ``dataset/truth.json``
* ``vtestbed sweep``: ``campaign.json``, ``trials/``
* ``vtestbed diagnose --out``: ``report.json``
"""

from __future__ import annotations

from pathlib import Path

from .errors import VtestbedError

SIMULATED, LAB, RUN, SWEEP, DIAGNOSIS = "simulated", "lab", "run", "sweep", "diagnosis"

# (kind, marker names, what the folder holds in words)
KINDS = (
    (SWEEP, ("campaign.json", "trials"), "a campaign's results (vtestbed sweep)"),
    (RUN, ("result.json", "dataset/truth.json"), "a run's results (vtestbed run)"),
    (DIAGNOSIS, ("report.json",), "a diagnosis (vtestbed diagnose --out)"),
    (SIMULATED, ("truth.json",), "a simulated dataset (vtestbed simulate)"),
    (
        LAB,
        ("setup.json", "tests.csv", "repeats.csv"),
        "a dataset without truth.json (vtestbed dataset import, or a lab's files)",
    ),
)


def folder_kinds(folder: str | Path) -> list[tuple[str, list[str], str]]:
    """The kinds of result ``folder`` holds: (kind, the marker names found, description) each.

    A dataset with truth.json is ``simulated`` only (its setup.json and tests.csv are its own).
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = []
    for kind, markers, words in KINDS:
        present = [folder / m for m in markers if (folder / m).exists()]
        if kind == LAB and ((folder / "truth.json").exists() or not any(map(_has_rows, present))):
            continue  # a simulated dataset, or an empty start (nothing in it to lose or to mix)
        if present:
            found.append((kind, [str(p.relative_to(folder)) for p in present], words))
    return found


def _has_rows(path: Path) -> bool:
    """A CSV file with a row below its header (setup.json alone records no measurement)."""
    if path.suffix != ".csv" or not path.is_file():
        return False
    with path.open("rb") as fh:
        return sum(1 for line in fh if line.strip()) > 1


def require_own_kind(
    folder: str | Path, allowed: tuple[str, ...], command: str, error: type[VtestbedError]
) -> None:
    """Raise ``error`` when ``folder`` holds a result of a kind not in ``allowed``.

    The message names the folder, the files that show what it holds, and the way out.
    """
    for kind, present, words in folder_kinds(folder):
        if kind not in allowed:
            shown = ", ".join(f"{m}/" if (Path(folder) / m).is_dir() else m for m in present)
            raise error(
                f"{folder} holds {words} ({shown}); '{command}' does not write into it, so as not to "
                "mix two results: choose a new or empty --out folder"
            )
