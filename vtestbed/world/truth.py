"""The truth of the virtual world: what the researcher is trying to find out.

The nominal description (:mod:`vtestbed.robots`) is what a researcher knows; the truth adds what
only the world knows: the true joint stiffness and the terms that shape the dynamic settle
(damping, armature), read from ``models/<name>/truth.toml``. The hidden effects the paper's
model leaves out will join it here. Only the world, the orchestrators and the reports that compare
an estimate with the truth import this module (a contract test in ``tests/test_architecture.py``
enforces it).

Units: SI (N*m/rad, N*m*s/rad, kg*m^2).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from ..errors import DescriptionError
from ..files import read_toml
from ..robots import RobotDescription, load_robot, robot_dir

TRUTH_FILE_NAME = "truth.toml"


@dataclass(frozen=True)
class RobotTruth:
    """One robot's true joint parameters, in the joint order of its description.

    Attributes
    ----------
    robot : str
        The description's name (``models/<robot>``).
    stiffness : tuple of float, length n
        True joint stiffness [N*m/rad].
    damping : tuple of float, length n
        Joint damping [N*m*s/rad]; only the dynamic settle (``Rig.settle``) feels it.
    armature : tuple of float, length n
        Reflected rotor inertia [kg*m^2]; only the dynamic settle feels it.
    source : Path or None
        The file it was read from.
    """

    robot: str
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    armature: tuple[float, ...]
    source: Path | None = None

    @property
    def stiffness_true(self) -> np.ndarray:
        """(n,) true joint stiffness [N*m/rad]."""
        return np.array(self.stiffness)


def _positive(values, source: Path, field: str, joint: int) -> float:
    if isinstance(values, bool) or not isinstance(values, int | float) or not 0.0 <= values < np.inf:
        raise DescriptionError(
            f"{source}: joints[{joint}].{field} must be a finite number >= 0, got {values!r}"
        )
    return float(values)


@cache
def load_truth(name: str) -> RobotTruth:
    """Read ``models/<name>/truth.toml`` (once per process), checked against the description."""
    return truth_from_file(robot_dir(name) / TRUTH_FILE_NAME, load_robot(name))


def truth_from_file(source: Path, robot: RobotDescription) -> RobotTruth:
    """Read and check a ``truth.toml`` at any path against ``robot`` (``robot import`` checks its
    new file before installing it)."""
    data = read_toml(source, "world truth", DescriptionError)
    if data.get("robot", robot.name) != robot.name:
        raise DescriptionError(
            f"{source}: robot = {data.get('robot')!r} does not match the description {robot.name!r}"
        )
    tables = data.get("joints")
    if (
        not isinstance(tables, list)
        or len(tables) != robot.dof
        or not all(isinstance(t, dict) for t in tables)
    ):
        raise DescriptionError(f"{source}: joints must be {robot.dof} tables ([[joints]]), one per joint")
    names = [t.get("name") for t in tables]
    if names != list(robot.joint_names):
        raise DescriptionError(
            f"{source}: joints must be named {list(robot.joint_names)} in order, got {names}"
        )
    fields = ("stiffness_Nm_per_rad", "damping_Nms_per_rad", "armature_kgm2")
    values = {f: tuple(_positive(t.get(f), source, f, i) for i, t in enumerate(tables)) for f in fields}
    if min(values["stiffness_Nm_per_rad"]) <= 0.0:
        raise DescriptionError(f"{source}: every stiffness_Nm_per_rad must be > 0")
    return RobotTruth(
        robot=robot.name,
        stiffness=values["stiffness_Nm_per_rad"],
        damping=values["damping_Nms_per_rad"],
        armature=values["armature_kgm2"],
        source=source,
    )
