"""The scanner's measurement errors, drawn on a fixed ray-cast geometry.

A scan is cast once (:class:`ScanGeometry`, deterministic, scanner frame, metres) and then
noised (:meth:`ScanNoise.sample`, with an explicit ``numpy.random.Generator``), so Monte Carlo
runs redraw the noise on one geometry. Defaults follow the VTOP 200B datasheet (paper Table 3)
plus the assumptions stated on each field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, check_range
from ..transforms import homogeneous, matrix_from_rotation_vector


@dataclass(frozen=True, eq=False)
class ScanGeometry:
    """Noise-free hits of one scan, in the scanner frame (the deterministic half of a scan)."""

    points_m: np.ndarray  # (N, 3) hit points [m]
    directions: np.ndarray  # (N, 3) unit ray directions
    normals: np.ndarray  # (N, 3) outward unit surface normals at the hits
    geom_ids: np.ndarray  # (N,) MuJoCo geom of each hit (truth-side information, not in a lab scan)
    ray_index: np.ndarray  # (N,) row of Scanner.ray_directions of each hit

    def __len__(self) -> int:
        return len(self.points_m)

    @property
    def cos_incidence(self) -> np.ndarray:
        """(N,) cosine of the angle between each ray and the surface normal."""
        return np.clip(-np.einsum("ij,ij->i", self.directions, self.normals), 0.0, 1.0)

    def take(self, selection) -> ScanGeometry:
        """The hits selected by a boolean mask or index array."""
        return ScanGeometry(
            *(
                a[selection]
                for a in (self.points_m, self.directions, self.normals, self.geom_ids, self.ray_index)
            )
        )


@dataclass(frozen=True, eq=False)
class NoisyScan:
    """A noisy scan: the points, which hits they come from, and the drift drawn for it."""

    points_m: np.ndarray  # (M, 3) m, scanner frame as the (drifted) scanner reports it
    hit_index: np.ndarray  # (M,) row of the ScanGeometry each point comes from (dropouts removed)
    outlier: np.ndarray  # (M,) bool, the point is an outlier
    drift: np.ndarray  # (4, 4) D: reported point = D @ true point


# Each parameter's valid range and unit, stated once: ScanNoise checks them and a scenario's
# [scanner.noise_params] names them in its errors. dropout_full_deg is also >= dropout_start_deg.
NOISE_PARAM_RANGES: dict[str, tuple[float, float, str]] = {
    "range_std_m": (0.0, 1e-3, "m"),
    "grazing_exponent": (0.0, 4.0, ""),
    "dropout_start_deg": (0.0, 90.0, "deg"),
    "dropout_full_deg": (0.0, 90.0, "deg"),
    "outlier_fraction": (0.0, 0.5, ""),
    "outlier_range_m": (0.0, 0.1, "m"),
    "drift_translation_std_m": (0.0, 1e-3, "m"),
    "drift_rotation_std_rad": (0.0, 1e-2, "rad"),
}


@dataclass(frozen=True)
class ScanNoise:
    """Measurement errors of the structured-light scanner. Defaults: VTOP 200B datasheet + assumptions.

    Parameters
    ----------
    range_std_m : float
        Standard deviation [m] of the per-point error along the ray at normal incidence. Default
        0.010 mm: the datasheet's "scanning accuracy 0.010-0.015 mm" (paper Table 3).
    grazing_exponent : float
        The along-ray std grows as ``range_std_m / cos(theta)**grazing_exponent`` with the incidence
        angle theta (the projected fringes widen on an inclined surface); the error normal to the
        surface is then ``range_std_m * cos(theta)**(1 - grazing_exponent)``. Default 1.5 (an
        assumption): 0.013 mm normal to a face seen at 55 deg, inside the datasheet's range.
    dropout_start_deg, dropout_full_deg : float
        Incidence angles [deg] between which the probability of losing a point rises linearly from 0
        to 1 (steep faces return too little light). Defaults 70 and 85 deg (assumption).
    outlier_fraction : float
        Fraction of points replaced by outliers (phase-unwrapping errors, multipath): moved along
        their ray by a uniform offset in ``[-outlier_range_m, outlier_range_m]``. Default 0.1 %.
    outlier_range_m : float
        Default 5 mm.
    drift_translation_std_m, drift_rotation_std_rad : float
        Standard deviation per axis of a rigid drift of the scanner frame drawn once per scan
        (thermal drift, tripod settling). It moves every point of a scan alike, so it does not
        average out over points. Defaults 3 um and 5 urad (assumptions: the datasheet gives none).
    """

    range_std_m: float = 0.010e-3
    grazing_exponent: float = 1.5
    dropout_start_deg: float = 70.0
    dropout_full_deg: float = 85.0
    outlier_fraction: float = 0.001
    outlier_range_m: float = 5e-3
    drift_translation_std_m: float = 3e-6
    drift_rotation_std_rad: float = 5e-6

    def __post_init__(self):
        for name, (low, high, unit) in NOISE_PARAM_RANGES.items():
            check_range(name, getattr(self, name), low, high, unit)
        # the one range that depends on another field: the dropout ramp must not run backwards
        check_range("dropout_full_deg", self.dropout_full_deg, self.dropout_start_deg, 90.0, "deg")

    @classmethod
    def perfect(cls) -> ScanNoise:
        """A scanner without any error (no noise, dropout, outlier or drift)."""
        return cls(0.0, 0.0, 90.0, 90.0, 0.0, 0.0, 0.0, 0.0)

    def along_ray_std(self, cos_incidence: np.ndarray) -> np.ndarray:
        """(N,) std [m] of the along-ray error at the given incidence cosines."""
        cos_min = np.cos(np.radians(self.dropout_full_deg))
        return self.range_std_m / np.maximum(cos_incidence, cos_min) ** self.grazing_exponent

    def sample(self, hits: ScanGeometry, rng: np.random.Generator) -> NoisyScan:
        """Draw one noisy scan of ``hits``. The draws are in a fixed order: same seed, same scan."""
        if not isinstance(rng, np.random.Generator):
            raise OutOfRangeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        n = len(hits)
        drift_rotvec = rng.standard_normal(3) * self.drift_rotation_std_rad
        drift_trans = rng.standard_normal(3) * self.drift_translation_std_m
        gauss, u_drop, u_out, u_off = rng.standard_normal(n), rng.random(n), rng.random(n), rng.random(n)
        cos_i = hits.cos_incidence
        p_drop = self._dropout_probability(cos_i)
        offset = gauss * self.along_ray_std(cos_i)
        outlier = u_out < self.outlier_fraction
        offset[outlier] = (2 * u_off[outlier] - 1) * self.outlier_range_m
        keep = np.flatnonzero(u_drop >= p_drop)
        points = hits.points_m + offset[:, None] * hits.directions
        if len(keep) < n:
            points = points[keep]
        drift = homogeneous(matrix_from_rotation_vector(drift_rotvec), drift_trans)
        return NoisyScan(_rigid(drift, points), keep, outlier[keep], drift)

    def _dropout_probability(self, cos_incidence: np.ndarray) -> np.ndarray:
        """(N,) probability of losing each point. Only rays that may lie beyond
        ``dropout_start_deg`` need the arccos (a margin keeps the boundary exact); the rest are 0."""
        p_drop = np.zeros(len(cos_incidence))
        near = np.flatnonzero(cos_incidence < np.cos(np.radians(self.dropout_start_deg)) + 1e-9)
        if near.size:
            theta = np.degrees(np.arccos(cos_incidence[near]))
            span = max(self.dropout_full_deg - self.dropout_start_deg, 1e-12)
            p_drop[near] = np.clip((theta - self.dropout_start_deg) / span, 0.0, 1.0)
        return p_drop

    def apply(self, hits: ScanGeometry, rng: np.random.Generator) -> np.ndarray:
        """(M, 3) noisy points [m] of one scan of ``hits`` (see :meth:`sample`)."""
        return self.sample(hits, rng).points_m


def _rigid(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``pose`` (4, 4) applied to ``points`` (N, 3), one output column at a time: four times
    faster than ``points @ R.T + t`` here (numpy's matmul takes a slow path for a 3x3 right
    factor), equal to it within an ulp."""
    out = np.empty_like(points)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    for row in range(3):
        rot = pose[row, :3]
        out[:, row] = x * rot[0] + y * rot[1] + z * rot[2] + pose[row, 3]
    return out


def scaled_noise(noise: ScanNoise, scale: float) -> ScanNoise:
    """``noise`` with its per-point range std and its drift stds multiplied by ``scale``.

    Outliers and dropouts are unchanged: they are rejected by the cloud pipeline, not averaged.
    """
    return dataclasses.replace(
        noise,
        range_std_m=noise.range_std_m * scale,
        drift_translation_std_m=noise.drift_translation_std_m * scale,
        drift_rotation_std_rad=noise.drift_rotation_std_rad * scale,
    )
