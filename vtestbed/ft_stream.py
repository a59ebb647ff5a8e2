"""A force/torque sensor's time series (CSV) reduced to one static reading and its noise.

Units and frames: the stream is in the sensor's own measurement frame (the frame of setup.json's
``sensor_in_flange``), as the sensor reports it; nothing is rotated. Inside, time is in seconds
and the wrench in N and N*m. The file carries its units in the column names: ``time_s``,
``Fx_N``, ``Fy_N``, ``Fz_N`` and ``Tx_Nm``, ``Ty_Nm``, ``Tz_Nm`` (or ``Tx_Nmm``... with
``torque_unit="Nmm"``, converted to N*m on reading). Other columns are ignored.

A static window (times ``start <= t <= end``) is averaged; it is given, or found as the quietest
window of a given length (the smallest sum over the six axes of the window's variance, each
axis scaled by its white-noise level estimated from the first differences of the whole stream).
Its noise: per axis the sample std, the integrated autocorrelation time ``tau`` (in samples,
``1 + 2 sum_k rho_k``, Sokal's automatic window ``M >= 5 tau``) and the standard error of the
mean ``std * sqrt(tau / n)``, honest for coloured noise (a sensor's anti-alias filter correlates
neighbouring samples; ``std / sqrt(n)`` would then be too small). The window must be settled:
the means of its two halves must agree within :data:`SETTLE_Z` of their standard errors on
every axis, or the stream is refused as one that never settles (or as a bad window).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DatasetError

AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
TORQUE_UNITS = {"Nm": 1.0, "Nmm": 1e-3}  # -> N*m
TIME_COLUMN = "time_s"
DEFAULT_WINDOW_LENGTH_S = 1.0
MIN_WINDOW_SAMPLES = 40  # fewer gives no usable noise estimate (nor two halves to compare)
SETTLE_Z = 5.0  # half-window means further apart than this many standard errors: not static
_SOKAL_C = 5.0


def stream_columns(torque_unit: str = "Nm") -> list[str]:
    """The wrench columns a stream file must hold, for ``torque_unit`` 'Nm' or 'Nmm'."""
    if torque_unit not in TORQUE_UNITS:
        raise DatasetError(f"torque unit {torque_unit!r} is not one of {', '.join(TORQUE_UNITS)}")
    return [f"{a}_N" for a in AXES[:3]] + [f"{a}_{torque_unit}" for a in AXES[3:]]


@dataclass(frozen=True)
class FTStream:
    """A recorded F/T stream (SI, sensor frame).

    Attributes
    ----------
    path : Path
        The file it was read from (named in every error).
    time : ndarray, shape (n,)
        Sample times [s], strictly increasing.
    wrench : ndarray, shape (n, 6)
        Fx, Fy, Fz [N], Tx, Ty, Tz [N*m] in the sensor frame.
    columns : tuple of str
        The file's names of the six wrench columns (with their units), for messages.
    """

    path: Path
    time: np.ndarray
    wrench: np.ndarray
    columns: tuple[str, ...] = tuple(f"{a}_{'N' if a[0] == 'F' else 'Nm'}" for a in AXES)


@dataclass(frozen=True)
class StaticReading:
    """One static window of a stream, averaged, with its noise.

    Attributes
    ----------
    start, end : float
        The window [s]: samples with ``start <= t <= end``.
    n : int
        Samples in the window.
    mean : ndarray, shape (6,)
        The reading [N, N*m], sensor frame.
    std : ndarray, shape (6,)
        Sample standard deviation per axis [N, N*m] (the per-sample noise).
    tau : ndarray, shape (6,)
        Integrated autocorrelation time per axis [samples] (1 for white noise).
    sem : ndarray, shape (6,)
        Standard error of ``mean``: ``std * sqrt(tau / n)`` [N, N*m].
    automatic : bool
        The window was found as the quietest one (not given).
    """

    start: float
    end: float
    n: int
    mean: np.ndarray
    std: np.ndarray
    tau: np.ndarray
    sem: np.ndarray
    automatic: bool


def _number(text: str, path: Path, line: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DatasetError(f"{path} line {line}: column {column} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise DatasetError(f"{path} line {line}: column {column} must be a finite number, got {text!r}")
    return value


def read_ft_csv(path: str | Path, torque_unit: str = "Nm") -> FTStream:
    """Read an F/T stream CSV (``time_s`` and the six wrench columns, see :func:`stream_columns`).

    Parameters
    ----------
    path : str or Path
        The CSV file, one header line then one row per sample.
    torque_unit : {'Nm', 'Nmm'}
        The unit of the torque columns (their names end with it); converted to N*m.

    Returns
    -------
    FTStream
        Times (n,) [s] and wrenches (n, 6) [N, N*m].

    Raises
    ------
    DatasetError
        Naming the file, the line and the column: a missing column (with a hint when the torque
        columns carry the other unit), a value that is not a finite number, times that do not
        increase, fewer than :data:`MIN_WINDOW_SAMPLES` rows.
    """
    path = Path(path)
    wanted = [TIME_COLUMN, *stream_columns(torque_unit)]
    if not path.is_file():
        raise DatasetError(f"F/T stream file {path} is missing")
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, None) or []]
            missing = [c for c in wanted if c not in header]
            if missing:
                other = [u for u in TORQUE_UNITS if u != torque_unit and f"Tx_{u}" in header]
                hint = f" (the file has Tx_{other[0]}: set the torque unit to {other[0]})" if other else ""
                raise DatasetError(
                    f"{path}: column {missing[0]} is missing{hint}; an F/T stream needs the columns "
                    f"{', '.join(wanted)}; the file has {', '.join(header) or 'no header'}"
                )
            twice = [c for c in wanted if header.count(c) > 1]
            if twice:  # the first would be read and the other ignored without a word
                raise DatasetError(f"{path}: column {twice[0]} appears {header.count(twice[0])} times in the "
                                   f"header; each of {', '.join(wanted)} once")  # fmt: skip
            index = [header.index(c) for c in wanted]
            rows = []
            for fields in reader:
                if not fields or not any(f.strip() for f in fields):
                    continue
                line = reader.line_num
                if len(fields) != len(header):
                    raise DatasetError(
                        f"{path} line {line}: {len(fields)} fields, the header has {len(header)}"
                    )
                rows.append([_number(fields[i], path, line, c) for i, c in zip(index, wanted)])
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not UTF-8 text (byte {exc.start}): is this an F/T stream CSV?") from None
    except csv.Error as exc:
        raise DatasetError(f"{path}: not a valid CSV file: {exc}") from None
    if len(rows) < MIN_WINDOW_SAMPLES:
        raise DatasetError(f"{path}: {len(rows)} samples; an F/T stream needs at least {MIN_WINDOW_SAMPLES}")
    data = np.array(rows)
    time = data[:, 0]
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        raise DatasetError(
            f"{path}: column {TIME_COLUMN} must increase strictly; row {bad[0] + 2} ({time[bad[0] + 1]:.15g} s) "
            f"does not follow row {bad[0] + 1} ({time[bad[0]]:.15g} s)"
        )
    wrench = data[:, 1:].copy()
    wrench[:, 3:] *= TORQUE_UNITS[torque_unit]
    return FTStream(path, time, wrench, tuple(wanted[1:]))


def autocorrelation_time(x: np.ndarray) -> float:
    """Integrated autocorrelation time ``1 + 2 sum_k rho_k`` [samples] of a series (n,).

    Sokal's automatic window: the sum runs to the first lag ``M >= 5 tau(M)``. 1 for white
    noise and for a constant series; at least 1 (a series cannot be better than independent
    samples for the mean's error as estimated here).
    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = x.size
    var = float(x @ x)
    if n < 2 or var == 0.0:
        return 1.0
    spectrum = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n] / var
    taus = 2.0 * np.cumsum(acf) - 1.0
    lags = np.arange(n)
    ok = np.flatnonzero(lags >= _SOKAL_C * taus)
    tau = taus[ok[0]] if ok.size else taus[-1]
    return float(max(tau, 1.0))


