"""Bring your own robot: a URDF's serial 6R chain as a vtestbed description (docs/robots.md).

:func:`import_urdf` turns the chain from a base link to a tip link into the texts of
``robot.toml`` (modified DH between two fixed transforms, limits, inertias), ``truth.toml``
(true stiffness: given, or the documented assumption :data:`ASSUMED_DEFLECTION_RAD`) and a
README naming the source and the assumptions. The MJCF files then come from the project's
generator (:func:`vtestbed.world.mjcf.write_model_files`), as for every robot.

Kinematics: every serial chain of revolute joints is a modified-DH table (Craig) plus a fixed
base transform (the base link -> DH frame 0) and a fixed flange transform (the last DH frame ->
the tip link). DH frame i has z along joint i's axis (URDF direction, so the URDF joint position
turns it positively) and x along the common normal to axis i+1; parallel axes take the normal
through the previous frame's x line (d_i = 0). Frame 0 is on axis 1 at the foot of the base
origin, its x the base x projected (so a base whose z is axis 1 gives the identity); frame 6 is on
axis 6 at the foot of the tip origin, its x the tip x projected. A controller angle is the URDF
joint position: ``theta_i = q_i + offset_i``.

Inertias: each link is lumped with the links rigidly attached to it (fixed joints, and joints off
the chain locked at 0) and written in its DH frame: mass, com, and the full inertia about the com
(``inertia_diag_kgm2`` and ``inertia_offdiag_kgm2``). Links fixed to the base make ``base_mass_kg``.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import robot_files
from .errors import DescriptionError
from .files import write_text_atomic
from .robots import inertia_problem
from .transforms import invert, modified_dh
from .urdf import Urdf, UrdfJoint, chain_pose, check_chain, default_tip

# Assumed true stiffness when none is given: the joint's rated torque (URDF effort) deflects it by
# 2.5 mrad. For a UR10 this gives 1.3e5 (330 N*m), 6.0e4 (150 N*m) and 2.2e4 N*m/rad (54 N*m), the
# order of the torsional stiffness of harmonic drives of those torque classes.
ASSUMED_DEFLECTION_RAD = 2.5e-3
PARALLEL_TOL = 1e-9  # |z_i x z_i+1| below this: parallel axes (error <= 1e-9 rad per metre of reach)
EXACT_TOL = 1e-9  # the DH chain must reproduce the URDF's to this [m, rad] or the import refuses


@dataclass(frozen=True)
class ImportedRobot:
    """The texts of ``models/<name>/``: ``robot.toml``, ``truth.toml`` and ``README.md``."""

    name: str
    robot_toml: str
    truth_toml: str
    readme: str
    chain: tuple[str, ...]  # the six URDF joint names
    stiffness: tuple[float, ...]  # N*m/rad
    max_error: float  # worst |DH - URDF| over the self-check poses [m or rad]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _perpendicular(v: np.ndarray, z: np.ndarray, fallbacks) -> np.ndarray:
    """``v`` with its ``z`` component removed, normalised; the first usable fallback otherwise."""
    for cand in (v, *fallbacks):
        w = cand - (cand @ z) * z
        if np.linalg.norm(w) > 1e-6:
            return _unit(w)
    raise AssertionError("no direction perpendicular to z")  # unreachable: x, y and z span R^3


def _frame(x: np.ndarray, z: np.ndarray, origin: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = x, np.cross(z, x), z, origin
    return out


def dh_from_axes(points, axes, tip: np.ndarray):
    """Modified DH of the joint axes (lines ``points[i] + t axes[i]``, base frame, at q = 0).

    Returns
    -------
    dh0_in_base : (4, 4)
    rows : list of ``(alpha_prev, a_prev, d, theta_offset)`` [rad, m], one per axis
    flange_in_dh : (4, 4) the tip pose ``tip`` (4, 4, base frame) in the last DH frame
    frames : list of (4, 4) DH frames 0..n in the base frame at q = 0
    """
    z = [_unit(np.asarray(a, dtype=float)) for a in axes]
    p = [np.asarray(pt, dtype=float) for pt in points]
    ex, ey = np.eye(3)[0], np.eye(3)[1]
    # frame 0: on axis 1, at the foot of the base origin, x = base x projected
    o0 = p[0] - (p[0] @ z[0]) * z[0]
    frames = [_frame(_perpendicular(ex, z[0], (ey,)), z[0], o0)]
    hits = [o0]  # hits[i]: where x_i meets axis i+1
    for i in range(len(z)):
        x_prev, zi = frames[-1][:3, 0], z[i]
        if i == len(z) - 1:  # last frame: on the axis at the foot of the tip origin, x = tip x projected
            origin = p[i] + ((tip[:3, 3] - p[i]) @ zi) * zi
            x = _perpendicular(tip[:3, 0], zi, (tip[:3, 1], x_prev))
        else:
            zn, pn = z[i + 1], p[i + 1]
            normal = np.cross(zi, zn)
            if np.linalg.norm(normal) < PARALLEL_TOL:  # parallel: the normal through hits[i] (d = 0)
                origin = p[i] + ((hits[i] - p[i]) @ zi) * zi
                x = _perpendicular(pn - origin, zi, (x_prev, ex, ey))
                reach = (pn - origin) @ x
            else:  # the unique common normal: closest points of the two lines
                w = p[i] - pn
                b, d, e = zi @ zn, zi @ w, zn @ w
                det = 1.0 - b * b
                origin = p[i] + ((b * e - d) / det) * zi
                other = pn + ((e - b * d) / det) * zn
                gap = other - origin
                x = _unit(gap) if np.linalg.norm(gap) > 1e-12 else _unit(normal)
                reach = gap @ x
            if (
                x @ x_prev < 0
            ):  # either sign is a valid DH frame: the one closer to x_prev keeps offsets small
                x, reach = -x, -reach
            hits.append(origin + reach * x)
        frames.append(_frame(x, zi, origin))
    rows = []
    for i in range(1, len(frames)):
        prev, cur = frames[i - 1], frames[i]
        xp, zp, xc, zc = prev[:3, 0], prev[:3, 2], cur[:3, 0], cur[:3, 2]
        alpha = np.arctan2(np.cross(zp, zc) @ xp, zp @ zc)
        a = (hits[i - 1] - prev[:3, 3]) @ xp
        d = (cur[:3, 3] - hits[i - 1]) @ zc
        theta = np.arctan2(np.cross(xp, xc) @ zc, xp @ xc)
        rows.append((float(alpha), float(a), float(d), float(theta)))
    return frames[0], rows, invert(frames[-1]) @ tip, frames


def _lumped(urdf: Urdf, links: list[str], frame_of_link: dict[str, np.ndarray]):
    """Mass [kg], com (3,) and inertia (3, 3) about it of ``links``, in the frame whose pose in
    each link is ``frame_of_link[link]`` (the group's DH frame), by the parallel-axis theorem."""
    parts = []
    for link in links:
        inertial = urdf.links[link]
        if inertial is None or inertial.mass == 0.0:
            continue
        pose = invert(frame_of_link[link]) @ inertial.origin
        rot = pose[:3, :3]
        parts.append((inertial.mass, pose[:3, 3], rot @ inertial.inertia @ rot.T))
    mass = sum(m for m, _, _ in parts)
    if mass <= 0.0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = sum(
        i + m * ((c - com) @ (c - com) * np.eye(3) - np.outer(c - com, c - com)) for m, c, i in parts
    )
    return mass, com, inertia


def _stiffness(movable: list[UrdfJoint], given, path) -> tuple[tuple[float, ...], str]:
    if given is not None:
        k = tuple(float(v) for v in given)
        if len(k) != 6 or not all(np.isfinite(v) and v > 0 for v in k):
            raise DescriptionError(
                f"--stiffness-Nm-per-rad must be 6 finite numbers > 0 [N*m/rad], got {given!r}"
            )
        return k, "given by the user (`--stiffness-Nm-per-rad`)"
    lacking = [j.name for j in movable if not (j.effort and j.effort > 0)]
    if lacking:
        raise DescriptionError(
            f"{path}: joints {', '.join(lacking)} have no <limit effort> > 0, from which the stiffness"
            " is assumed; give --stiffness-Nm-per-rad k1,...,k6 [N*m/rad]"
        )
    k = tuple(j.effort / ASSUMED_DEFLECTION_RAD for j in movable)
    return k, (
        f"assumed: the URDF's rated torque (`<limit effort>`) deflects each joint by "
        f"{ASSUMED_DEFLECTION_RAD * 1e3:g} mrad, k = effort / {ASSUMED_DEFLECTION_RAD:g} rad"
    )


def import_urdf(urdf: Urdf, name: str, base: str | None = None, tip: str | None = None,
                stiffness=None, source_note: str = "", rated_payload_kg: float | None = None) -> ImportedRobot:  # fmt: skip
    """The description, truth and README texts of the 6R chain ``base`` -> ``tip`` of ``urdf``.

    Parameters
    ----------
    urdf : the parsed file (:func:`vtestbed.urdf.read_urdf`)
    name : the robot's name, its folder ``models/<name>``
    base, tip : link names; default the URDF's root and the child of the sixth revolute joint
    stiffness : (6,) true joint stiffness [N*m/rad]; default the assumption of :data:`ASSUMED_DEFLECTION_RAD`
    source_note : where the URDF came from, written into the README
    rated_payload_kg : the maker's rated payload [kg] (a URDF does not hold it); it caps the wire
        tension (:mod:`vtestbed.lab`); None: not known, no cap from the robot
    """
    if rated_payload_kg is not None and not (np.isfinite(rated_payload_kg) and rated_payload_kg > 0):
        raise DescriptionError(f"--rated-payload-kg {rated_payload_kg!r} must be a number in (0, inf) kg")
    roots = urdf.roots()
    if base is None:
        if len(roots) != 1:
            raise DescriptionError(
                f"{urdf.path}: the URDF has {len(roots)} root links ({', '.join(roots)}); choose --base"
            )
        base = roots[0]
    urdf.check_link(base, "--base")
    tip = default_tip(urdf, base) if tip is None else urdf.check_link(tip, "--tip")
    chain = urdf.path_between(base, tip)
    movable = check_chain(urdf, chain, base, tip)
    below = urdf.below(base)
    # q = 0 poses of every link below the base, and the axes of the six joints (base frame)
    pose = {base: np.eye(4)}
    for link, path in sorted(below.items(), key=lambda item: len(item[1])):
        pose[link] = pose[path[-1].parent] @ path[-1].origin
    axis_frames = [pose[j.parent] @ j.origin for j in movable]
    dh0, rows, flange, frames = dh_from_axes(
        [f[:3, 3] for f in axis_frames], [f[:3, :3] @ j.axis for f, j in zip(axis_frames, movable)], pose[tip]
    )
    error = _self_check(chain, dh0, rows, flange)
    if error > EXACT_TOL:
        raise DescriptionError(
            f"{urdf.path}: the modified-DH form reproduces the chain only to {error:.1e} (m or rad; needed"
            f" {EXACT_TOL:g}): two joint axes are nearly but not exactly parallel"
        )
    # which rigid body each link belongs to: 0 = the base, k = moved by the k-th chain joint
    names = {j.name for j in movable}
    group = {base: 0} | {link: sum(j.name in names for j in path) for link, path in below.items()}
    for joint in movable:
        if urdf.links[joint.child] is None:
            raise DescriptionError(
                f"{urdf.path}: link {joint.child!r} (moved by joint {joint.name!r}) has no <inertial>;"
                " every moving link of the chain needs <inertial> with <mass>, <origin> and <inertia>"
            )
    frame_of_link = {link: invert(pose[link]) @ frames[g] for link, g in group.items()}
    bodies = [_lumped(urdf, [link for link, g in group.items() if g == k], frame_of_link) for k in range(7)]
    for k, (mass, _, _) in enumerate(bodies[1:], start=1):
        if mass <= 0.0:
            raise DescriptionError(
                f"{urdf.path}: the links moved by joint {movable[k - 1].name!r} have no mass; MuJoCo needs > 0 kg"
            )
    for k, (_, _, inertia) in enumerate(bodies[1:], start=1):  # what MuJoCo would refuse, said first
        problem = inertia_problem(inertia)
        if problem:
            raise DescriptionError(
                f"{urdf.path}: the links moved by joint {movable[k - 1].name!r}, lumped, have an inertia"
                f" that {problem}; MuJoCo needs a physical inertia for every moving body"
            )
    k_true, k_note = _stiffness(movable, stiffness, urdf.path)
    locked = sorted({j.name for path in below.values() for j in path if j.movable and j.name not in names})
    sha = hashlib.sha256(urdf.path.read_bytes()).hexdigest()
    robot_toml = robot_files.robot_toml(
        urdf, name, base, tip, movable, dh0, rows, flange, bodies, sha, rated_payload_kg
    )
    truth_toml = robot_files.truth_toml(name, k_true, k_note)
    readme = robot_files.readme(
        urdf, name, base, tip, movable, k_true, k_note, locked, sha, source_note, error
    )
    return ImportedRobot(name, robot_toml, truth_toml, readme, tuple(j.name for j in movable), k_true, error)


def _self_check(chain, dh0, rows, flange, n_poses: int = 20) -> float:
    """Worst difference [m, rad] between the DH form and the URDF chain at random joint positions."""
    rng = np.random.default_rng(0)
    worst = 0.0
    for q in rng.uniform(-np.pi, np.pi, (n_poses, 6)):
        dh = dh0.copy()
        for (alpha, a, d, offset), qi in zip(rows, q):
            dh = dh @ modified_dh(alpha, a, qi + offset, d)
        diff = invert(chain_pose(chain, q)) @ dh @ flange
        worst = max(worst, np.abs(diff[:3, 3]).max(), np.abs(diff[:3, :3] - np.eye(3)).max())
    return float(worst)


NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
FILES = ("robot.toml", "truth.toml", "README.md")


def check_name(name: str) -> str:
    """A robot name usable as the folder ``models/<name>``, or a :class:`DescriptionError`."""
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise DescriptionError(
            f"--name {name!r} is not a valid robot name (valid: letters, digits, '_' and '-', not first)"
        )
    return name


def write_folder(imported: ImportedRobot, directory: Path, force: bool = False) -> list[Path]:
    """Write ``robot.toml``, ``truth.toml`` and ``README.md`` into ``directory``; an existing
    description is overwritten only with ``force``."""
    directory = Path(directory)
    if (directory / "robot.toml").exists() and not force:
        raise DescriptionError(f"{directory / 'robot.toml'} exists already; pass --force to overwrite it")
    directory.mkdir(parents=True, exist_ok=True)
    texts = dict(zip(FILES, (imported.robot_toml, imported.truth_toml, imported.readme)))
    return [write_text_atomic(directory / name, text) for name, text in texts.items()]
