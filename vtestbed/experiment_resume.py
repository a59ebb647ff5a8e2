"""Resuming a simulated dataset folder: what :func:`vtestbed.experiment.simulate` keeps, refuses or redoes.

Part of the experiment orchestrator (it reads the truth file, as :mod:`vtestbed.experiment` does).

A simulation reruns into its folder to finish it (the tests it finished are kept). Before it
writes anything it checks that the folder is its own: no other command's result
(:mod:`vtestbed.output_folders`), a truth.json of the same scenario, and every row of tests.csv
recorded in that truth.json (a lab's rows, or rows of another simulation, would be taken as
finished and compared with a truth that does not cover them). A finished test whose point cloud
is gone is redone: its draws come from its own seeded stream
(:func:`vtestbed.world.physics.test_rng`), so the cloud comes back byte for byte.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from . import comparison
from .dataset import CLOUD_DIR, TESTS_FILE, TRUTH_FILE, read_tests
from .dataset_repeats import REPEAT_FILES
from .errors import DatasetError
from .output_folders import SIMULATED, require_own_kind
from .scenario import Scenario


def remove_dataset(out: Path) -> None:
    """Delete the files a simulation writes in ``out`` (and nothing else)."""
    for name in (TRUTH_FILE, TESTS_FILE, "setup.json", *REPEAT_FILES.values()):
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / CLOUD_DIR, ignore_errors=True)


def start_truth(out: Path, scenario: Scenario, rig, replace_stale: bool = False) -> dict:
    """The truth table to resume (``out``'s truth.json of the same scenario) or a new one.

    Raises DatasetError when ``out`` holds another command's result, or another scenario's
    dataset (replaced with ``replace_stale``; a dataset without truth.json never is: it may be
    a lab's only copy). Another scenario's start that finished no test (a simulation refused at
    its first test, since truth.json is written first) is replaced: it holds nothing to lose, and
    the rerun after fixing the scenario must not need a new folder.
    """
    require_own_kind(out, (SIMULATED,), "vtestbed simulate", DatasetError)
    truth_path = out / TRUTH_FILE
    if truth_path.exists():
        truth = comparison.read_truth(out)
        unfinished = not truth.get("tests") and not _has_rows(out / TESTS_FILE)
        if truth.get("scenario_fingerprint") != scenario.fingerprint and (replace_stale or unfinished):
            remove_dataset(out)
            return start_truth(out, scenario, rig)
        if truth.get("scenario_fingerprint") != scenario.fingerprint:
            raise DatasetError(
                f"{out} holds a dataset of another scenario (fingerprint {truth.get('scenario_fingerprint')} "
                f"!= {scenario.fingerprint}); choose a new output folder"
            )
        truth.setdefault("tests", {})
        return truth
    return {
        "scenario": scenario.name,
        "scenario_fingerprint": scenario.fingerprint,
        "seed": scenario.seed,
        "robot": scenario.robot_name,
        "joint_names": list(rig.robot.joint_names),
        "stiffness_true_Nm_per_rad": rig.truth.stiffness_true.tolist(),
        "effects": [e.to_dict() for e in scenario.effects if not e.is_null],
        "tests": {},
    }


def _has_rows(path: Path) -> bool:
    """tests.csv with a row below its header."""
    return path.is_file() and bool(read_tests(path.parent, check_files=False))


def check_finished(out: Path, truth: dict, test_ids: list[str]) -> None:
    """Refuse tests.csv rows that are not this simulation's: ids not in the scenario, or not in truth.json."""
    finished = (
        {r.test_id for r in read_tests(out, check_files=False)} if (out / TESTS_FILE).exists() else set()
    )
    foreign = sorted((finished - set(truth["tests"])) | (finished - set(test_ids)))
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise DatasetError(
            f"{out / TESTS_FILE} lists tests ({shown}) that {out / TRUTH_FILE} of scenario "
            f"{truth.get('scenario')!r} does not record: the folder mixes another dataset in; "
            "choose a new --out folder"
        )


def lost_clouds(out: Path, finished: set[str]) -> dict[str, list[Path]]:
    """The point clouds of finished tests that are no longer on disk, by test id (to redo them)."""
    lost = {}
    for tid in sorted(finished):
        paths = [out / CLOUD_DIR / f"{tid}_{state}.ply" for state in ("unloaded", "loaded")]
        missing = [p for p in paths if not p.is_file()]
        if missing:
            lost[tid] = missing
    return lost
