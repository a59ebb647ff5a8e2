"""A cubic joint spring's deflection, ``k x + k3 x^3 = tau``: the exact form of the
``nonlinear_joint`` candidate (:mod:`.candidates`).

Units: stiffness ``k`` [N*m/rad], ``k3`` [N*m/rad^3], torque ``tau`` [N*m], deflection ``x`` [rad].
"""

from __future__ import annotations

import numpy as np

__all__ = ["NONLINEAR_SECANT_LIMIT", "cubic_deflection"]

# Largest change of the tangent stiffness, 3 k3 x^2 / k, at which the nonlinear joint's column is
# the exact secant (the realistic k3 changes it by about a tenth at 2 mrad).
NONLINEAR_SECANT_LIMIT = 0.5


def cubic_deflection(k: float, k3: float, tau: np.ndarray) -> np.ndarray:
    """Deflection ``x`` [rad] of a spring ``k x + k3 x^3 = tau`` (tau [N*m], array): Newton from
    ``tau / k`` to round-off, on the stable branch (``k + 3 k3 x^2 > 0``); NaN where there is none
    (a softening spring past its limit load)."""
    tau = np.asarray(tau, dtype=float)
    x = tau / k
    with np.errstate(all="ignore"):
        for _ in range(40):
            x = x - (k * x + k3 * x**3 - tau) / (k + 3.0 * k3 * x**2)
        converged = np.abs(k * x + k3 * x**3 - tau) <= 1e-12 * (np.abs(tau) + k * np.abs(x))
        return np.where(np.isfinite(x) & converged & (k + 3.0 * k3 * x**2 > 0), x, np.nan)
