"""Argument helpers shared by the command groups: comma-separated numbers and poses, with errors
that name the option and the valid form (exit code 2 through :func:`vtestbed.cli.main.main`)."""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..errors import OutOfRangeError

DEFAULT_POSE_DEG = "0,-60,-20,30,50,45"


def parse_numbers(text: str, field: str, count: int, unit: str) -> np.ndarray:
    """Parse ``"a,b,c"`` into ``count`` finite numbers, with an error naming ``field``."""
    try:
        values = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise OutOfRangeError(
            f"{field} must be {count} comma-separated numbers [{unit}], got {text!r}"
        ) from None
    if values.size != count or not np.all(np.isfinite(values)):
        raise OutOfRangeError(f"{field} must be {count} finite numbers [{unit}], got {text!r}")
    return values


def parse_angles_deg(text: str, field: str, count: int = 6) -> np.ndarray:
    """Parse ``"a,b,c,d,e,f"`` (degrees) into radians, with a clear error."""
    return np.radians(parse_numbers(text, field, count, "deg"))


def pose_from_args(robot, args) -> np.ndarray:
    """DH pose [rad] from ``--q-deg`` (DH) or ``--controller-deg`` (KUKA A1..A6), inside the joint
    limits (an error names the option, the joint and its limits)."""
    if getattr(args, "controller_deg", None):
        q = robot.controller_to_dh(parse_angles_deg(args.controller_deg, "--controller-deg", robot.dof))
        return robot.check_pose(q, field="--controller-deg")
    return robot.check_pose(parse_angles_deg(args.q_deg, "--q-deg", robot.dof), field="--q-deg")


def runnable_pose(robot, lab, args) -> np.ndarray:
    """:func:`pose_from_args`, away from singularities at the lab's block (as ``simulate`` checks a
    test): ``load`` and ``scan`` print a test's numbers, and at a singular pose they mean nothing."""
    q = pose_from_args(robot, args)
    field = "--controller-deg" if getattr(args, "controller_deg", None) else "--q-deg"
    robot.check_not_singular(q, lab.block_in_flange[:3, 3], field=field)
    return q


NEGATIVE_HINT = "negative first value: --q-deg=-10,20,... or --q-deg -10,20,..."


def add_pose_arguments(parser: argparse.ArgumentParser) -> None:
    # one pose, in one convention: given both, one would silently win over the other
    angles = parser.add_mutually_exclusive_group()
    angles.add_argument(
        "--q-deg",
        default=DEFAULT_POSE_DEG,
        help=f"DH joint angles in degrees (default %(default)s; {NEGATIVE_HINT})",
    )
    angles.add_argument(
        "--controller-deg",
        help="controller angles in degrees (KUKA A1..A6, an imported robot's URDF joint positions; instead of --q-deg)",
    )


# ---------------------------------------------------------------------- option types
# argparse calls these on the option's text: a bad value exits 2 with one line naming the option
# (argparse adds the usage line), before any work is done.
def integer(low: int, high: int | None = None):
    """An ``type=`` for an integer in ``[low, high]`` (no upper bound when None)."""
    valid = f"[{low}, {high}]" if high is not None else f">= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer {valid}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be an integer {valid}, got {text!r}")
        return value

    parse.__name__ = "integer"
    return parse


def number(low: float, high: float, unit: str = "", low_open: bool = False):
    """An ``type=`` for a finite number in ``[low, high]`` (``(low, high]`` with ``low_open``)."""
    u = f" {unit}" if unit else ""
    valid = f"{'(' if low_open else '['}{low:g}, {high:g}]{u}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (low < value <= high if low_open else low <= value <= high):  # refuses NaN, inf
            raise argparse.ArgumentTypeError(f"must be a finite number in {valid}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


SEED = integer(0)


def output_dir(text: str) -> Path:
    """An ``type=`` for an output folder: an existing folder we may write in, or one we can create
    (its nearest existing parent is a writable folder); never a file."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("must be a folder path, got ''")
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a file, not a folder: choose a folder path")
    parent = path
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{path}: {parent} is a file, so the folder cannot be created")
    try:
        if not os.access(parent, os.W_OK | os.X_OK):
            raise PermissionError
        with tempfile.TemporaryFile(dir=parent):  # the real test (root passes os.access everywhere)
            pass
    except OSError:
        where = "" if parent == path else f" (its parent {parent} is not writable, so it cannot be created)"
        raise argparse.ArgumentTypeError(f"{path}: cannot write in this folder{where}") from None
    return path


def output_file(text: str) -> Path:
    """An ``type=`` for a file to write (``report --out FILE``): not a folder, and its folder is
    one we may write in or can create (checked like :func:`output_dir`; the command creates it)."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("must be a file path, got ''")
    if path.is_dir():
        raise argparse.ArgumentTypeError(
            f"{path} is a folder, not a file: give the file to write, e.g. {path / 'report.html'}"
        )
    try:
        output_dir(str(path.parent))
    except argparse.ArgumentTypeError as exc:  # the folder's own message, prefixed with the file
        raise argparse.ArgumentTypeError(f"{path}: cannot write the file: {exc}") from None
    return path


NUMBER_LIST = re.compile(r"^-[\d.][\d.eE+-]*(,\s*[-+]?[\d.][\d.eE+-]*)+$")


def join_negative_lists(argv: list[str]) -> list[str]:
    """``--q-deg -10,20,...`` as ``--q-deg=-10,20,...``: argparse would take the value for an option.

    Only a comma-separated list of numbers that starts with a minus sign right after a long option
    is joined; ``--q-deg=-10,...`` is the explicit form and always works.
    """
    out = []
    for token in argv:
        if out and NUMBER_LIST.match(token) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def add_load_arguments(parser: argparse.ArgumentParser) -> None:
    """``--tension``, ``--anchor``, ``--hook``: one wire load, with the lab's defaults."""
    from ..scenario import DEFAULT_ANCHOR, DEFAULT_HOOK

    parser.add_argument(
        "--tension",
        type=number(0, 1e5, "N"),
        default=None,
        help="wire tension in N (default: the robot's lab's, docs/lab.md: 200 N for the KR60-3)",
    )
    parser.add_argument("--anchor", default=DEFAULT_ANCHOR, help="table ring (default %(default)s)")
    parser.add_argument("--hook", default=DEFAULT_HOOK, help="block hook (default %(default)s)")


def load_tension(args, lab) -> float:
    """``--tension`` [N] checked against ``lab``'s range, or the lab's default tension."""
    return lab.check_tension(lab.default_tension_N if args.tension is None else args.tension, "--tension")


shown: set[str] = set()  # warnings already printed in this command


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the command line: one line in words, no source path or code
    line (those are for developers), each message once."""
    text = str(message)
    if text not in shown:
        shown.add(text)
        print(f"vtestbed: warning: {text}", file=sys.stderr if file is None else file)


def print_notes(notes) -> None:
    """A result's warnings that were not already shown when they were raised."""
    for note in notes:
        if note not in shown:
            shown.add(note)
            print(f"warning: {note}")
