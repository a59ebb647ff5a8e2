"""Nominal robot descriptions: modified-DH table, limits and inertias, as data.

A description is read from ``models/<name>/robot.toml`` (written by hand, or by
:mod:`vtestbed.robot_import` from a URDF; docs/robots.md). It is what a researcher knows of the
robot, and the one source from which both the truth world (MuJoCo, :mod:`vtestbed.world.mjcf`)
and the researcher's model (Pinocchio, :mod:`vtestbed.researcher.kinematics`) are built. It holds
no stiffness: the world's truth (true stiffness, hidden effects) is a separate file,
``models/<name>/truth.toml``, read only by :mod:`vtestbed.world.truth`.

Units: SI (m, kg, kg*m^2); angles in rad, except in the file where the key says ``_deg``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from .errors import DescriptionError, JointLimitError, SingularPoseError, UnknownNameError
from .files import read_toml
from .transforms import modified_dh

# A pose whose scaled block Jacobian has sigma_min / sigma_max below this is refused as
# (near-)singular: on the KR60 it is about 0.33 deg from the wrist singularity (theta5 = 0), where
# joints 4 and 6 stop being separable from the block's displacement. The paper's 20 test poses
# are above 0.14 and 99 % of random poses within the limits above it.
NEAR_SINGULAR = 1e-3
JACOBIAN_LENGTH_SCALE_M = 1.0  # divides the translational rows: 1 mm of translation ~ 1 mrad

MODELS_DIR = Path(os.environ.get("VTESTBED_MODELS", Path(__file__).resolve().parents[1] / "models"))


@dataclass(frozen=True)
class JointDescription:
    """One revolute joint and the link it moves (all SI; angles in rad unless named _deg)."""

    name: str
    controller_name: str
    alpha_prev: float  # rad
    a_prev: float  # m
    d: float  # m
    controller_sign: float
    controller_offset: float  # rad: theta = sign * A + offset
    lower: float  # rad, DH convention
    upper: float  # rad, DH convention
    mass: float  # kg
    com: tuple[float, float, float]  # m, in the link's DH frame
    inertia_diag: tuple[float, float, float]  # kg*m^2, about the com, DH-frame axes
    # products of inertia (Ixy, Ixz, Iyz) [kg*m^2], about the com in DH-frame axes; a link whose
    # principal axes are not the DH axes (an imported URDF) needs them, the KR60's are zero
    inertia_offdiag: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia tensor about the com in the link's DH-frame axes [kg*m^2]."""
        (ixx, iyy, izz), (ixy, ixz, iyz) = self.inertia_diag, self.inertia_offdiag
        return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


IDENTITY4 = tuple(tuple(float(x) for x in row) for row in np.eye(4))


