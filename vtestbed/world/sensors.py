"""Measurement-chain models: the 6-axis force/torque sensor.

The true wrench comes from MuJoCo (:attr:`vtestbed.world.rig.RigState.sensor_wrench`); a sensor
adds its bias and noise and refuses a wrench outside its measuring range
(:meth:`vtestbed.lab.ForceSensorSpec.check`), as the real one saturates. Units: N and N*m, in
the sensor frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..lab import ForceSensorSpec

# ATI SI-330-30 resolution (1/16 N, 1/528 N*m), taken as the noise standard deviation.
DEFAULT_NOISE_STD = (0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019)
NO_BIAS = (0.0,) * 6


@dataclass(frozen=True)
class ForceTorqueSensor:
    """A 6-axis F/T sensor: reading = true + bias + N(0, noise_std^2), range-checked.

    ``noise_std`` and ``bias`` are (Fx, Fy, Fz, Tx, Ty, Tz) in N and N*m. The bias is the
    same for every reading (a zero offset); the identification works on loaded minus unloaded
    readings, which cancels it.
    """

    spec: ForceSensorSpec = field(default_factory=ForceSensorSpec)
    noise_std: tuple[float, ...] = DEFAULT_NOISE_STD
    bias: tuple[float, ...] = NO_BIAS

    def read(self, true_wrench, rng: np.random.Generator | None) -> np.ndarray:
        """One reading (6,) of ``true_wrench`` (6,); ``rng=None`` gives a noise-free reading."""
        true_wrench = self.spec.check(true_wrench, "true wrench at the sensor")
        reading = true_wrench + np.asarray(self.bias)
        if rng is not None:
            reading = reading + rng.normal(0.0, 1.0, 6) * np.asarray(self.noise_std)
        return self.spec.check(reading, "force sensor reading")