def window_statistics(stream: FTStream, start: float, end: float, automatic: bool = False) -> StaticReading:
    """Mean, std, autocorrelation time and standard error of the samples ``start <= t <= end``."""
    mask = (stream.time >= start) & (stream.time <= end)
    w = stream.wrench[mask]
    n = len(w)
    if n < MIN_WINDOW_SAMPLES:
        raise DatasetError(
            f"{stream.path}: the window [{start:g}, {end:g}] s holds {n} samples; it needs at least "
            f"{MIN_WINDOW_SAMPLES} (a longer window)"
        )
    return _statistics(w, start, end, automatic)


def _statistics(w: np.ndarray, start: float, end: float, automatic: bool = False) -> StaticReading:
    n = len(w)
    std = w.std(axis=0, ddof=1)
    tau = np.array([autocorrelation_time(w[:, i]) for i in range(6)])
    sem = std * np.sqrt(tau / n)
    return StaticReading(float(start), float(end), n, w.mean(axis=0), std, tau, sem, automatic)


def _white_noise_scale(wrench: np.ndarray) -> np.ndarray:
    """Per-axis white-noise std from the first differences (robust: median absolute difference);
    the axis's std where the differences are mostly 0 (quantized), 1 for an axis that is constant
    to round-off (its variance then counts in its own units, i.e. not at all)."""
    mad = np.median(np.abs(np.diff(wrench, axis=0)), axis=0) / (0.6744897501960817 * math.sqrt(2.0))
    scale = np.where(mad > 0, mad, wrench.std(axis=0))
    constant = scale <= 1e-9 * np.abs(wrench).max(axis=0)
    return np.where(constant | (scale == 0), 1.0, scale)


