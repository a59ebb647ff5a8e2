"""Measurement-chain effects: a misaligned or drifting force sensor, a mis-scaled scanner.

They change what the instruments report, not the physics: the rig's equilibrium is the clean
one, and the sensor (or scanner) reports it wrongly. Wrenches are (Fx, Fy, Fz, Tx, Ty, Tz)
[N, N*m] in the sensor frame about its origin; points are (N, 3) [m] in the scanner frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .base import Param, WorldEffect


@dataclass(frozen=True)
class FtMisalignment(WorldEffect):
    """The sensor is mounted rotated by (roll, pitch, yaw) from its nominal frame in setup.json.

    The true measurement frame is ``R = Rz(yaw) Ry(pitch) Rx(roll)`` relative to the nominal one
    (same origin), so a wrench ``w`` in the nominal frame reads ``[R^T f, R^T t]``.
    """

    roll_pitch_yaw_deg: tuple[float, float, float] = (0.0, 0.0, 1.5)

    name = "ft_misalignment"
    summary = "the force sensor is mounted rotated from its nominal frame (readings in a rotated frame)"
    PARAMS = (
        Param("roll_pitch_yaw_deg", "deg", -20.0, 20.0, (0.0, 0.0, 1.5),
              "mounting rotation; realistic: 1.5 deg of yaw (a dowel-less bolt circle)", kind="vector", length=3),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return not any(self.roll_pitch_yaw_deg)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) true sensor axes in the nominal sensor frame."""
        roll, pitch, yaw = np.radians(self.roll_pitch_yaw_deg)
        return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()

    def wrench_reading(self, wrench: np.ndarray, phase: str) -> np.ndarray:
        rot = self.rotation
        return np.concatenate([rot.T @ wrench[:3], rot.T @ wrench[3:]])


@dataclass(frozen=True)
class FtBiasDrift(WorldEffect):
    """The sensor's zero drifts between the unloaded and the loaded reading (thermal drift)."""

    drift_N_Nm: tuple[float, ...] = (0.2, 0.2, 0.4, 0.01, 0.01, 0.01)

    name = "ft_bias_drift"
    summary = "the force sensor's bias changes between the unloaded and the loaded reading"
    PARAMS = (
        Param("drift_N_Nm", "N, N*m", -50.0, 50.0, (0.2, 0.2, 0.4, 0.01, 0.01, 0.01),
              "change of the bias (Fx..Tz) from the unloaded to the loaded reading; realistic: a few "
              "resolution steps of the SI-330-30 over the minutes a test takes", kind="vector", length=6),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return not any(self.drift_N_Nm)

    def wrench_reading(self, wrench: np.ndarray, phase: str) -> np.ndarray:
        return wrench + np.asarray(self.drift_N_Nm) if phase == "loaded" else wrench


@dataclass(frozen=True)
class ScannerScale(WorldEffect):
    """A length-calibration error: every reported coordinate is (1 + scale) times the true one."""

    scale_ppm: float = 100.0

    name = "scanner_scale"
    summary = "a length scale error of the scanner's calibration (about its optical centre)"
    PARAMS = (
        Param("scale_ppm", "ppm", -1e4, 1e4, 100.0,
              "scale error; realistic: 100 ppm, 0.02 mm over the 200 mm the block spans at 0.6 m"),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return self.scale_ppm == 0.0

    def scan_points(self, points: np.ndarray) -> np.ndarray:
        return points * (1.0 + self.scale_ppm * 1e-6)
