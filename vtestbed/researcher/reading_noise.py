"""The F/T sensor's reading noise in the displacement the model predicts.

Units and frames: SI; wrenches at the block's origin in the block axes [N, N*m], displacements
in the unloaded block frame [m, rad], compliances in rad/(N*m).

The model predicts a test's displacement from the measured wrench change (loaded minus unloaded
reading), ``d = J diag(c) J^T w`` (the paper's Eq. 17), so a reading's noise enters the residual as
``J diag(c) J^T dw``. Repeat scans average the scanner's noise down, not this: there is one
reading at each end of a test. With 8 scans at each end it is about 2 % of the scan floor's
variance on the paper's 20 tests, and a chi^2 against the scan floor alone then rejects a right
model at 2 % where its level is 1 % (docs/discrepancy.md, "The F/T readings' noise in the floor").

:func:`with_reading_noise` adds its covariance to the floor the model is tested against: the
mean over the identification tests of ``G_t S_w G_t^T``, ``G_t = J_t diag(c) J_t^T`` with the
paper's model's compliances fitted against the scan floor, and ``S_w`` the covariance of the
wrench change at the block, from setup.json's ``force_sensor.noise_std_N_Nm`` (two readings,
independent). One mean for every test keeps the chi^2's mean exact (the sum over the tests of
``tr(S^-1 (F + S_t))`` is ``6 T`` with ``S = F + mean_t S_t``) and one 6 x 6 metric for every
test, validation and proposed tests included; its tails are slightly off where ``S_t`` differs
from test to test (about 2x between the paper's tests, on a term 2 % of the floor).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..dataset import DatasetSetup
from ..errors import OutOfRangeError
from .identify import stack
from .measure import TestMeasurement, wrench_at_block
from .model_fit import Whitener
from .noise_floor import NoiseFloor

__all__ = ["reading_covariance", "wrench_change_covariance", "with_reading_noise"]


def wrench_change_covariance(setup: DatasetSetup) -> np.ndarray:
    """(6, 6) covariance of the wrench change (loaded minus unloaded reading) at the block's
    origin, block axes [N, N*m]: two independent readings of std ``setup.sensor_noise_std``
    each, moved from the sensor's frame (:func:`.measure.wrench_at_block`, linear)."""
    move = np.array([wrench_at_block(e, setup) for e in np.eye(6)]).T  # block wrench = move @ sensor wrench
    std = np.asarray(setup.sensor_noise_std, dtype=float)
    return move @ np.diag(2.0 * std**2) @ move.T


def reading_covariance(
    measurements: Sequence[TestMeasurement], setup: DatasetSetup, compliance: np.ndarray
) -> np.ndarray:
    """(6, 6) mean over ``measurements`` of the predicted displacement's covariance from the
    readings' noise, ``J diag(c) J^T S_w J diag(c) J^T`` [m, rad], at compliances ``compliance``
    (n,) rad/(N*m)."""
    s_w = wrench_change_covariance(setup)
    out = np.zeros((6, 6))
    for m in measurements:
        g = m.jacobian @ (np.asarray(compliance, dtype=float)[:, None] * m.jacobian.T)
        out += g @ s_w @ g.T
    return out / len(measurements)


def with_reading_noise(
    floor: NoiseFloor, measurements: Sequence[TestMeasurement], setup: DatasetSetup
) -> NoiseFloor:
    """``floor`` with the readings' noise (:func:`reading_covariance`) as its ``reading_covariance``,
    at the compliances of the paper's model fitted to the identification tests by least squares
    whitened with the scan floor. Unchanged when setup.json gives no ``noise_std_N_Nm``, or
    when no identification test is among ``measurements``, or for a singular floor (too few
    repeat scans, a perfect scanner: the model fit refuses it with its own message)."""
    ident = [m for m in measurements if m.group == "identification"]
    if setup.sensor_noise_std is None or not ident or not np.any(setup.sensor_noise_std):
        return floor
    try:
        white = Whitener(floor)  # the scans' floor: no reading part yet
    except OutOfRangeError:  # the model fit refuses this floor later, with the same message
        return floor
    a = stack([m.jacobian for m in ident], [m.wrench for m in ident])
    d = np.concatenate([m.displacement for m in ident])
    compliance = np.linalg.lstsq(white(a), white(d), rcond=None)[0]
    # abs: a compliance the tests barely determine may come out negative; its size is what counts
    covariance = reading_covariance(ident, setup, np.abs(compliance))
    return dataclasses.replace(floor, reading_covariance=covariance)
