"""Argument helpers shared by the command groups: comma-separated numbers and poses, with errors
that name the option and the valid form (exit code 2 through :func:`vtestbed.cli.main.main`)."""

from __future__ import annotations

import argparse

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
    """DH pose [rad] from ``--q-deg`` (DH) or ``--controller-deg`` (KUKA A1..A6)."""
    if getattr(args, "controller_deg", None):
        return robot.controller_to_dh(parse_angles_deg(args.controller_deg, "--controller-deg", robot.dof))
    return parse_angles_deg(args.q_deg, "--q-deg", robot.dof)


def add_pose_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--q-deg", default=DEFAULT_POSE_DEG, help="DH joint angles in degrees (default %(default)s)"
    )
    parser.add_argument(
        "--controller-deg", help="KUKA controller angles A1..A6 in degrees (overrides --q-deg)"
    )
