"""Joint-level effects: coupled joint stiffness and nonlinear joint springs.

Both are generalized forces on the robot's joints, functions of the joint deflections
``dq = q - q_cmd`` [rad] from the commanded pose, added inside the rig's static equilibrium.
Joint numbers are 1-based, as on the robot (A1..A6 are joints 1..6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import OutOfRangeError
from .base import Param, WorldEffect

# Realistic sizes (docs/effects.md): k56 = 5 % of sqrt(k5 k6) of the KR60-3 (paper Table 5),
# the order of the cross-coupling of a wrist whose A6 drive shaft runs through the A5 gear train.
DEFAULT_K56 = 0.05 * float(np.sqrt(2.5362e4 * 1.9978e4))  # N*m/rad, about 1125
# Hardening that raises joint 2's tangent stiffness by 10 % at 2 mrad (3 k3 dq^2 = 0.1 k2):
# the stiffening of a cycloidal or harmonic gear as its backlash-free preload zone is left.
DEFAULT_K3_JOINT2 = 0.1 * 8.9939e5 / (3 * 0.002**2)  # N*m/rad^3, about 7.5e9


@dataclass(frozen=True)
class JointCoupling(WorldEffect):
    """Symmetric off-diagonal joint stiffness: tau_i = -k_ij dq_j and tau_j = -k_ij dq_i."""

    joints: tuple[int, int] = (5, 6)
    stiffness_Nm_per_rad: float = DEFAULT_K56

    name = "joint_coupling"
    summary = "symmetric off-diagonal joint stiffness k_ij between two joints (wrist gear trains)"
    PARAMS = (
        Param("joints", "-", 1, 6, (5, 6), "the coupled pair (i, j), 1-based, i != j", kind="pair", length=2),
        Param("stiffness_Nm_per_rad", "N*m/rad", -1e8, 1e8, DEFAULT_K56,
              "k_ij; realistic for A5-A6: 5 % of sqrt(k5 k6) = 1125 N*m/rad"),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return self.stiffness_Nm_per_rad == 0.0

    def joint_forces(self, deflection: np.ndarray) -> np.ndarray:
        i, j = self.joints[0] - 1, self.joints[1] - 1
        tau = np.zeros_like(deflection)
        tau[i] = -self.stiffness_Nm_per_rad * deflection[j]
        tau[j] = -self.stiffness_Nm_per_rad * deflection[i]
        return tau

    def check_world(self, robot, truth, field: str) -> None:
        for joint in self.joints:
            if not 1 <= joint <= robot.dof:
                raise OutOfRangeError(f"{field}.joints: joint {joint} does not exist (valid 1..{robot.dof})")
        k = truth.stiffness_true
        i, j = self.joints[0] - 1, self.joints[1] - 1
        limit = float(np.sqrt(k[i] * k[j]))
        if not abs(self.stiffness_Nm_per_rad) < limit:  # the stiffness matrix must stay positive definite
            raise OutOfRangeError(
                f"{field}.stiffness_Nm_per_rad = {self.stiffness_Nm_per_rad:g} N*m/rad makes the joint stiffness "
                f"matrix indefinite: |k_ij| must be below sqrt(k_i k_j) = {limit:.4g} N*m/rad"
            )


@dataclass(frozen=True)
class NonlinearJoint(WorldEffect):
    """A hardening (k3 > 0) or softening (k3 < 0) joint spring: tau = -(k dq + k3 dq^3)."""

    joint: int = 2
    k3_Nm_per_rad3: float = DEFAULT_K3_JOINT2

    name = "nonlinear_joint"
    summary = "cubic joint spring tau = k dq + k3 dq^3 (positive k3 hardens, negative softens)"
    PARAMS = (
        Param("joint", "-", 1, 6, 2, "the joint, 1-based", kind="integer"),
        Param("k3_Nm_per_rad3", "N*m/rad^3", -1e13, 1e13, DEFAULT_K3_JOINT2,
              "cubic coefficient; realistic for A2: +10 % tangent stiffness at 2 mrad, 7.5e9 N*m/rad^3"),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return self.k3_Nm_per_rad3 == 0.0

    def joint_forces(self, deflection: np.ndarray) -> np.ndarray:
        tau = np.zeros_like(deflection)
        dq = deflection[self.joint - 1]
        tau[self.joint - 1] = -self.k3_Nm_per_rad3 * dq**3
        return tau

    def tangent_stiffness(self, k: float, dq: float) -> float:
        """d tau / d dq [N*m/rad] of the joint at deflection ``dq`` [rad] with linear stiffness ``k``."""
        return k + 3.0 * self.k3_Nm_per_rad3 * dq**2

    def past_peak(self, k: float, dq: float | None, field: str) -> str:
        """Why a softening spring (k3 < 0) leaves no stable equilibrium: its torque ``k dq + k3 dq^3``
        peaks at ``dq* = sqrt(k / (3 |k3|))``, so a joint loaded beyond ``2/3 k dq*`` has none
        (``dq`` [rad]: the deflection an equilibrium search ended at, if any; ``field``: the
        effect's place in the scenario). A world past the peak describes nothing physical."""
        peak = np.sqrt(k / (3 * -self.k3_Nm_per_rad3))
        here = "" if dq is None else f" (the equilibrium found lies at {dq * 1e3:.3g} mrad)"
        return (
            f"{field} ({self.name}).k3_Nm_per_rad3 = {self.k3_Nm_per_rad3:g} N*m/rad^3 caps joint {self.joint}'s "
            f"spring torque at {2 / 3 * k * peak:.4g} N*m, reached at a deflection of {peak * 1e3:.3g} mrad{here}: "
            "a joint loaded beyond it (gravity and wire) has no stable equilibrium; valid: a softening k3 whose "
            f"cap the joint's load stays well below, k3 > -4 k^3 / (27 tau^2) for a load tau (k = {k:.4g} N*m/rad)"
        )

    def check_world(self, robot, truth, field: str) -> None:
        if not 1 <= self.joint <= robot.dof:
            raise OutOfRangeError(f"{field}.joint: joint {self.joint} does not exist (valid 1..{robot.dof})")
