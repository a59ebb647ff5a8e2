"""Geometry effects: the true robot and the true block are not where the nominal data say.

``geometric_error`` moves the links' DH frames (a, d, alpha and theta-offset deviations per
joint); ``block_offset`` moves the block (and its hooks) on the sensor. The researcher's
setup.json and robot.toml keep the nominal values. Units: m and deg in the file, SI inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ...transforms import homogeneous, modified_dh, quat_wxyz
from .base import Param, WorldEffect

# An uncalibrated industrial arm: link lengths off by tenths of a millimetre, axes by a few
# hundredths of a degree, zero offsets by up to 0.05 deg (typical of calibration residuals
# reported for robots of this class before calibration).
DEFAULT_DA_MM = (0.0, 0.2, -0.3, 0.15, 0.0, 0.0)
DEFAULT_DD_MM = (0.0, 0.0, 0.0, -0.25, 0.0, 0.1)
DEFAULT_DALPHA_DEG = (0.0, 0.02, -0.03, 0.02, -0.01, 0.0)
DEFAULT_DTHETA_DEG = (0.0, 0.04, -0.05, 0.03, 0.02, -0.03)


@dataclass(frozen=True)
class GeometricError(WorldEffect):
    """The true DH table: nominal + deviations (a, d in mm; alpha, theta offset in deg), per joint."""

    da_mm: tuple[float, ...] = DEFAULT_DA_MM
    dd_mm: tuple[float, ...] = DEFAULT_DD_MM
    dalpha_deg: tuple[float, ...] = DEFAULT_DALPHA_DEG
    dtheta_deg: tuple[float, ...] = DEFAULT_DTHETA_DEG

    name = "geometric_error"
    summary = "the true robot's DH parameters differ from the nominal table (a, d, alpha, theta offset)"
    PARAMS = (
        Param("da_mm", "mm", -20.0, 20.0, DEFAULT_DA_MM, "deviation of a_{i-1} per joint", kind="vector", length=6),
        Param("dd_mm", "mm", -20.0, 20.0, DEFAULT_DD_MM, "deviation of d_i per joint", kind="vector", length=6),
        Param("dalpha_deg", "deg", -2.0, 2.0, DEFAULT_DALPHA_DEG, "deviation of alpha_{i-1} per joint",
              kind="vector", length=6),
        Param("dtheta_deg", "deg", -2.0, 2.0, DEFAULT_DTHETA_DEG,
              "zero offset: true theta_i = commanded + offset", kind="vector", length=6),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return not any((*self.da_mm, *self.dd_mm, *self.dalpha_deg, *self.dtheta_deg))

    def link_transform(self, robot, index: int, theta: float) -> np.ndarray:
        """(4, 4) true pose of DH frame ``index+1`` in frame ``index`` at commanded angle ``theta``."""
        j = robot.joints[index]
        return modified_dh(
            j.alpha_prev + np.radians(self.dalpha_deg[index]),
            j.a_prev + self.da_mm[index] * 1e-3,
            theta + np.radians(self.dtheta_deg[index]),
            j.d + self.dd_mm[index] * 1e-3,
        )

    def edit_spec(self, spec, robot, lab) -> None:
        for i in range(robot.dof):
            placement = self.link_transform(robot, i, 0.0)  # the joint then turns about the body's z
            if i == 0:  # an imported robot's DH frame 0 may sit off its base frame
                placement = robot.base_transform @ placement
            body = spec.body(f"link{i + 1}")
            body.pos = placement[:3, 3]
            body.quat = quat_wxyz(placement[:3, :3])


@dataclass(frozen=True)
class BlockOffset(WorldEffect):
    """The block sits off its nominal place on the sensor: a small rigid motion in the block frame."""

    translation_mm: tuple[float, float, float] = (0.3, -0.2, 0.4)
    rotation_deg: tuple[float, float, float] = (0.1, -0.15, 0.2)

    name = "block_offset"
    summary = "the block is mounted off its nominal place on the sensor (translation, rotation)"
    PARAMS = (
        Param("translation_mm", "mm", -20.0, 20.0, (0.3, -0.2, 0.4),
              "offset of the block frame, in its nominal axes; realistic: a few tenths of a mm", kind="vector", length=3),
        Param("rotation_deg", "deg", -5.0, 5.0, (0.1, -0.15, 0.2),
              "rotation vector of the block frame; realistic: 0.1-0.2 deg", kind="vector", length=3),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return not any((*self.translation_mm, *self.rotation_deg))

    @property
    def motion(self) -> np.ndarray:
        """(4, 4) true block frame in the nominal block frame."""
        rot = Rotation.from_rotvec(np.radians(self.rotation_deg)).as_matrix()
        return homogeneous(rot, np.array(self.translation_mm) * 1e-3)

    def edit_spec(self, spec, robot, lab) -> None:
        nominal = homogeneous(np.eye(3), lab.block_in_flange[:3, 3] - lab.sensor.origin_in_flange)
        true = nominal @ self.motion  # block frame in the tool body
        quat = quat_wxyz(true[:3, :3])
        cube = spec.geom("target_block")
        cube.pos = true[:3, :3] @ np.full(3, -lab.block.edge / 2) + true[:3, 3]
        cube.quat = quat
        site = spec.site("block")
        site.pos, site.quat = true[:3, 3], quat
        for name, pos in lab.block.hooks.items():
            spec.site(name).pos = true[:3, :3] @ np.array(pos) + true[:3, 3]
