"""Do the loaded block's repeat scans scatter like the unloaded ones? (a check for creep)

The mean-scan displacements (:mod:`.scan_mean`) and their floor's scale ``(1/m + 1/m') / 2``
assume that a test's loaded scans differ by the scanner's noise alone, as its unloaded scans do.
A block under load may creep, or the wire settle, between scans; then the loaded scans scatter
more, the mean loaded frame is a frame the block held at no single instant, and the floor,
estimated from the unloaded repeats only, is too small for the displacements.

The check compares, per component (x, y, z [m], rx, ry, rz [rad], block frame), the pooled
within-test variance of the loaded scans with that of the unloaded scans, both pooled as
:func:`.noise_floor.noise_floor_from_frames` pools them. Under the hypothesis (same Gaussian
noise) each ratio is ``F(nu_loaded, nu_unloaded)`` distributed, exactly; the test is one-sided
(loaded larger: creep only adds motion; a loaded scatter below the unloaded one leaves the floor
conservative) with a Bonferroni correction over the six components.

What follows a rejection (:func:`.scan_mean.against_scan_mean`): the loaded end of every
displacement falls back to the test's own loaded scan, the first, taken with the F/T reading
(``left_out``). Creep carries the block on from there, so the mean of ``m'`` scans lies about
``(m' - 1) / 2`` scans' creep beyond it (0.75 % of the deflection with 3 repeats at 0.5 % per
scan), which the compliances absorb as a bias; the own scan has more noise and no such bias.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import f as f_dist

from ..transforms import DISPLACEMENT_COMPONENTS as COMPONENTS
from .noise_floor import noise_floor_from_frames

__all__ = ["LoadedScatter", "loaded_scatter"]


@dataclass(frozen=True)
class LoadedScatter:
    """The loaded scans' scatter against the unloaded scans', per component.

    Attributes
    ----------
    ratio : (6,) array
        Loaded over unloaded pooled within-test variance (1 = the same noise).
    dof_loaded, dof_unloaded : int
        Their degrees of freedom (``sum_t (n_t - 1)`` over the tests with two or more scans).
    p_value : float
        One-sided, Bonferroni over the six components: small when some component of the loaded
        scans scatters more than the unloaded floor allows.
    left_out : bool
        Whether the loaded repeats were left out of the displacements because of this check (each
        measured to its test's own loaded scan instead of the loaded scans' mean).
    """

    ratio: np.ndarray
    dof_loaded: int
    dof_unloaded: int
    p_value: float
    left_out: bool = False

    def moved(self, alpha: float) -> bool:
        """Whether the loaded block moved between its scans beyond the noise at level ``alpha``."""
        return bool(self.p_value < alpha)

    @classmethod
    def from_dict(cls, data: dict) -> LoadedScatter:
        """From :meth:`to_dict`'s form (a report.json)."""
        return cls(np.asarray(data["ratio"], dtype=float), int(data["dof_loaded"]), int(data["dof_unloaded"]),
                   float(data["p_value"]), bool(data.get("left_out", False)))  # fmt: skip

    def to_dict(self) -> dict:
        return {"ratio": np.asarray(self.ratio).tolist(), "dof_loaded": self.dof_loaded,
                "dof_unloaded": self.dof_unloaded, "p_value": self.p_value, "left_out": self.left_out}  # fmt: skip

    def sentence(self, alpha: float) -> str:
        """One line for a report."""
        worst = int(np.argmax(self.ratio))
        head = (
            f"The loaded block's scans scatter {np.min(self.ratio):.2f}-{np.max(self.ratio):.2f} times "
            f"the unloaded ones' variance per component ({self.dof_loaded} against {self.dof_unloaded} "
            f"samples, p = {self.p_value:.3g})"
        )
        moved = (
            f"{head}: the loaded block moved between its scans (creep, or the wire settling; most in "
            f"{COMPONENTS[worst]})"
        )
        if self.left_out:
            return (
                f"{moved}, so every displacement is measured to its test's own loaded scan (the first, "
                "taken with the F/T reading) and the loaded repeats are left out: wait for the load to "
                "settle before the repeat scans."
            )
        if self.moved(alpha):
            return (
                f"{moved}, so the mean loaded frame and the floor scaled for it are not to be trusted: "
                "wait for the load to settle before the repeat scans, or leave them out."
            )
        return f"{head}: no sign that the loaded block moved between its scans."


def loaded_scatter(
    unloaded_frames: Mapping[str, Sequence[np.ndarray]] | None,
    loaded_frames: Mapping[str, Sequence[np.ndarray]] | None,
) -> LoadedScatter | None:
    """The check, or None when either side has no test with two scans.

    Parameters
    ----------
    unloaded_frames, loaded_frames : mapping test_id -> sequence of (4, 4) arrays
        Per test, the fitted frames of its scans of that block (the test's own first), as
        :func:`.repeat_scans.repeat_scan_frames` and :func:`.scan_mean.loaded_scan_frames` give them.
    """
    if not unloaded_frames or not loaded_frames:
        return None
    if not any(len(f) > 1 for f in unloaded_frames.values()) or not any(
        len(f) > 1 for f in loaded_frames.values()
    ):
        return None
    unloaded = noise_floor_from_frames(unloaded_frames)
    loaded = noise_floor_from_frames(loaded_frames, "the loaded repeats (loaded_repeats.csv)", "loaded")
    var_loaded, var_unloaded = np.diag(loaded.covariance), np.diag(unloaded.covariance)
    with np.errstate(divide="ignore", invalid="ignore"):  # a perfect (simulated) scanner: 0 / 0
        ratio = np.where(var_unloaded > 0, var_loaded / var_unloaded, np.where(var_loaded > 0, np.inf, 1.0))
    p_each = f_dist.sf(ratio, loaded.n_samples, unloaded.n_samples)
    return LoadedScatter(
        ratio, int(loaded.n_samples), int(unloaded.n_samples), float(min(1.0, 6 * p_each.min()))
    )