@dataclass(frozen=True)
class RobotDescription:
    """A serial 6R robot as data (see ``models/<name>/README.md`` for the sources).

    Any serial chain of revolute joints is a modified-DH table between two fixed transforms:
    ``dh0_in_base``, DH frame 0 in the robot's base frame (the world frame of the rig), and
    ``flange_in_dh``, the flange (where the sensor is mounted) in the last DH frame. Both are
    stored as nested tuples (the description stays hashable) and are the identity for a robot
    written as DH from its base to its flange (the KR60).
    """

    name: str
    display_name: str
    base_mass: float
    joints: tuple[JointDescription, ...]
    source: Path
    dh0_in_base: tuple[tuple[float, ...], ...] = IDENTITY4
    flange_in_dh: tuple[tuple[float, ...], ...] = IDENTITY4
    rated_payload_kg: float | None = None  # the maker's rated payload; None: not in the file

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower(self) -> np.ndarray:
        """DH lower limits [rad], shape (n,)."""
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        """DH upper limits [rad], shape (n,)."""
        return np.array([j.upper for j in self.joints])

    @property
    def base_transform(self) -> np.ndarray:
        """(4, 4) pose of DH frame 0 in the robot's base frame."""
        return np.array(self.dh0_in_base)

    @property
    def flange_transform(self) -> np.ndarray:
        """(4, 4) pose of the flange in the last DH frame."""
        return np.array(self.flange_in_dh)

    @property
    def total_mass(self) -> float:
        return self.base_mass + sum(j.mass for j in self.joints)

    def link_transform(self, index: int, theta: float) -> np.ndarray:
        """(4, 4) pose of DH frame ``index+1`` in frame ``index`` at joint angle ``theta`` [rad]."""
        j = self.joints[index]
        return modified_dh(j.alpha_prev, j.a_prev, theta, j.d)

    def frame_poses(self, q) -> list[np.ndarray]:
        """Poses (4, 4) in the base frame of DH frames 1..n at DH angles ``q`` [rad], then the flange."""
        pose = self.base_transform
        out = []
        for i in range(self.dof):
            pose = pose @ self.link_transform(i, float(q[i]))
            out.append(pose)
        out.append(pose @ self.flange_transform)
        return out

    def controller_to_dh(self, angles_controller) -> np.ndarray:
        """Controller angles (KUKA A1..A6; an imported URDF's joint positions) [rad] -> DH angles [rad]."""
        a = np.asarray(angles_controller, dtype=float)
        sign = np.array([j.controller_sign for j in self.joints])
        offset = np.array([j.controller_offset for j in self.joints])
        return sign * a + offset

    def dh_to_controller(self, theta) -> np.ndarray:
        """DH angles theta [rad] -> controller angles [rad] (inverse of :meth:`controller_to_dh`)."""
        t = np.asarray(theta, dtype=float)
        sign = np.array([j.controller_sign for j in self.joints])
        offset = np.array([j.controller_offset for j in self.joints])
        return (t - offset) / sign

    def check_pose(self, q, field: str = "pose") -> np.ndarray:
        """Return ``q`` (DH, rad) as an array, or raise naming the joint and its limits."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.dof,) or not np.all(np.isfinite(q)):
            raise JointLimitError(f"{field} must be {self.dof} finite joint angles, got {q!r}")
        for i, j in enumerate(self.joints):
            if not (j.lower - 1e-12 <= q[i] <= j.upper + 1e-12):
                ctrl = np.degrees(self.dh_to_controller(q))[i]
                raise JointLimitError(
                    f"{field}: {j.name} = {np.degrees(q[i]):.3f} deg (DH; controller {j.controller_name}"
                    f" = {ctrl:.3f} deg) is outside its limits [{np.degrees(j.lower):.1f},"
                    f" {np.degrees(j.upper):.1f}] deg (DH)"
                )
        return q

    def jacobian_conditioning(self, q, point_in_flange=(0.0, 0.0, 0.0)) -> float:
        """sigma_min / sigma_max of the geometric Jacobian at a point fixed to the flange.

        Parameters
        ----------
        q : (n,) DH angles [rad]
        point_in_flange : (3,) the point (the block's origin) in the flange frame [m]

        The translational rows are divided by :data:`JACOBIAN_LENGTH_SCALE_M` so that the ratio
        does not depend on the unit of length; 0 at a singularity.
        """
        frames = self.frame_poses(q)
        axes = [f[:3, 2] for f in frames[:-1]]
        origins = [f[:3, 3] for f in frames[:-1]]
        point = frames[-1][:3, :3] @ np.asarray(point_in_flange, dtype=float) + frames[-1][:3, 3]
        linear = np.stack([np.cross(z, point - o) for z, o in zip(axes, origins)], axis=1)
        jac = np.vstack([linear / JACOBIAN_LENGTH_SCALE_M, np.stack(axes, axis=1)])
        s = np.linalg.svd(jac, compute_uv=False)
        return float(s[-1] / s[0])

    def check_not_singular(self, q, point_in_flange=(0.0, 0.0, 0.0), field: str = "pose") -> float:
        """The conditioning of :meth:`jacobian_conditioning`, or a :class:`SingularPoseError`
        naming the field when it is below :data:`NEAR_SINGULAR`."""
        ratio = self.jacobian_conditioning(q, point_in_flange)
        if not ratio >= NEAR_SINGULAR:
            raise SingularPoseError(
                f"{field}: the pose is at or near a singularity (Jacobian sigma_min/sigma_max = {ratio:.1e}"
                f" at the block, valid: >= {NEAR_SINGULAR:g}); move the joints away from it, e.g."
                f" |theta5| of at least 1 deg"
            )
        return ratio

    def random_pose(self, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        """A uniform random DH pose inside the limits shrunk by ``margin`` [rad] at each end."""
        return rng.uniform(self.lower + margin, self.upper - margin)


def available_robots() -> list[str]:
    """Names of the robots under :data:`MODELS_DIR` (folders holding a robot.toml)."""
    # a dot folder is an import in progress (robot_import.install), and robot_dir refuses the name
    return sorted(p.parent.name for p in MODELS_DIR.glob("*/robot.toml") if not p.parent.name.startswith("."))


def robot_dir(name: str) -> Path:
    """The folder ``models/<name>``; an unknown name lists the available robots."""
    if not isinstance(name, str) or not name or "/" in name or "\\" in name or name.startswith("."):
        raise UnknownNameError("robot", str(name), available_robots())
    path = MODELS_DIR / name
    if not (path / "robot.toml").is_file():
        raise UnknownNameError("robot", name, available_robots())
    return path


_FIELDS = (
    "name controller alpha_prev_deg a_prev_m d_m controller_sign controller_offset_deg "
    "controller_limits_deg mass_kg com_m inertia_diag_kgm2"
).split()


def inertia_problem(inertia) -> str | None:
    """Why a (3, 3) inertia about the com [kg*m^2] is not one MuJoCo accepts for a moving body,
    or None. Its principal moments must be positive (MuJoCo: above mjMINVAL) and each at most the
    sum of the other two (the triangle inequality every real mass distribution satisfies)."""
    matrix = np.asarray(inertia, dtype=float)
    if not np.all(np.isfinite(matrix)):
        return "must be finite"
    moments = np.linalg.eigvalsh((matrix + matrix.T) / 2)
    shown = "[" + ", ".join(f"{m:.4g}" for m in moments) + "] kg*m^2"
    if not moments[0] > 1e-15:  # MuJoCo's mjMINVAL
        return f"has principal moments {shown}; all must be > 0"
    if moments[2] > (moments[0] + moments[1]) * (1 + 1e-9):  # 1e-9: a thin rod's round-off
        return f"has principal moments {shown}; the largest must not exceed the sum of the other two"
    return None


def _finite_numbers(table: dict, field: str, count: int, where: str) -> list[float]:
    """``table[field]``: one finite number (``count`` 1) or a list of ``count``, or an error naming it."""
    value = table.get(field, [0.0] * count if field == "inertia_offdiag_kgm2" else None)
    items = [value] if count == 1 else value
    if (
        not isinstance(items, list | tuple)
        or len(items) != count
        or not all(isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) for v in items)
    ):
        what = "a finite number" if count == 1 else f"{count} finite numbers"
        raise DescriptionError(f"{where}.{field} must be {what}, got {value!r}")
    return [float(v) for v in items]


def _joint_from_table(table: dict, index: int, source: Path) -> JointDescription:
    missing = [f for f in _FIELDS if f not in table]
    if missing:
        raise DescriptionError(f"{source}: joints[{index}] lacks {', '.join(missing)}")
    where = f"{source}: joints[{index}]"
    sign = float(table["controller_sign"])
    if sign not in (1.0, -1.0):
        raise DescriptionError(f"{where}.controller_sign must be 1 or -1, got {sign}")
    # what MuJoCo and the kinematics need of a hand-edited file: finite numbers, a positive mass, a
    # physical inertia, a limit range with lower < upper (a NaN limit would let every pose through)
    for field in ("alpha_prev_deg", "a_prev_m", "d_m", "controller_offset_deg"):
        _finite_numbers(table, field, 1, where)
    for field in ("com_m", "inertia_diag_kgm2", "inertia_offdiag_kgm2"):
        _finite_numbers(table, field, 3, where)
    low, high = _finite_numbers(table, "controller_limits_deg", 2, where)
    if not low < high:
        raise DescriptionError(
            f"{where}.controller_limits_deg must be [lower, upper] deg with lower < upper, got {[low, high]}"
        )
    (mass,) = _finite_numbers(table, "mass_kg", 1, where)
    if not mass > 0:
        raise DescriptionError(
            f"{where}.mass_kg must be a finite number > 0 kg (a moving link), got {mass!r}"
        )
    (ixx, iyy, izz), (ixy, ixz, iyz) = (
        table["inertia_diag_kgm2"],
        table.get("inertia_offdiag_kgm2", (0, 0, 0)),
    )
    problem = inertia_problem([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if problem:
        raise DescriptionError(f"{where}: the inertia (inertia_diag_kgm2, inertia_offdiag_kgm2) {problem}")
    offset = np.radians(table["controller_offset_deg"])
    lim = np.radians([low, high])
    dh_lim = sorted(sign * lim + offset)
    return JointDescription(
        name=table["name"],
        controller_name=table["controller"],
        alpha_prev=float(np.radians(table["alpha_prev_deg"])),
        a_prev=float(table["a_prev_m"]),
        d=float(table["d_m"]),
        controller_sign=sign,
        controller_offset=float(offset),
        lower=float(dh_lim[0]),
        upper=float(dh_lim[1]),
        mass=float(table["mass_kg"]),
        com=tuple(float(x) for x in table["com_m"]),
        inertia_diag=tuple(float(x) for x in table["inertia_diag_kgm2"]),
        inertia_offdiag=tuple(float(x) for x in table.get("inertia_offdiag_kgm2", (0.0, 0.0, 0.0))),
    )


def _rigid_transform(data: dict, field: str, source: Path) -> tuple[tuple[float, ...], ...]:
    """The optional 4x4 rigid transform ``field`` of the file (identity when absent)."""
    if field not in data:
        return IDENTITY4
    try:
        matrix = np.array(data[field], dtype=float)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    valid = "valid: 4 rows of 4 finite numbers, a rotation (R^T R = I, det +1) and last row [0, 0, 0, 1]"
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise DescriptionError(f"{source}: {field} = {data[field]!r} is not a 4x4 transform ({valid})")
    rot = matrix[:3, :3]
    # 1e-9: the file holds 17 significant digits, so an orthonormal matrix passes with room to spare
    if (
        np.abs(rot.T @ rot - np.eye(3)).max() > 1e-9
        or np.linalg.det(rot) < 0
        or np.abs(matrix[3] - [0, 0, 0, 1]).max() > 0
    ):
        raise DescriptionError(f"{source}: {field} is not a rigid transform ({valid})")
    return tuple(tuple(float(x) for x in row) for row in matrix)


def _rated_payload(data: dict, source: Path) -> float | None:
    """The optional ``rated_payload_kg`` (> 0, finite; it caps the wire tension, vtestbed.lab)."""
    value = data.get("rated_payload_kg")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < float("inf"):
        raise DescriptionError(f"{source}: rated_payload_kg = {value!r} must be a number in (0, inf) kg")
    return float(value)


DEFAULT_ROBOT = "kuka_kr60_3"


@cache
def load_robot(name: str = DEFAULT_ROBOT) -> RobotDescription:
    """Load ``models/<name>/robot.toml`` once per process (the description is frozen).

    Unknown names list the available robots.
    """
    return robot_from_file(robot_dir(name) / "robot.toml")


def robot_from_file(source: Path) -> RobotDescription:
    """Read and check a ``robot.toml`` at any path (``robot import`` checks its new file before
    installing it); errors name the file and the field."""
    data = read_toml(source, "robot description", DescriptionError)
    tables = data.get("joints", [])
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise DescriptionError(f"{source}: joints must be a non-empty array of tables ([[joints]])")
    try:
        joints = tuple(_joint_from_table(t, i, source) for i, t in enumerate(tables))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, DescriptionError):
            raise
        raise DescriptionError(f"{source}: malformed joint table: {exc}") from None
    base_mass = data.get("base_mass_kg", 0.0)
    if isinstance(base_mass, bool) or not isinstance(base_mass, int | float) or not 0 <= base_mass < np.inf:
        raise DescriptionError(f"{source}: base_mass_kg must be a finite number >= 0 kg, got {base_mass!r}")
    return RobotDescription(
        name=data["name"],
        display_name=data.get("display_name", data["name"]),
        base_mass=float(base_mass),
        joints=joints,
        source=source,
        dh0_in_base=_rigid_transform(data, "dh0_in_base", source),
        flange_in_dh=_rigid_transform(data, "flange_in_dh", source),
        rated_payload_kg=_rated_payload(data, source),
    )
