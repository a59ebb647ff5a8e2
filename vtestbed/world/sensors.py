"""Measurement-chain models: the 6-axis force/torque sensor.

The true wrench comes from MuJoCo (:attr:`vtestbed.rig.RigState.sensor_wrench`); a sensor adds
its bias and noise and refuses a wrench outside its measuring range, as the real one saturates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SensorOverloadError
from ..lab import ForceSensorSpec

AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
UNITS = ("N", "N", "N", "N*m", "N*m", "N*m")


def check_wrench_range(wrench, spec: ForceSensorSpec, field_name: str = "wrench") -> np.ndarray:
    """Return ``wrench`` (6,) or raise :class:`SensorOverloadError` naming the axis and range."""
    wrench = np.asarray(wrench, dtype=float)
    if wrench.shape != (6,) or not np.all(np.isfinite(wrench)):
        raise SensorOverloadError(f"{field_name} must be 6 finite numbers (Fx..Tz), got {wrench!r}")
    for axis, unit, value, limit in zip(AXES, UNITS, wrench, spec.wrench_range):
        if abs(value) > limit:
            raise SensorOverloadError(
                f"{field_name}: {axis} = {value:.2f} {unit} is outside the measuring range "
                f"[-{limit:g}, {limit:g}] {unit} of the {spec.name}"
            )
    return wrench


@dataclass(frozen=True)
class ForceTorqueSensor:
    """A 6-axis F/T sensor: reading = true + bias + N(0, noise_std^2), range-checked.

    ``noise_std`` and ``bias`` are (Fx, Fy, Fz, Tx, Ty, Tz) in N and N*m. The bias is the
    same for every reading (a zero offset); the identification works on loaded minus unloaded
    readings, which cancels it. Defaults: ATI SI-330-30 resolution (1/16 N, 1/528 N*m)
    taken as the noise standard deviation.
    """

    spec: ForceSensorSpec = field(default_factory=ForceSensorSpec)
    noise_std: tuple[float, ...] = (0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019)
    bias: tuple[float, ...] = (0.0,) * 6

    def read(self, true_wrench, rng: np.random.Generator | None) -> np.ndarray:
        """One reading (6,) of ``true_wrench`` (6,); ``rng=None`` gives a noise-free reading."""
        true_wrench = check_wrench_range(true_wrench, self.spec, "true wrench at the sensor")
        reading = true_wrench + np.asarray(self.bias)
        if rng is not None:
            reading = reading + rng.normal(0.0, 1.0, 6) * np.asarray(self.noise_std)
        return check_wrench_range(reading, self.spec, "force sensor reading")
