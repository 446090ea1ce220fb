"""Error metrics of a rate-table log: steady segments, noise floor, rms, systematic and heading errors.

A steady segment is a run of constant table rate (``ref_rate``) less its first
``settle_s`` seconds, where the table accelerates and the log's time stamps of the
table and the gyro may disagree.

Field errors (:func:`field_errors`) judge a calibration the way a robot uses it: the
error of the node's output (static bias included, nothing removed) from the end of the
static-bias window on, as a mean bias, the rms of the steady segments' mean errors, and
the heading error integrated over 10 minutes and 1 hour.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

DEFAULT_SETTLE_S = 1.0
# Heading horizons of the field errors: a short mission and a long one (s).
HEADING_HORIZONS_S = (600.0, SECONDS_PER_HOUR)

# Rows per piece where a long log's per-row temporaries are taken a piece at a time.
PIECE_ROWS = 1 << 20


@dataclass(frozen=True)
class Segments:
    """Steady segments of a log: row ranges ``[starts[i], stops[i])`` at table rate ``rate[i]``."""

    starts: NDArray[np.int64]
    stops: NDArray[np.int64]
    rate: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.starts)

    @property
    def counts(self) -> NDArray[np.int64]:
        """Rows per segment."""
        return self.stops - self.starts

    def rows(self) -> NDArray[np.int64]:
        """Indices of all steady rows, in order (one read-only array, made once: a long log's is large)."""
        return self._rows

    @cached_property
    def _rows(self) -> NDArray[np.int64]:
        rows = np.concatenate([np.arange(a, b) for a, b in zip(self.starts, self.stops)]) if len(self) \
            else np.zeros(0, dtype=np.int64)
        rows.flags.writeable = False
        return rows

    def after(self, row: int) -> Segments:
        """The segments from ``row`` on: one that begins before it counts from it, one that ends before it is gone."""
        starts = np.maximum(self.starts, row)
        keep = self.stops - starts >= 1
        return Segments(starts[keep], self.stops[keep], self.rate[keep])

    def means(self, values: ArrayLike) -> NDArray[np.float64]:
        """Mean of ``values`` (one per log row) over each segment."""
        v = np.asarray(values, dtype=float)
        csum = np.concatenate([[0.0], np.cumsum(v)])
        return np.asarray((csum[self.stops] - csum[self.starts]) / self.counts, dtype=np.float64)


def correlation_time_s(t: ArrayLike, residual: ArrayLike, segments: Segments, bin_s: float = 60.0) -> float:
    """Lag (s) where the autocorrelation of the residual's ``bin_s`` means over the steady rows falls below 1/e.

    Means on a regular time grid, empty bins left out of the sums (a gappy
    autocorrelation by FFT), so rests and gaps between segments do not matter. White
    noise gives one bin; a slow bias wander or an unmodelled slow effect, its time scale
    (the 1/e point of the autocorrelation from one bin on, where white noise is gone).
    """
    index = segments.rows()
    if index.size < 2:
        return 0.0
    tt, r = np.asarray(t, dtype=float), np.asarray(residual, dtype=float)
    n = int(np.floor((tt[index[-1]] - tt[index[0]]) / bin_s)) + 1
    counts, sums = np.zeros(n), np.zeros(n)
    for i in range(0, index.size, PIECE_ROWS):   # a piece at a time: the bins' sums add in the same order
        part = index[i:i + PIECE_ROWS]
        k = np.floor((tt[part] - tt[index[0]]) / bin_s).astype(np.int64)
        counts += np.bincount(k, minlength=n)
        sums += np.bincount(k, r[part], minlength=n)
    present = counts > 0
    x = np.zeros(n)
    x[present] = sums[present] / counts[present]
    x[present] -= x[present].mean()
    size = 2 * n
    fx, fm = np.fft.rfft(x, size), np.fft.rfft(present.astype(float), size)
    pairs = np.fft.irfft(fm * np.conj(fm), size)[:n]
    covariance = np.fft.irfft(fx * np.conj(fx), size)[:n] / np.maximum(np.rint(pairs), 1.0)
    # White noise adds to lag 0 only: the slow part's variance is the covariance at one bin,
    # if that stands out of the sampling noise of an autocorrelation (2 / sqrt(bins)).
    slow = covariance[1] if n > 1 else 0.0
    if covariance[0] <= 0.0 or slow <= 2.0 / np.sqrt(present.sum()) * covariance[0]:
        return bin_s
    # Lags with few pairs are noise; stop looking where fewer than a tenth of the bins pair up.
    usable = np.flatnonzero(pairs >= 0.1 * pairs[0])[1:]
    if not usable.size:
        return bin_s  # bins too sparse (a few samples over a long log) to follow the correlation at all
    below = usable[covariance[usable] < slow * np.exp(-1.0)]
    return float((below[0] if below.size else usable[-1]) * bin_s)


def steady_segments(t: ArrayLike, ref_rate: ArrayLike, settle_s: float = DEFAULT_SETTLE_S,
                    min_rows: int = 3, breaks: ArrayLike = ()) -> Segments:
    """Runs of constant ``ref_rate`` without their first ``settle_s`` seconds, of at least ``min_rows`` rows.

    ``breaks``: rows where a new run of the table begins whatever its rate (the first rows of the
    runs of a several-run fit: the table rested at the end of one log and the start of the next).
    """
    tt = np.asarray(t, dtype=float)
    ref = np.asarray(ref_rate, dtype=float)
    last = max(len(ref) - 1, 0)   # the rows that have a next one, a piece at a time
    change = np.concatenate([np.zeros(0, dtype=np.int64)] + [
        np.flatnonzero(~np.isclose(ref[i + 1:j + 1], ref[i:j], rtol=1e-9, atol=1e-9)) + i + 1
        for i, j in ((i, min(i + PIECE_ROWS, last)) for i in range(0, last, PIECE_ROWS))])
    extra = np.asarray(breaks, dtype=np.int64)
    if extra.size:
        change = np.union1d(change, extra[(extra > 0) & (extra < len(ref))])
    run_starts = np.concatenate([[0], change])
    run_stops = np.concatenate([change, [len(ref)]])
    starts = np.searchsorted(tt, tt[run_starts] + settle_s, side='left')
    starts = np.maximum(starts, run_starts)
    keep = run_stops - starts >= min_rows
    return Segments(starts[keep].astype(np.int64), run_stops[keep].astype(np.int64), ref[run_starts[keep]])


def noise_floor(residual: ArrayLike, segments: Segments) -> float:
    """White-noise level (deg/s per sample) from first differences within segments: blind to slow effects."""
    r = np.asarray(residual, dtype=float)
    count = int(np.sum(np.maximum(segments.counts - 1, 0)))
    if count < 2:
        raise ValueError('too few steady samples to estimate the noise floor')
    # Their standard deviation in two passes over pieces of the segments: all the differences of a long
    # log at once would be two more arrays as long as it.
    mean = sum(float(np.sum(d)) for d in _differences(r, segments)) / count
    return float(np.sqrt(sum(float(np.sum((d - mean) ** 2)) for d in _differences(r, segments)) / count)
                 / np.sqrt(2.0))


def _differences(r: NDArray[np.float64], segments: Segments) -> Iterator[NDArray[np.float64]]:
    """First differences of ``r`` within each segment, in pieces of at most :data:`PIECE_ROWS`."""
    for a, b in zip(segments.starts, segments.stops):
        for i in range(a, b - 1, PIECE_ROWS):
            yield np.diff(r[i:min(b, i + PIECE_ROWS + 1)])


@dataclass(frozen=True)
class ErrorMetrics:
    """Errors of a corrected rate against the table (deg/s, deg)."""

    rms_dps: float
    systematic_rms_dps: float
    heading_360_deg_max: float

    def to_dict(self) -> dict[str, float]:
        """Plain dict for JSON."""
        return asdict(self)


def heading_errors_360(error: ArrayLike, segments: Segments) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per turning segment: (table rate, heading error in degrees after a full turn at that rate)."""
    mean = segments.means(error)
    turning = segments.rate != 0.0
    return segments.rate[turning], mean[turning] * 360.0 / np.abs(segments.rate[turning])


def error_metrics(error: ArrayLike, segments: Segments) -> ErrorMetrics:
    """RMS over all steady rows, RMS of the segment means, and the largest heading error after a full turn."""
    e = np.asarray(error, dtype=float)
    rows = segments.rows()
    if rows.size == 0:
        raise ValueError('the log has no steady segments to measure errors on')
    _, heading = heading_errors_360(e, segments)
    return ErrorMetrics(
        rms_dps=float(np.sqrt(np.mean(e[rows] ** 2))),
        systematic_rms_dps=float(np.sqrt(np.mean(segments.means(e) ** 2))),
        heading_360_deg_max=float(np.max(np.abs(heading))) if heading.size else 0.0)


def heading_error_deg(t: ArrayLike, error: ArrayLike, start: int, horizons_s: ArrayLike) -> NDArray[np.float64]:
    """Heading error (deg): ``error`` (deg/s) integrated from row ``start`` over each horizon (s).

    Trapezoids between samples, so gaps count with their length, interpolated at
    ``t[start] + horizon``; NaN for a horizon beyond the end of the log.
    """
    tt = np.asarray(t, dtype=float)[start:]
    e = np.asarray(error, dtype=float)[start:]
    if tt.size == 0:
        raise ValueError(f'row {start} is beyond the {start + tt.size} rows of the log')
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (e[1:] + e[:-1]) * np.diff(tt))])
    h = np.asarray(horizons_s, dtype=float)
    return np.where(h <= tt[-1] - tt[0], np.interp(tt[0] + h, tt, heading), np.nan)


@dataclass(frozen=True)
class FieldErrors:
    """Errors of the node's output on a run (deg/s, deg), bias included, from the end of the static bias on."""

    mean_bias_dps: float
    systematic_rms_dps: float
    heading_10min_deg: float
    heading_1h_deg: float
    # The node would refuse this run's static bias (the calibration moves the still gyro past the motion
    # check); the errors are those of the bias taken anyway.
    bias_refused: bool = False

    def to_dict(self) -> dict[str, float | None]:
        """Plain dict for JSON: deg/s values also in deg/h; a heading the log is too short for is None."""
        d: dict[str, float | None] = asdict(self)
        d['mean_bias_dph'] = self.mean_bias_dps * DEG_PER_H_PER_DPS
        d['systematic_rms_dph'] = self.systematic_rms_dps * DEG_PER_H_PER_DPS
        return {k: (None if v is not None and not np.isfinite(v) else v) for k, v in d.items()}


def field_errors(t: ArrayLike, error: ArrayLike, segments: Segments, start: int) -> FieldErrors:
    """Field errors of ``error`` (output - table rate, deg/s) from row ``start`` (the first after the static bias).

    The mean bias is the mean error over the steady rows from ``start`` on (what a
    heading integrates); the systematic rms is the rms of those segments' mean errors,
    their common bias included; the headings are :func:`heading_error_deg` at
    :data:`HEADING_HORIZONS_S`. Segments that begin before ``start`` count from ``start``.
    """
    e = np.asarray(error, dtype=float)
    later = segments.after(start)
    if not len(later):
        raise ValueError(f'the log has no steady segment after row {start} to measure field errors on')
    means = later.means(e)
    heading = heading_error_deg(t, e, start, HEADING_HORIZONS_S)
    return FieldErrors(
        mean_bias_dps=float(np.average(means, weights=later.counts)),
        systematic_rms_dps=float(np.sqrt(np.mean(means ** 2))),
        heading_10min_deg=float(heading[0]), heading_1h_deg=float(heading[1]))
