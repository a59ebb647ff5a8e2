"""The shape of a hidden effect: a named, world-only piece of physics the paper's model leaves out.

An effect changes the truth world in one or more of five places, each a method with a neutral
default, so a subclass implements only what its physics needs:

``hinges``
    Extra compliant hinges the scene builder inserts into a body before its own joint
    (link compliance, a compliant foundation). Units: m, N*m/rad.
``edit_spec``
    Any other edit of the MuJoCo spec before compilation (a balancer's spring tendon).
``joint_forces``
    A generalized force [N*m] on the robot's joints as a function of their deflection from the
    commanded pose [rad], added inside the rig's static equilibrium (joint coupling, nonlinear
    springs). The rig solves with it; the F/T sensor reads the resulting static state.
``wrench_reading`` / ``scan_points``
    A change of the measurement chain: the wrench the sensor reports (a misaligned sensor, a
    drifting bias) or the points the scanner reports (a scale error).
``loaded_motion``
    The loaded block moving on while the wire stays tensioned (creep): each further scan of the
    loaded block sees it a little farther along (:mod:`vtestbed.world.repeats`).

Every effect has a fixed ``name`` (what scenario files and the discrepancy workflow call it), a
parameter table (:class:`Param`: unit, valid range, realistic default with its source) and
``is_null``: an effect whose size is zero changes nothing, and the rig then builds exactly the
clean world. Effects are truth: only :mod:`vtestbed.world` and the orchestrators see them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np


@dataclass(frozen=True)
class Param:
    """One parameter of an effect as a scenario file gives it.

    ``kind`` is ``"number"``, ``"integer"``, ``"vector"`` (``length`` numbers) or ``"pair"`` (two
    distinct integers); ``low``/``high`` bound every number; ``default`` is the realistic value
    (its derivation is in ``doc`` and in docs/effects.md).
    """

    name: str
    unit: str
    low: float
    high: float
    default: object
    doc: str
    kind: str = "number"
    length: int = 1


@dataclass(frozen=True)
class ExtraHinge:
    """A compliant hinge inserted into a body of the robot before its own joint.

    ``body`` is 0 for the base and k for link k; ``pos`` [m] and ``axis`` are in that body's
    frame; ``stiffness`` [N*m/rad] about ``axis`` with its spring at rest at 0.
    """

    body: int
    name: str
    pos: tuple[float, float, float]
    axis: tuple[float, float, float]
    stiffness: float
    damping: float = 1e3  # N*m*s/rad, only for the dynamic settle


@dataclass(frozen=True)
class WorldEffect:
    """Base of every hidden effect (frozen dataclasses whose fields are the parameters)."""

    name: ClassVar[str] = "effect"
    summary: ClassVar[str] = ""
    PARAMS: ClassVar[tuple[Param, ...]] = ()

    # ------------------------------------------------------------------ what it changes
    @property
    def is_null(self) -> bool:
        """True when the effect's size is zero: the world is then the clean one, bit for bit."""
        return False

    def hinges(self, robot) -> tuple[ExtraHinge, ...]:
        return ()

    def edit_spec(self, spec, robot, lab) -> None:
        return None

    def joint_forces(self, deflection: np.ndarray) -> np.ndarray | None:
        """(n,) generalized force [N*m] at joint deflections ``deflection`` (n,) [rad], or None."""
        return None

    def wrench_reading(self, wrench: np.ndarray, phase: str) -> np.ndarray:
        """The wrench (6,) the sensor reports for the true ``wrench`` (``phase``: unloaded/loaded)."""
        return wrench

    def scan_points(self, points: np.ndarray) -> np.ndarray:
        """The points (N, 3) [m, scanner frame] the scanner reports for the true ``points``."""
        return points

    def loaded_motion(self, displacement: np.ndarray, scan: int) -> np.ndarray | None:
        """The loaded block's further motion (6,) [m, rad], in its own frame, at its ``scan``-th scan
        (0: the test's own loaded scan, k: loaded repeat k) for the test's elastic ``displacement``
        (6,) [m, rad]; None when the block holds still under the load."""
        return None

    def check_world(self, robot, truth, field: str) -> None:
        """Raise an OutOfRangeError naming ``field`` if the effect cannot exist in this world."""
        return None

    # ------------------------------------------------------------------ records
    @property
    def has_joint_forces(self) -> bool:
        return type(self).joint_forces is not WorldEffect.joint_forces

    @property
    def changes_physics(self) -> bool:
        """True when the effect changes the truth world's statics (extra hinges, the scene, joint
        forces), not only what the sensors report or how the loaded block creeps."""
        return (
            self.has_joint_forces
            or type(self).hinges is not WorldEffect.hinges
            or type(self).edit_spec is not WorldEffect.edit_spec
        )

    @property
    def moves_loaded_block(self) -> bool:
        return type(self).loaded_motion is not WorldEffect.loaded_motion

    @property
    def changes_measurement(self) -> bool:
        return (
            type(self).wrench_reading is not WorldEffect.wrench_reading
            or type(self).scan_points is not WorldEffect.scan_points
        )

    def to_dict(self) -> dict:
        """``{"name": ..., <parameter>: <value>}`` as truth.json records it (SI, file units)."""
        out = {"name": self.name}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


def check_effects(effects, robot, truth) -> None:
    """Each effect of a scenario's list against the robot and its truth (:meth:`WorldEffect.check_world`),
    named by its place in the list (``world.effects[i]``); a null effect is off, not renumbered."""
    for i, effect in enumerate(effects):
        if not effect.is_null:
            effect.check_world(robot, truth, f"world.effects[{i}] ({effect.name})")
