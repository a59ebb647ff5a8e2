"""A model-free noise floor: the displacement-noise covariance from repeat scans of a static block.

Why: the default FGLS estimator takes its weights from its own residuals, so its reduced chi^2
is 1 by construction and nothing can be detected against it. A lab gets an independent noise
floor by scanning the unloaded block ``r`` more times without touching anything (the dataset's
``repeats.csv``). Nothing moves between those scans, so the difference of any two of them is
pure measurement noise, and it has exactly the noise of a measured displacement (which is also
the difference of two independent scans): its covariance estimates the displacement-noise
covariance with no model at all.

Frames and units: every scan is reduced by the researcher's own pipeline
(:mod:`.repeat_scans` for a dataset's repeats.csv): each repeat exactly as the test's unloaded
scan, from the kinematic nominal pose. A scan's deviation
is ``e_i = displacement_in_block_frame(F_0, F_i)`` with ``F_0`` the test's unloaded frame:
components x, y, z [m] and rx, ry, rz [rad] in the unloaded block frame, those of a measured
displacement.

How the repeats are paired (the estimator): a test with ``n = r + 1`` scans (the unloaded scan
and ``r`` repeats) gives the displacements ``d_jk = e_k - e_j`` of all ``n (n - 1) / 2`` pairs.
Pairs that share a scan are correlated: the star ``d_0k`` (each repeat against the unloaded
scan) has correlation 1/2 between any two members, so for Gaussian noise its variance estimate
is worth at most 4 independent pairs per test however many repeats are taken; disjoint pairs
alone are independent but use only ``floor(n / 2)`` of the ``r`` degrees of freedom. Averaging
``d d^T`` over all pairs is exact algebra for twice the within-test sample covariance of the
``e_i`` (``sum_{j<k} d_jk d_jk^T = n sum_i (e_i - mean e)(e_i - mean e)^T``), the
minimum-variance unbiased estimate for Gaussian noise, with ``r`` degrees of freedom per test.
The tests are pooled weighted by their degrees of freedom; ``n_samples = sum_t r_t`` is the
effective number of independent displacement samples (one repeat per test is one pair).

The mean: the pairs' displacements are not mean-subtracted. Two scans of a static block are
exchangeable, so ``d_jk`` and ``d_kj = -d_jk`` have the same distribution and the mean is zero
by construction; any systematic error of the fit that is the same in every scan of a geometry
cancels in the difference. Subtracting a sample mean of the displacements would spend degrees
of freedom on a quantity known to be zero. (Within a test the pairing does remove the mean of
the ``e_i``, the unknown true frame: that is the one degree of freedom each test loses.)

What it covers: the scanner's noise (per-point noise, dropouts, outliers, per-scan drift)
through the cloud fit, averaged over the tests with repeats (the noise differs between poses:
by up to about +-20 % per component between the paper's tests). It does not see the F/T sensor's
noise, which enters the model's prediction instead: :mod:`.reading_noise` adds it as the known
``reading_covariance`` where setup.json states it. Nor does it see noise that only appears when
the robot moves between scans (a real lab's backlash, re-settling).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError, OutOfRangeError
from ..transforms import DISPLACEMENT_COMPONENTS as COMPONENTS
from ..transforms import displacement_in_block_frame

__all__ = [
    "COMPONENTS",
    "NoiseFloor",
    "noise_floor_from_frames",
    "scan_deviations",
]


def _scan_mean_scale(scans: int, loaded_scans: int) -> float:
    """The single-scan floor's factor for a displacement from the mean of ``scans`` unloaded to the
    mean of ``loaded_scans`` loaded scans: ``(1 / m + 1 / m') / 2`` (:meth:`NoiseFloor.for_scan_mean`)."""
    return (1.0 / scans + 1.0 / loaded_scans) / 2.0


@dataclass(frozen=True, eq=False)
class NoiseFloor:
    """The displacement-noise covariance estimated from repeat scans (block frame, SI).

    Attributes
    ----------
    covariance : (6, 6) array
        Covariance of a measured displacement's noise, components x, y, z [m], rx, ry, rz [rad]
        in the unloaded block frame, pooled over the tests with repeats.
    n_samples : int
        Degrees of freedom: the number of independent displacement samples it is worth
        (``sum_t r_t`` over the tests, ``r_t`` repeats each).
    n_tests : int
        Tests with at least one repeat.
    test_ids : tuple of str
        Those tests.
    reference_scans : int
        The unloaded scans each displacement is measured against: 1 (the estimate, a single-scan
        displacement's floor) or ``m`` after :meth:`for_scan_mean`, whose covariance is the
        floor of a displacement against the mean of ``m`` unloaded scans.
    loaded_scans : int
        The loaded scans averaged at the other end of each displacement: 1 (the test's own) or
        ``m'`` after :meth:`for_scan_mean` with loaded repeats.
    loaded_scatter : LoadedScatter or None
        Whether the loaded repeats scatter like the unloaded ones (:mod:`.loaded_scatter`, a
        check for creep) and whether they were left out for it, set by
        :func:`.scan_mean.against_scan_mean`; None without loaded repeats.
    """

    covariance: np.ndarray
    n_samples: int
    n_tests: int
    test_ids: tuple[str, ...] = ()
    reference_scans: int = 1  # unloaded scans averaged into each displacement (:meth:`for_scan_mean`)
    loaded_scans: int = 1  # loaded scans averaged into each displacement
    # a .loaded_scatter.LoadedScatter when the loaded block was scanned again (:func:`.scan_mean.against_scan_mean`)
    loaded_scatter: object = None
    # (6, 6) the F/T readings' noise in the model's prediction [m, rad], known rather than
    # estimated (:mod:`.reading_noise`); None: not known. The model is tested against the sum.
    reading_covariance: np.ndarray | None = None

    def for_scan_mean(self, scans: int, loaded_scans: int = 1) -> NoiseFloor:
        """The floor of a displacement measured from the mean of ``scans`` unloaded scans to the
        mean of ``loaded_scans`` loaded ones.

        A displacement is the loaded scan's frame minus the unloaded one's: with per-scan
        covariance ``S`` it has ``2 S``, the floor estimated from pairs of repeats. From the mean
        of ``m`` unloaded scans to the mean of ``m'`` loaded ones it has ``S (1 / m + 1 / m')``, so
        the floor scales by ``(1 / m + 1 / m') / 2``: 0.625 with a test's unloaded scan and 3
        repeats (1.6 times the information per test), 0.25 with 3 repeats of the loaded block too
        (4 times). The sample count stays: the scale is known, not estimated.
        (:mod:`.scan_mean` builds such displacements.)
        """
        if self.reference_scans != 1 or self.loaded_scans != 1:
            raise OutOfRangeError(
                f"this floor is already for a mean of {self.reference_scans} unloaded and "
                f"{self.loaded_scans} loaded scans"
            )
        for name, value in (("scans", scans), ("loaded_scans", loaded_scans)):
            if int(value) != value or value < 1:
                raise OutOfRangeError(f"{name} = {value!r} must be an integer >= 1 (1: the test's own scan)")
        return dataclasses.replace(
            self,
            covariance=self.covariance * _scan_mean_scale(scans, loaded_scans),
            reference_scans=int(scans),
            loaded_scans=int(loaded_scans),
        )

    @property
    def displacement_covariance(self) -> np.ndarray:
        """(6, 6) the scans' covariance plus the readings' (``reading_covariance``, if known)."""
        return (
            self.covariance if self.reading_covariance is None else self.covariance + self.reading_covariance
        )

    @property
    def reading_std(self) -> np.ndarray | None:
        """(6,) the readings' part's std per component [m, rad], or None when not known."""
        return None if self.reading_covariance is None else np.sqrt(np.diag(self.reading_covariance))

    @property
    def component_std(self) -> np.ndarray:
        """(6,) standard deviation per component [m, m, m, rad, rad, rad]."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray:
        """(6, 6) correlation matrix (a component with zero std has zero correlation, 1 on the diagonal)."""
        std = self.component_std
        outer = np.outer(std, std)
        corr = np.divide(self.covariance, outer, out=np.zeros((6, 6)), where=outer > 0)
        np.fill_diagonal(corr, 1.0)
        return corr

    @property
    def relative_std_uncertainty(self) -> float:
        """Approximate relative standard error of each ``component_std``: ``1 / sqrt(2 n_samples)``.

        Gaussian noise and tests of equal noise; tests of different noise levels make it larger.
        """
        return float(1.0 / np.sqrt(2.0 * self.n_samples))

    def chi2(self, residuals) -> float:
        """Sum over tests of ``r_t^T Sigma^-1 r_t`` for displacement residuals measured - predicted.

        Parameters
        ----------
        residuals : array (T, 6) or (6 T,)
            Per test x, y, z [m], rx, ry, rz [rad] in the block frame (as
            ``IdentificationResult.residuals``).

        Raises
        ------
        OutOfRangeError
            A residual array that is not 6 per test, or a singular floor (a perfect scanner).
        """
        res = np.asarray(residuals, dtype=float)
        if res.size == 0 or res.size % 6:
            raise OutOfRangeError(f"residuals must have 6 components per test, got shape {res.shape}")
        res = res.reshape(-1, 6)
        std = self.component_std
        if np.any(std <= 0):
            raise OutOfRangeError(
                "the noise floor is singular (zero std in "
                f"{', '.join(c for c, s in zip(COMPONENTS, std) if s <= 0)}): a perfect scanner has no chi^2"
            )
        # whiten in the correlation's eigenbasis, scaled per component (m and rad differ by 1e0..1e3)
        corr_inv = np.linalg.inv(self.correlation)
        white = res / std
        return float(np.einsum("ti,ij,tj->", white, corr_inv, white))

    def reduced_chi2(self, residuals, n_parameters: int) -> float:
        """``chi2(residuals) / (residuals.size - n_parameters)``: about 1 when model and floor agree.

        Against an estimated floor (``n_samples = nu`` degrees of freedom) its expectation under
        a right model is about ``nu / (nu - 7)`` (the mean of an inverse Wishart matrix in 6
        dimensions: 1.13 at nu = 60, 1.04 at 200), and it scatters by at least
        ``sqrt(2 / dof)`` (relative). On the paper scenario (20 tests, dof 114): 1.11 +- 0.15 at
        r = 3 repeats, 1.06 +- 0.15 at r = 10 (``benchmarks/bench_noise_floor.py``).
        """
        res = np.asarray(residuals, dtype=float)
        dof = res.size - int(n_parameters)
        if dof <= 0:
            raise OutOfRangeError(
                f"n_parameters = {n_parameters} leaves no degree of freedom in {res.size} residuals"
            )
        return self.chi2(res) / dof

    def as_dict(self) -> dict:
        return {
            "covariance": self.covariance.tolist(),
            "component_std": self.component_std.tolist(),
            "n_samples": self.n_samples,
            "n_tests": self.n_tests,
            "test_ids": list(self.test_ids),
            "reference_scans": self.reference_scans,
            "loaded_scans": self.loaded_scans,
            "loaded_scatter": self.loaded_scatter and self.loaded_scatter.to_dict(),
            **({} if self.reading_std is None else {"reading_std": self.reading_std.tolist()}),
        }

    def summary(self) -> str:
        """One line: per-component std in um and urad, and the sample count."""
        std = self.component_std * 1e6
        return (
            f"noise floor from repeat scans: std x y z {std[0]:.2f} {std[1]:.2f} {std[2]:.2f} um, "
            f"rx ry rz {std[3]:.2f} {std[4]:.2f} {std[5]:.2f} urad ({self.n_samples} samples from "
            f"{self.n_tests} tests, each std +-{self.relative_std_uncertainty * 100:.0f} %)"
            + (
                f"; displacements from the mean of {self.reference_scans} unloaded scans to the mean of "
                f"{self.loaded_scans} loaded: covariance x {_scan_mean_scale(self.reference_scans, self.loaded_scans):.3g}"
                if self.reference_scans > 1 or self.loaded_scans > 1
                else ""
            )
            + (
                f"; loaded repeats left out: they scatter up to {max(self.loaded_scatter.ratio):.2f} times the "
                f"unloaded scans' variance (creep check p = {self.loaded_scatter.p_value:.2g})"
                if self.loaded_scatter is not None and self.loaded_scatter.left_out
                else ""
            )
        )


def scan_deviations(frames: Sequence[np.ndarray]) -> np.ndarray:
    """(n, 6) ``displacement_in_block_frame(F_0, F_i)`` of each frame from the first [m, rad]."""
    return np.array([displacement_in_block_frame(frames[0], f) for f in frames])


def noise_floor_from_frames(
    frames_by_test: Mapping[str, Sequence[np.ndarray]], where: str = "", state: str = "unloaded"
) -> NoiseFloor:
    """Pool the repeat scans of several tests into one :class:`NoiseFloor` (all pairs per test).

    Parameters
    ----------
    frames_by_test : mapping test_id -> sequence of (4, 4) arrays
        Per test, the fitted frames of the unloaded scan and its repeats (any one fixed frame).
        Tests with a single scan are skipped.
    where, state : str
        What holds the scans (a dataset's repeats file) and which block they show, for an error message.

    Raises
    ------
    OutOfRangeError
        No test has two scans.
    """
    total, dof, ids, copies = np.zeros((6, 6)), 0, [], []
    for tid, frames in frames_by_test.items():
        n = len(frames)
        if n < 2:
            continue
        e = scan_deviations(frames)
        j, k = np.triu_indices(n, 1)
        d = e[k] - e[j]  # every pair's displacement: exactly zero for identical scans
        copies += [(tid, int(a), int(b)) for a, b, row in zip(j, k, d) if not np.any(row)]
        total += (2.0 / n) * (d.T @ d)  # = 2 (n - 1) x the within-test sample covariance
        dof += n - 1
        ids.append(tid)
    if dof == 0:
        raise OutOfRangeError("no test has a repeat scan: a noise floor needs at least two scans of one test")
    if copies and np.any(total):  # a noise-free scanner repeats itself everywhere; a lab's scans never do
        tid = copies[0][0]
        scans = "its own scan and a repeat" if copies[0][1] == 0 else "two of its repeats"
        raise DatasetError(
            f"{where + ': ' if where else ''}test {tid}: {scans} of the {state} block give bitwise the same "
            f"frame while the other scans differ ({len(copies)} such pair{'s' * (len(copies) > 1)}): the same "
            "scan twice (a copied file?), which would enter the noise floor as an exact zero; each repeat must "
            "be a new scan"
        )
    return NoiseFloor(total / dof, dof, len(ids), tuple(ids))
