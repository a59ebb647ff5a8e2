"""Structural effects: compliant links, a compliant foundation and the joint-2 spring balancer.

Link and base compliance are lumped hinges (:class:`~.base.ExtraHinge`) the scene builder
inserts before a body's own joint; the balancer is a MuJoCo spring tendon between a point on
link 1 and a point on link 2. Frames: the DH frames of the links (m), joint numbers 1-based.

Realistic sizes (derivations in docs/effects.md):

- links: a cast-aluminium box beam (E = 70 GPa, G = 26 GPa) of the link's length, as one lumped
  hinge with the beam's end-moment compliance ``k = E I / L`` (bending) and ``G J / L`` (torsion);
- foundation: a steel pedestal bolted to a concrete floor, tilt 2e8 and twist 4e8 N*m/rad;
- balancer: a 30 kN/m tension spring from 0.3 m above A2 on the column to 0.25 m along the lower
  arm (free length 0.05 m). Close to a zero-free-length balancer, its torque is about
  ``k a b sin(phi)`` (phi: the arm's angle from vertical), 1960 N*m when horizontal: about the
  arm's own weight torque (about 2100 N*m); over the paper's poses its stiffness is 0-1900
  N*m/rad, at most 0.21 % of k2.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ...errors import OutOfRangeError
from .base import ExtraHinge, Param, WorldEffect

LINK_BOXES = {  # link -> (in-plane depth h, width b, wall t) [m] of the cast box section
    2: (0.25, 0.20, 0.006),
    3: (0.18, 0.16, 0.005),
}
E_CAST_AL, G_CAST_AL = 70e9, 26e9  # Pa


def box_beam_hinge(length: float, h: float, b: float, t: float, e=E_CAST_AL, g=G_CAST_AL):
    """(in-plane, out-of-plane, torsion) stiffness [N*m/rad] of a thin-walled box beam of ``length``
    [m] lumped into one hinge: ``E I / L`` about each bending axis and ``G J / L`` in torsion
    (Bredt: J = 4 A_m^2 t / perimeter_m)."""
    i_in = (b * h**3 - (b - 2 * t) * (h - 2 * t) ** 3) / 12
    i_out = (h * b**3 - (h - 2 * t) * (b - 2 * t) ** 3) / 12
    j = 4 * ((b - t) * (h - t)) ** 2 * t / (2 * ((b - t) + (h - t)))
    return e * i_in / length, e * i_out / length, g * j / length


# Link lengths of the KR60-3 (paper Table 1): link 2 = a3 = 0.85 m; link 3 = |(a4, d4)| = 0.833 m.
_K_LINK2 = box_beam_hinge(0.85, *LINK_BOXES[2])
DEFAULT_LINK2 = tuple(float(round(k, -3)) for k in _K_LINK2)  # about (4.05e6, 2.87e6, 1.86e6)


def _link_geometry(robot, link: int):
    """Link ``link``'s direction (unit, in its DH frame) and the pose of the next body in it."""
    child = robot.link_transform(link, 0.0)  # next DH frame in this link's frame
    end = child[:3, 3]
    return end, child


