"""Load creep: the loaded block keeps moving while the wire stays tensioned.

A joint's reducer, its bearings and the wire's anchorage settle under a sustained load, so the
deflection a scan of the loaded block sees grows with the time since the wire was tightened.
The effect moves the block on, in the direction of the test's elastic displacement, by
``rate_percent`` of it per scan of the loaded block: the test's own loaded scan (scan 0) sees
the elastic equilibrium, loaded repeat ``k`` the block ``k * rate`` farther. The wire's tension
and the F/T reading are left as they are (a creep of a few um changes a 200 N wire load by far
less than the sensor resolves). It acts only on repeat scans of the loaded block
(``[scanner] loaded_repeats``); without them a dataset is the clean world's, bit for bit.
Units: rate in percent of the elastic displacement per scan; motions in m and rad, block frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import Param, WorldEffect

__all__ = ["LoadCreep"]


@dataclass(frozen=True)
class LoadCreep(WorldEffect):
    """The loaded deflection creeps on by ``rate_percent`` of itself per scan of the loaded block."""

    rate_percent: float = 0.5

    name = "load_creep"
    summary = "the loaded block creeps on between successive scans of it (seen by loaded repeats only)"
    PARAMS = (
        Param("rate_percent", "%", 0.0, 20.0, 0.5,
              "further deflection per scan of the loaded block, in percent of the test's elastic one; "
              "no measured value for the KR60's reducers: 0.5 % moves the block about 3.7 um and 10 urad "
              "per scan on the paper's tests, the scanner's own noise per scan (docs/effects.md)"),
    )  # fmt: skip

    @property
    def is_null(self) -> bool:
        return self.rate_percent == 0.0

    def loaded_motion(self, displacement: np.ndarray, scan: int) -> np.ndarray | None:
        return np.asarray(displacement, dtype=float) * (self.rate_percent / 100.0) * scan
