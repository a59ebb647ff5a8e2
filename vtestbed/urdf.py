"""Reading a URDF: links, inertials, joints, and the serial chain between two links.

Only what a nominal description needs is read (joint placements, axes, limits, efforts and the
link inertials); visuals, collisions, transmissions and plugins are ignored. Every error names
the file and the element. The conversion to a description is :mod:`vtestbed.robot_import`.

URDF conventions (https://wiki.ros.org/urdf/XML): a joint's ``<origin xyz rpy>`` places the
joint frame (= the child link's frame at q = 0) in the parent link's frame, with
``R = Rz(yaw) Ry(pitch) Rx(roll)``; the child turns about ``<axis>`` (joint-frame axes). An
inertial's ``<origin>`` places its frame (com, inertia axes) in the link frame. SI throughout.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import DescriptionError, UnknownNameError

MOVABLE = ("revolute", "continuous")
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


@dataclass(frozen=True)
class UrdfInertial:
    """A link's ``<inertial>``: mass [kg], its frame in the link frame (4, 4), inertia (3, 3) [kg*m^2]
    about the com in that frame's axes."""

    mass: float
    origin: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class UrdfJoint:
    """A ``<joint>``: placement (4, 4) in the parent link, unit axis, limits [rad], effort [N*m]."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None
    upper: float | None
    effort: float | None

    @property
    def movable(self) -> bool:
        return self.type in MOVABLE

    def transform(self, q: float = 0.0) -> np.ndarray:
        """(4, 4) pose of the child link in the parent link at joint position ``q`` [rad]."""
        if not self.movable or q == 0.0:
            return self.origin
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_rotvec(self.axis * q).as_matrix()
        return self.origin @ turn


@dataclass(frozen=True)
class Urdf:
    """A parsed URDF: ``links`` maps each link to its inertial (None without one), ``parent_joint``
    maps each child link to the joint that carries it."""

    path: Path
    name: str
    links: dict[str, UrdfInertial | None]
    parent_joint: dict[str, UrdfJoint]

    def roots(self) -> list[str]:
        return [name for name in self.links if name not in self.parent_joint]

    def children(self, link: str) -> list[UrdfJoint]:
        return [j for j in self.parent_joint.values() if j.parent == link]

    def check_link(self, link: str, option: str) -> str:
        if link not in self.links:
            raise UnknownNameError(f"{option} link of {self.path}", link, self.links)
        return link

    def path_between(self, base: str, tip: str) -> list[UrdfJoint]:
        """The joints from ``base`` down to ``tip``, in order; an error if ``tip`` is not below ``base``."""
        joints, link = [], tip
        while link != base:
            joint = self.parent_joint.get(link)
            if joint is None:
                below = sorted(self.below(base)) or ["(none)"]
                raise DescriptionError(
                    f"{self.path}: link {tip!r} is not below the base link {base!r}; links below it: "
                    + ", ".join(below)
                )
            joints.append(joint)
            link = joint.parent
        return joints[::-1]

    def below(self, base: str) -> dict[str, list[UrdfJoint]]:
        """Every link below ``base`` with the joints from ``base`` to it."""
        out: dict[str, list[UrdfJoint]] = {}
        todo = [(base, [])]
        while todo:
            link, path = todo.pop()
            for joint in self.children(link):
                out[joint.child] = path + [joint]
                todo.append((joint.child, path + [joint]))
        return out


def _floats(elem, attr: str, n: int, default: str | None, where: str) -> np.ndarray:
    text = elem.get(attr, default) if elem is not None else default
    if text is None:
        raise DescriptionError(f"{where} lacks the attribute {attr!r} ({n} number(s))")
    try:
        values = np.array([float(x) for x in text.split()])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise DescriptionError(f"{where}: {attr}={text!r} must be {n} finite number(s)")
    return values


def _origin(elem, where: str) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", _floats(elem, "rpy", 3, "0 0 0", where)).as_matrix()
    out[:3, 3] = _floats(elem, "xyz", 3, "0 0 0", where)
    return out


def _inertial(link, where: str) -> UrdfInertial | None:
    elem = link.find("inertial")
    if elem is None:
        return None
    mass = float(_floats(elem.find("mass"), "value", 1, None, f"{where} <inertial><mass>")[0])
    if mass < 0:
        raise DescriptionError(f"{where} <inertial><mass>: value={mass:g} must be >= 0 kg")
    tensor = elem.find("inertia")
    names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    ixx, ixy, ixz, iyy, iyz, izz = (
        float(_floats(tensor, n, 1, None, f"{where} <inertial><inertia>")[0]) for n in names
    )
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    # a real body's principal moments are >= 0, each at most the sum of the other two; a zero
    # tensor (a point mass, a massless frame) is allowed here: the lumped links are checked again
    moments = np.linalg.eigvalsh(inertia)
    tol = 1e-9 * max(abs(moments).max(), 1e-12)  # round-off of the file's digits
    if moments[0] < -tol or moments[2] > moments[0] + moments[1] + tol:
        shown = ", ".join(f"{m:.4g}" for m in moments)
        raise DescriptionError(
            f"{where} <inertial><inertia>: ixx={ixx:g} ixy={ixy:g} ixz={ixz:g} iyy={iyy:g} iyz={iyz:g}"
            f" izz={izz:g} is not a physical inertia: principal moments [{shown}] kg*m^2 must be >= 0"
            " and each at most the sum of the other two"
        )
    return UrdfInertial(mass, _origin(elem.find("origin"), f"{where} <inertial><origin>"), inertia)


def _joint(elem, path: Path, links: dict) -> UrdfJoint:
    name = elem.get("name", "?")
    where = f"{path}: joint {name!r}"
    kind = elem.get("type")
    if kind not in JOINT_TYPES:
        raise DescriptionError(
            f"{where}: type={kind!r} is not a URDF joint type; valid: {', '.join(JOINT_TYPES)}"
        )
    ends = []
    for tag in ("parent", "child"):
        ref = elem.find(tag)
        link = ref.get("link") if ref is not None else None
        if link not in links:
            raise DescriptionError(f"{where}: <{tag} link={link!r}> is not a link of the file")
        ends.append(link)
    axis = _floats(elem.find("axis"), "xyz", 3, "1 0 0", f"{where} <axis>")  # URDF default: x
    if kind in MOVABLE and np.linalg.norm(axis) < 1e-12:
        raise DescriptionError(f"{where} <axis>: xyz must not be zero")
    limit = elem.find("limit")
    lower = upper = effort = None
    if limit is not None:
        effort = float(_floats(limit, "effort", 1, "0", f"{where} <limit>")[0])
        if kind == "revolute":
            lower = float(_floats(limit, "lower", 1, "0", f"{where} <limit>")[0])
            upper = float(_floats(limit, "upper", 1, "0", f"{where} <limit>")[0])
    if kind == "revolute" and (lower is None or not lower < upper):
        raise DescriptionError(
            f"{where}: a revolute joint needs <limit lower=... upper=...> with lower < upper"
        )
    return UrdfJoint(
        name=name,
        type=kind,
        parent=ends[0],
        child=ends[1],
        origin=_origin(elem.find("origin"), f"{where} <origin>"),
        axis=axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else axis,
        lower=lower,
        upper=upper,
        effort=effort,
    )


def read_urdf(path: str | Path) -> Urdf:
    """Parse a URDF file; a missing file, text that is not XML or a malformed element raise a
    :class:`~vtestbed.errors.DescriptionError` naming the file (and the element)."""
    path = Path(path)
    if not path.is_file():
        raise DescriptionError(f"URDF {path} is missing (the file does not exist)")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DescriptionError(f"{path}: not valid XML ({exc}): is this a URDF?") from None
    except OSError as exc:
        raise DescriptionError(f"{path}: cannot read the URDF: {exc.strerror}") from None
    if root.tag != "robot":
        raise DescriptionError(f"{path}: the top element is <{root.tag}>, a URDF's is <robot>")
    links = {}
    for link in root.findall("link"):
        name = link.get("name")
        if not name or name in links:
            raise DescriptionError(f"{path}: every <link> needs a unique name, got {name!r}")
        links[name] = _inertial(link, f"{path}: link {name!r}")
    parent_joint = {}
    for elem in root.findall("joint"):
        joint = _joint(elem, path, links)
        if joint.child in parent_joint:
            raise DescriptionError(f"{path}: link {joint.child!r} is the child of two joints (not a tree)")
        parent_joint[joint.child] = joint
    if not links:
        raise DescriptionError(f"{path}: the URDF has no <link>")
    return Urdf(path=path, name=root.get("name", path.stem), links=links, parent_joint=parent_joint)


def chain_pose(chain: list[UrdfJoint], q) -> np.ndarray:
    """(4, 4) pose of the chain's last link in its first joint's parent, URDF joint positions ``q``."""
    pose, k = np.eye(4), 0
    for joint in chain:
        if joint.movable:
            pose = pose @ joint.transform(float(q[k]))
            k += 1
        else:
            pose = pose @ joint.origin
    return pose


def check_chain(urdf: Urdf, chain: list[UrdfJoint], base: str, tip: str) -> list[UrdfJoint]:
    """The six revolute joints of ``chain``, or an error naming a joint of another type or the count."""
    for joint in chain:
        if joint.type not in ("fixed", "revolute", "continuous"):
            raise DescriptionError(
                f"{urdf.path}: joint {joint.name!r} between {base!r} and {tip!r} is {joint.type}; "
                "a chain may hold only revolute, continuous and fixed joints"
            )
    movable = [j for j in chain if j.movable]
    if len(movable) != 6:
        raise DescriptionError(
            f"{urdf.path}: the chain {base!r} -> {tip!r} has {len(movable)} revolute joints "
            f"({', '.join(j.name for j in movable) or 'none'}); a 6R arm needs exactly 6 (choose --base/--tip)"
        )
    return movable


def default_tip(urdf: Urdf, base: str) -> str:
    """The child link of the sixth revolute joint below ``base``, when exactly one such link exists."""
    below = urdf.below(base)
    counts = {link: sum(j.movable for j in path) for link, path in below.items()}
    sixth = sorted(link for link, path in below.items() if counts[link] == 6 and path[-1].movable)
    if len(sixth) == 1:
        return sixth[0]
    if not sixth:
        most = max(counts.values(), default=0)
        raise DescriptionError(
            f"{urdf.path}: below the base link {base!r} the longest chain has {most} revolute joints; "
            "a 6R arm needs exactly 6"
        )
    raise DescriptionError(
        f"{urdf.path}: several 6R chains below {base!r}; choose --tip from: {', '.join(sixth)}"
    )