@dataclass(frozen=True)
class LinkCompliance(WorldEffect):
    """A compliant point inside link 2 or 3: three hinges (in-plane, out-of-plane, torsion)."""

    link: int = 2
    position: float = 0.5
    stiffness_Nm_per_rad: tuple[float, float, float] = DEFAULT_LINK2

    name = "link_compliance"
    summary = "compliant hinges inside link 2 or 3 (bending in and out of the joint plane, torsion)"
    PARAMS = (
        Param("link", "-", 2, 3, 2, "the link (2: lower arm, 3: forearm)", kind="integer"),
        Param("position", "-", 0.05, 0.95, 0.5, "where along the link, as a fraction of its length from its joint"),
        Param("stiffness_Nm_per_rad", "N*m/rad", 1e4, float("inf"), DEFAULT_LINK2,
              "(in-plane bending, out-of-plane bending, torsion); realistic for link 2: a cast-aluminium box "
              "250 x 200 x 6 mm over 0.85 m, E I / L and G J / L", kind="vector", length=3),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return all(np.isinf(self.stiffness_Nm_per_rad))

    def hinges(self, robot) -> tuple[ExtraHinge, ...]:
        end, child = _link_geometry(robot, self.link)
        along = end / np.linalg.norm(end)
        z = np.array([0.0, 0.0, 1.0])  # the link's joint axis: bending in the joint plane turns about it
        out = np.cross(along, z)
        out /= np.linalg.norm(out)
        rot, origin = child[:3, :3], child[:3, 3]
        point = rot.T @ (self.position * end - origin)  # in the child body's frame
        axes = {"in_plane": z, "out_of_plane": out, "torsion": along}
        return tuple(
            ExtraHinge(self.link + 1, f"link{self.link}_flex_{label}", tuple(point), tuple(rot.T @ axis), k)
            for (label, axis), k in zip(axes.items(), self.stiffness_Nm_per_rad)
            if np.isfinite(k)
        )

    def check_world(self, robot, truth, field: str) -> None:
        if self.link not in (2, 3) or self.link >= robot.dof:
            raise OutOfRangeError(f"{field}.link = {self.link}: valid links are 2 and 3")


@dataclass(frozen=True)
class BaseCompliance(WorldEffect):
    """The foundation: the whole robot tilts about x, y and twists about z at its base origin."""

    stiffness_Nm_per_rad: tuple[float, float, float] = (2e8, 2e8, 4e8)

    name = "base_compliance"
    summary = "the robot's foundation: tilt about x and y, twist about z at the base origin"
    PARAMS = (
        Param("stiffness_Nm_per_rad", "N*m/rad", 1e5, float("inf"), (2e8, 2e8, 4e8),
              "(tilt x, tilt y, twist z); realistic: a steel pedestal on a concrete floor", kind="vector", length=3),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return all(np.isinf(self.stiffness_Nm_per_rad))

    def hinges(self, robot) -> tuple[ExtraHinge, ...]:
        axes = (("tilt_x", (1.0, 0.0, 0.0)), ("tilt_y", (0.0, 1.0, 0.0)), ("twist_z", (0.0, 0.0, 1.0)))
        return tuple(
            ExtraHinge(0, f"base_{label}", (0.0, 0.0, 0.0), axis, k, damping=1e5)
            for (label, axis), k in zip(axes, self.stiffness_Nm_per_rad)
            if np.isfinite(k)
        )


BALANCER_SITES = ("balancer_link1", "balancer_link2")
BALANCER_TENDON = "balancer"


@dataclass(frozen=True)
class GravityCompensator(WorldEffect):
    """The joint-2 spring balancer: a spring between a point on link 1 and a point on link 2."""

    anchor_link1_m: tuple[float, float, float] = (0.35, 0.0, 0.30)
    anchor_link2_m: tuple[float, float, float] = (0.25, 0.0, 0.0)
    spring_rate_N_per_m: float = 3e4
    free_length_m: float = 0.05

    name = "gravity_compensator"
    summary = "the joint-2 spring balancer of heavy KUKA arms (a spring tendon from link 1 to link 2)"
    PARAMS = (
        Param("anchor_link1_m", "m", -2.0, 2.0, (0.35, 0.0, 0.30),
              "spring end on link 1, in its DH frame (0.3 m above A2)", kind="vector", length=3),
        Param("anchor_link2_m", "m", -2.0, 2.0, (0.25, 0.0, 0.0),
              "spring end on link 2, in its DH frame (along the lower arm)", kind="vector", length=3),
        Param("spring_rate_N_per_m", "N/m", 0.0, 1e7, 3e4, "spring rate; 0 removes the balancer"),
        Param("free_length_m", "m", 0.0, 5.0, 0.05, "unstretched length (a chain makes it short)"),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return self.spring_rate_N_per_m == 0.0

    def edit_spec(self, spec, robot, lab) -> None:
        spec.body("link1").add_site(
            name=BALANCER_SITES[0], pos=list(self.anchor_link1_m), size=[0.01, 0, 0], group=3
        )
        spec.body("link2").add_site(
            name=BALANCER_SITES[1], pos=list(self.anchor_link2_m), size=[0.01, 0, 0], group=3
        )
        tendon = spec.add_tendon(name=BALANCER_TENDON)
        tendon.wrap_site(BALANCER_SITES[0])
        tendon.wrap_site(BALANCER_SITES[1])
        tendon.stiffness[0] = self.spring_rate_N_per_m
        tendon.springlength = [self.free_length_m, self.free_length_m]  # a two-way spring
        tendon.damping[0] = 1e3

    def torque_joint2(self, robot, theta2: float) -> float:
        """Closed-form torque [N*m] of the spring on joint 2 at DH angle ``theta2`` [rad]."""
        frame = robot.link_transform(1, theta2)  # link 2's frame in link 1's frame
        p1 = np.array(self.anchor_link1_m)
        p2 = frame[:3, :3] @ np.array(self.anchor_link2_m) + frame[:3, 3]
        length = np.linalg.norm(p2 - p1)
        force = self.spring_rate_N_per_m * (length - self.free_length_m)  # tension > 0
        axis, pivot = frame[:3, 2], frame[:3, 3]  # joint 2's axis and origin in link 1's frame
        pull = -force * (p2 - p1) / length  # force on link 2 at p2
        return float(axis @ np.cross(p2 - pivot, pull))

    def check_world(self, robot, truth, field: str) -> None:
        if robot.dof < 2:
            raise OutOfRangeError(f"{field}: the robot has no joint 2")


def add_hinges(body: mujoco.MjsBody, hinges) -> None:
    """Add ``hinges`` (their spring at rest at 0) to ``body``; the builder calls this first."""
    for h in hinges:
        joint = body.add_joint(
            name=h.name, type=mujoco.mjtJoint.mjJNT_HINGE, pos=list(h.pos), axis=list(h.axis)
        )
        joint.stiffness[0] = h.stiffness
        joint.damping[0] = h.damping
        joint.armature = 1.0