def quietest_window(stream: FTStream, length_s: float) -> tuple[float, float]:
    """The window ``[t_i, t_i + length_s]`` of least scaled variance (summed over the axes) [s]."""
    t = stream.time
    if not length_s > 0 or t[-1] - t[0] < length_s:
        raise DatasetError(
            f"{stream.path}: the stream lasts {t[-1] - t[0]:g} s ({t[0]:g} to {t[-1]:g} s), shorter than "
            f"the static window's length {length_s:g} s (choose a window length in (0, {t[-1] - t[0]:g}] s)"
        )
    x = (stream.wrench - stream.wrench.mean(axis=0)) / _white_noise_scale(stream.wrench)
    c1 = np.vstack([np.zeros(6), np.cumsum(x, axis=0)])
    c2 = np.vstack([np.zeros(6), np.cumsum(x * x, axis=0)])
    starts = np.flatnonzero(t <= t[-1] - length_s)
    ends = np.searchsorted(t, t[starts] + length_s, side="right")  # exclusive sample index
    n = (ends - starts)[:, None]
    s1, s2 = c1[ends] - c1[starts], c2[ends] - c2[starts]
    score = np.sum(s2 / n - (s1 / n) ** 2, axis=1)
    score[n[:, 0] < MIN_WINDOW_SAMPLES] = np.inf
    if not np.isfinite(score).any():
        raise DatasetError(
            f"{stream.path}: no window of {length_s:g} s holds {MIN_WINDOW_SAMPLES} samples (a longer window)"
        )
    best = int(np.argmin(score))
    return float(t[starts[best]]), float(t[starts[best]] + length_s)


def settle_check(stream: FTStream, reading: StaticReading, settle_z: float = SETTLE_Z) -> None:
    """Refuse a window whose two halves' means differ by more than ``settle_z`` standard errors.

    The standard error of the difference, ``2 std_r sqrt(tau_r / n)``, comes from the residuals of a
    straight line fitted to the window: a drift would otherwise inflate its own autocorrelation
    time and hide; stationary (white or coloured) noise is barely changed by the detrending.
    """
    inside = (stream.time >= reading.start) & (stream.time <= reading.end)
    t, w = stream.time[inside], stream.wrench[inside]
    n, half = len(w), len(w) // 2
    diff = np.abs(w[half:].mean(axis=0) - w[:half].mean(axis=0))
    design = np.column_stack([np.ones(n), t - t.mean()])
    resid = w - design @ np.linalg.lstsq(design, w, rcond=None)[0]
    tau = np.array([autocorrelation_time(resid[:, i]) for i in range(6)])
    err = 2.0 * resid.std(axis=0, ddof=2) * np.sqrt(tau / n)
    floor = 1e-12 * np.abs(w).max(axis=0)  # round-off of a noiseless, constant axis
    z = np.where(diff > floor, diff / np.maximum(err, floor + 1e-300), 0.0)
    worst = int(np.argmax(z))
    if z[worst] > settle_z:
        unit = "N" if worst < 3 else "N*m"
        how = "the quietest" if reading.automatic else "the"
        raise DatasetError(
            f"{stream.path}: the stream never settles in {how} window [{reading.start:g}, {reading.end:g}] s: "
            f"column {stream.columns[worst]} drifts by {diff[worst]:.3g} {unit} between the window's halves, "
            f"{z[worst]:.3g} standard errors (static needs <= {settle_z:g}); choose a static window "
            "(--window START:END or the manifest's window_s) or record longer at rest"
        )


def static_reading(
    stream: FTStream,
    window: tuple[float, float] | None = None,
    length_s: float = DEFAULT_WINDOW_LENGTH_S,
    settle_z: float = SETTLE_Z,
) -> StaticReading:
    """The stream's static reading: the given window [s], or the quietest one of ``length_s``.

    Parameters
    ----------
    stream : FTStream
        The recorded stream.
    window : (float, float) or None
        ``(start, end)`` [s], inside the stream's time span; None finds the quietest window.
    length_s : float
        The automatic window's length [s].
    settle_z : float
        The settle check's threshold [standard errors] (:func:`settle_check`).

    Returns
    -------
    StaticReading
        Mean (6,) [N, N*m] with its std, autocorrelation time and standard error.

    Raises
    ------
    DatasetError
        A window outside the stream, too short, or not static (:func:`settle_check`), naming the
        file, the window and the stream's time span.
    """
    t = stream.time
    if window is None:
        start, end = quietest_window(stream, length_s)
        reading = window_statistics(stream, start, end, automatic=True)
    else:
        start, end = (float(v) for v in window)
        if not (t[0] <= start < end <= t[-1]):
            raise DatasetError(
                f"{stream.path}: window [{start:g}, {end:g}] s is outside the stream: it must satisfy "
                f"{t[0]:g} <= start < end <= {t[-1]:g} s (column {TIME_COLUMN})"
            )
        reading = window_statistics(stream, start, end)
    settle_check(stream, reading, settle_z)
    return reading
