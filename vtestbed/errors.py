"""One error hierarchy for everything vtestbed refuses to do.

Every message names the offending field and the valid range or the valid names, so that a
researcher can fix the input without reading a traceback.
"""

from __future__ import annotations

from collections.abc import Iterable


class VtestbedError(Exception):
    """Base class of every error vtestbed raises on purpose."""


class UnknownNameError(VtestbedError, KeyError):
    """A name (robot, anchor, hook, joint, ...) that does not exist."""

    def __init__(self, kind: str, name: str, valid: Iterable[str], where: str = ""):
        self.kind, self.name, self.valid = kind, name, sorted(valid)
        prefix = f"{where}: " if where else ""  # the file, field or option that gave the name
        super().__init__(f"{prefix}unknown {kind} {name!r}; valid names: {', '.join(self.valid)}")

    def __str__(self) -> str:  # KeyError would quote the whole message otherwise
        return self.args[0]


class OutOfRangeError(VtestbedError, ValueError):
    """A value outside its valid range; the message names the field and the range."""


class JointLimitError(OutOfRangeError):
    """A commanded pose outside the robot's joint limits."""


class SingularPoseError(VtestbedError, ValueError):
    """A pose at (or numerically at) a kinematic singularity."""


class SlackWireError(VtestbedError, ValueError):
    """The wire is slack where a taut wire is required."""


class SensorOverloadError(OutOfRangeError):
    """A wrench outside the force/torque sensor's measuring range.

    Raised by a tightened wire (:meth:`vtestbed.world.rig.Rig.tighten`), it carries the wire's
    ``tension`` [N] and the ``wrench`` it caused; :func:`vtestbed.world.physics.run_test_physics`
    adds ``max_tension`` [N], the largest tension whose wrench the sensor measures in that test.
    """

    tension: float | None = None
    wrench: object = None  # (6,) array [N, N*m]
    max_tension: float | None = None


class ClearanceError(VtestbedError, ValueError):
    """A test whose pose puts a link into the table, the wire through a link, or blocks the scanner."""


class ConvergenceError(VtestbedError, RuntimeError):
    """An iterative solver did not reach its tolerance."""


class ScenarioError(VtestbedError, ValueError):
    """A malformed scenario or campaign file."""


class DescriptionError(VtestbedError, ValueError):
    """A malformed robot description (robot.toml) or world truth (truth.toml) file."""


class DatasetError(VtestbedError, ValueError):
    """A measurement dataset that is missing files or is inconsistent."""


class ImplausibleDataError(DatasetError):
    """Measurements that no wire load on the block could produce (with ``--strict``; otherwise a
    warning on the result)."""


class ScanError(VtestbedError, ValueError):
    """A scan that cannot deliver the block frame (block out of view, faces missing)."""


def check_range(field: str, value: float, low: float, high: float, unit: str = "", why: str = "") -> float:
    """Return ``value`` if ``low <= value <= high``, else raise :class:`OutOfRangeError` (its
    message ends with ``why``, the reason for the range, if given)."""
    value = float(value)
    if not (low <= value <= high):  # also rejects NaN
        u = f" {unit}" if unit else ""
        raise OutOfRangeError(
            f"{field} = {value:g}{u} is outside the valid range [{low:g}, {high:g}]{u}{why}"
        )
    return value


def require_level(value: float, field: str = "alpha") -> float:
    """Return ``value`` if it is a significance level, in the open interval (0, 1), else raise
    :class:`OutOfRangeError` naming ``field`` (NaN is refused too)."""
    if not 0.0 < value < 1.0:
        raise OutOfRangeError(f"{field} = {value:g} must be in (0, 1)")
    return value
