"""The block's known size as a scale reference: the scanner's length scale, measured without a model.

A scanner whose length calibration is off by ``s`` reports every coordinate ``(1 + s)`` times the
true one. The displacements then scale by ``1 + s`` and the identified compliances with them: the
stiffness model tells a scale error from stiffer joints only by its rotations, which it leaves
alone, and near its detection limit the ``scanner_scale`` candidate's pattern is 96 % that of a
``block_offset`` (docs/discrepancy.md). The block itself is a length standard: its edge ``e`` is declared in
setup.json (``block_edge_m``), and every scan shows three of its faces. Each face's points reach to
its far edges, at ``-e (1 + s)`` from the fitted corner along the two in-plane axes, so the six
apparent edge lengths of a scan measure ``s`` directly.

Units: m for lengths, ppm (1e-6) for scales. Frames: the fitted block frame B (the block occupies
``[-e, 0]^3``; the scanned faces are +x, +y, +z at 0).

The estimator (:func:`apparent_edges`): for each face and in-plane axis, the points in a band from
the far edge to :data:`EDGE_BAND_M` inside the declared edge cover the band evenly on a continuous
surface, so their mean places the edge (:func:`_far_edge`). Two things keep a real scan from
that. The scanner's perspective thins the points towards the far edge, further from the scanner,
and pulls a plain mean inwards by about the band's width squared (55 ppm short with this band).
A pinhole camera's pixel grid puts one point on a plane per ``z**3`` of area (``z`` the depth
along the optical axis, the cloud's +z), so each point is weighted by ``z**3``, the area it
stands for: the band's area-weighted mean. And on the pixel grid the last row of points stops up
to a row spacing short of the edge: where an edge runs nearly along the grid's rows that error is
the same for all its points, and one edge of one scan errs by up to several thousand ppm, either
way, while most edges err by about a hundred (docs/discrepancy.md, "The scanner's scale, measured
on the block").

The check (:func:`scale_check`): each test's scale is a trimmed mean (:data:`EDGE_TRIM` cut at
each end) of its scans' edges, so an edge aligned with the grid does not carry its test; the
tests' mean against a tolerance ``|s| <= tolerance`` (a Student t over the tests, so the
pose-to-pose scatter of the grid's error is in the standard error). A lab sets the tolerance
from how well it knows its block (a machined block to 0.01 mm over 80 mm: 125 ppm) and how sharp its edges scan
(a broken edge of 0.1 mm shortens the apparent edge by about that much): the default,
:data:`SCALE_TOLERANCE_PPM`, assumes sharp edges known to 0.08 mm.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import OutOfRangeError, require_level

SCALE_TOLERANCE_PPM = 1000.0  # |s| within this is consistent with a sharp block known to 0.08 mm
SCALE_TOLERANCE_RANGE_PPM = (0.0, 30000.0)  # the band ends 3 mm (37 500 ppm) inside the declared edge
EDGE_BAND_M = 3e-3  # the band at the far edge whose points' area-weighted mean places the edge
EDGE_TRIM = 0.2  # share of a test's edge values cut at each end before their mean (module docstring)
BEYOND_WINDOW_M = 0.3e-3  # points further beyond the current edge estimate are outliers
FACE_GATE_M = 0.2e-3  # a point belongs to face k within this of its plane (or 5 times the fit's rms)
MIN_EDGE_POINTS = 50  # fewest points in the band for an edge to be measured
MIN_TESTS = 3  # fewest tests with measured edges for the check (2 degrees of freedom)
NOT_CHECKED = (
    "The scanner's scale is not checked on the block: its target is a mesh (its faces end in "
    f"chamfers), or fewer than {MIN_TESTS} tests have a scan with all six edges measured."
)
EDGES = (
    "x face along y",
    "x face along z",
    "y face along x",
    "y face along z",
    "z face along x",
    "z face along y",
)


def apparent_edges(points: np.ndarray, pose: np.ndarray, edge_m: float, rms_m=None) -> np.ndarray:
    """The six apparent edge lengths [m] of one scan of the block (:data:`EDGES` order; NaN for an
    edge with fewer than :data:`MIN_EDGE_POINTS` points near it).

    Parameters
    ----------
    points : (N, 3) array
        The cloud [m], in the scanner's camera frame (optical axis +z), the frame ``pose`` is
        given in. A cloud with a point at ``z <= 0`` is not in a camera frame: its points are
        weighted evenly.
    pose : (4, 4) array
        The fitted block frame B (``cloud.fit_block_frame``): its corner and axes.
    edge_m : float
        The declared block edge [m]; points more than 10 % beyond it (along any axis) are not the
        block's.
    rms_m : (3,) array, optional
        The fit's robust residual of each face [m]; the face gate widens to 5 times it.
    """
    points = np.asarray(points, dtype=float)
    local = pose[:3, :3].T @ (points.T - pose[:3, 3][:, None])
    # the area each point stands for on a face (module docstring): z**3 for a pinhole camera
    area = points[:, 2] ** 3 if points.size and points[:, 2].min() > 0.0 else np.ones(len(points))
    gates = np.full(3, FACE_GATE_M) if rms_m is None else np.maximum(FACE_GATE_M, 5.0 * np.asarray(rms_m))
    # within the block's box, 10 % beyond its declared edge: the mount and other clutter that lies
    # in a face's plane but off the block (about 1 % of a face's points) stay out of its bands
    in_box = np.all((local > -1.1 * edge_m) & (local < gates[:, None]), axis=0)
    out = []
    for k in range(3):
        on_face = in_box & (np.abs(local[k]) < gates[k])
        for j in (j for j in range(3) if j != k):
            mine = on_face & (local[j] < 0.0)
            out.append(_far_edge(local[j, mine], area[mine], edge_m))
    return np.array(out)


def _far_edge(u: np.ndarray, area: np.ndarray, edge_m: float) -> float:
    """Where the points ``u`` [m] (negative, the face's extent along one axis) end, NaN with too few
    points near the end; ``area`` weights each point by the face area it stands for.

    The band ``(-L - w, -edge_m + b)`` ends at a fixed place (:data:`EDGE_BAND_M` inside the
    declared edge), so for points that cover it evenly from ``-L`` its area-weighted mean is
    ``(-L - edge_m + b) / 2`` and ``L = b - edge_m - 2 mean``: unbiased, its noise twice the
    mean's. Its start, a little past the current ``L`` (:data:`BEYOND_WINDOW_M`), only leaves out
    points far beyond the edge (outliers); ``L`` starts from a low quantile and is iterated so that
    start stays past it. (A band placed from the estimate itself, ``(-L, -L + b)``, moves with it
    and is biased, -5 um on these faces.)"""
    if u.size < MIN_EDGE_POINTS:
        return float("nan")
    end = -float(np.quantile(u, 0.002))
    for _ in range(3):
        band = (u > -end - BEYOND_WINDOW_M) & (u < -edge_m + EDGE_BAND_M)
        if np.count_nonzero(band) < MIN_EDGE_POINTS:
            return float("nan")
        end = EDGE_BAND_M - edge_m - 2.0 * float(np.average(u[band], weights=area[band]))
    return end


@dataclass(frozen=True)
class ScaleCheck:
    """The scanner's length scale from the block's apparent edges, against a tolerance.

    Attributes
    ----------
    scale_ppm, std_ppm : float
        The mean of the tests' scales (each the trimmed mean, :data:`EDGE_TRIM`, over its scans and
        edges of ``L / e - 1``) and its standard error [ppm].
    interval_ppm : (float, float)
        Its 95 % interval (Student t, ``n_tests - 1`` degrees of freedom).
    n_tests : int
    tolerance_ppm : float
        ``|s|`` up to this is consistent with the block and its edges as declared.
    p_value : float
        Of ``|s| <= tolerance`` (one-sided t at the nearer bound).
    beyond : bool
        ``p_value`` below the level the check was run at.
    """

    scale_ppm: float
    std_ppm: float
    interval_ppm: tuple
    n_tests: int
    tolerance_ppm: float
    p_value: float
    beyond: bool

    def to_dict(self) -> dict:
        return {**asdict(self), "interval_ppm": list(self.interval_ppm)}

    @classmethod
    def from_dict(cls, data: dict) -> ScaleCheck:
        """The check as :meth:`to_dict` (a report's ``scale_check``) wrote it."""
        return cls(**{**data, "interval_ppm": tuple(data["interval_ppm"])})

    def sentence(self) -> str:
        """One sentence for the report: the estimate, its interval, and what the check says."""
        lo, hi = self.interval_ppm
        where = (
            f"The block's apparent edges put the scanner's length scale at {self.scale_ppm:+.0f} ppm "
            f"(95 % interval {lo:+.0f} to {hi:+.0f} ppm over the {self.n_tests} tests; the edge estimate itself "
            f"may be off by about 10 ppm, which the tolerance of {self.tolerance_ppm:g} ppm for the block's size "
            "and edges covers)"
        )
        if self.beyond:
            return (f"{where}: beyond the tolerance (p = {self.p_value:.2g}): a scanner scale error "
                    "(`scanner_scale`), or a block that is not the size setup.json says.")  # fmt: skip
        if max(abs(lo), abs(hi)) <= self.tolerance_ppm:
            return (f"{where}: within it; with it, a scale error larger than "
                    f"{max(abs(lo), abs(hi)) + self.tolerance_ppm:.0f} ppm is ruled out (95 %).")  # fmt: skip
        return (f"{where}: not shown beyond it (p = {self.p_value:.2g}), nor within it: the tests scatter too "
                "much, or are too few, to tell.")  # fmt: skip


def require_tolerance(tolerance_ppm: float) -> None:
    """Raise OutOfRangeError unless ``tolerance_ppm`` is in :data:`SCALE_TOLERANCE_RANGE_PPM`."""
    lo, hi = SCALE_TOLERANCE_RANGE_PPM
    if not lo <= tolerance_ppm <= hi:
        raise OutOfRangeError(f"scale tolerance = {tolerance_ppm:g} ppm must be in [{lo:g}, {hi:g}] ppm")


def scale_check(
    edges, edge_m: float, alpha: float, tolerance_ppm: float = SCALE_TOLERANCE_PPM
) -> ScaleCheck | None:
    """The scale check over a dataset's tests.

    Parameters
    ----------
    edges : sequence of (S, 6) arrays or None
        Per test, its scans' apparent edges [m] (:func:`apparent_edges`); None: not measured. A
        scan with an unmeasured edge (NaN) is left out.
    edge_m : float
        The declared block edge [m].
    alpha : float
        The check's level, in (0, 1).
    tolerance_ppm : float
        The tolerance [ppm], in :data:`SCALE_TOLERANCE_RANGE_PPM`.

    Returns
    -------
    ScaleCheck or None
        None when fewer than :data:`MIN_TESTS` tests have a scan with all six edges measured.
    """
    from scipy import stats  # here: the command line imports this module's constants, not scipy

    require_level(alpha)
    require_tolerance(tolerance_ppm)
    per_test = []
    for test in edges:
        values = None if test is None else np.asarray(test, dtype=float)
        if values is not None:  # scans with all six edges (each edge has its own grid error)
            whole = values[np.isfinite(values).all(axis=1)]
            if len(whole):
                per_test.append(float(stats.trim_mean((whole / edge_m - 1.0).ravel(), EDGE_TRIM)) * 1e6)
    n = len(per_test)
    if n < MIN_TESTS:
        return None
    mean, se = float(np.mean(per_test)), float(np.std(per_test, ddof=1) / np.sqrt(n))
    half = float(stats.t.ppf(0.975, n - 1)) * se
    excess = abs(mean) - tolerance_ppm
    p = float(stats.t.sf(excess / se, n - 1)) if se > 0 else float(excess <= 0)
    return ScaleCheck(mean, se, (mean - half, mean + half), n, float(tolerance_ppm), p, bool(p < alpha))


DECIDE_Z = 2.05  # a round sized for the check aims at a decision with 98 % power (one-sided normal)


def tests_to_decide(check: ScaleCheck, alpha: float, z: float = DECIDE_Z, limit: int = 50) -> int:
    """How many more tests, as scattered as the check's, it takes for the check to decide with
    ``z`` standard errors to spare, were its estimate the truth: the size of a round meant to
    settle the scale (``discover --separation``). 0 where the margin is there already.

    Beyond the tolerance the margin is ``|s| - tolerance`` against the one-sided threshold at
    ``alpha``; within it, ``tolerance - |s|`` against the 95 % interval's half-width (what
    rules the scale out). The tests' scatter is the check's standard error times
    ``sqrt(n_tests)``, so ``n`` more tests divide the standard error by ``sqrt(1 + n / n_tests)``.

    Parameters
    ----------
    check : ScaleCheck
    alpha : float
        The level the next check runs at, in (0, 1).
    z : float
        The standard errors to spare (:data:`DECIDE_Z`: 98 % power at the estimate).
    limit : int
        The largest answer (a round's largest size).
    """
    from scipy import stats  # here: the command line imports this module's constants, not scipy

    require_level(alpha)
    margin = abs(check.scale_ppm) - check.tolerance_ppm
    scatter = check.std_ppm * np.sqrt(check.n_tests)
    for extra in range(limit + 1):
        n = check.n_tests + extra
        quantile = stats.t.ppf(1 - alpha, n - 1) if margin > 0 else stats.t.ppf(0.975, n - 1)
        if abs(margin) >= (quantile + z) * scatter / np.sqrt(n):
            return extra
    return limit
