"""Stiffness priors for experiment design: what the researcher believes before the experiment.

Design criteria that are not scale-invariant (A, E, the predicted std) need a guess of the joint
stiffness. The guess is always an explicit argument: a name from :data:`NAMED_PRIORS` or the
researcher's own numbers [N*m/rad]. The paper's Table 5 is offered by name; it is never a silent
default (in the virtual lab it also happens to be the truth of the KR60-3 world).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, UnknownNameError


@dataclass(frozen=True)
class StiffnessPrior:
    """A named stiffness guess. ``values_nmm`` in N*mm/rad as published; :attr:`stiffness` in SI."""

    name: str
    values_nmm: tuple[float, ...]
    source: str

    @property
    def stiffness(self) -> np.ndarray:
        """(n,) joint stiffness [N*m/rad]."""
        return np.array(self.values_nmm) / 1e3


PAPER_TABLE5 = StiffnessPrior(
    "paper_table5",
    (2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7),
    "Gao et al. 2023, Table 5: the KR60-3 stiffness identified in their lab",
)
NAMED_PRIORS = {p.name: p for p in (PAPER_TABLE5,)}


def stiffness_prior(value, dof: int, field: str = "stiffness prior") -> np.ndarray:
    """(dof,) stiffness [N*m/rad] from a prior name or from ``dof`` positive numbers [N*m/rad]."""
    if isinstance(value, str):
        if value not in NAMED_PRIORS:
            raise UnknownNameError(field, value, NAMED_PRIORS)
        k = NAMED_PRIORS[value].stiffness
    else:
        k = np.asarray(value, dtype=float)
    if k.shape != (dof,) or not np.all(np.isfinite(k)) or not np.all(k > 0):
        raise OutOfRangeError(f"{field} must be {dof} positive stiffness values [N*m/rad], got {value!r}")
    return k
