"""``calibrate allan``: the noise of a gyro at rest, as IEEE Std 952 terms and as the node's parameters.

The overlapping Allan deviation of the record (:mod:`.allan`, streamed: any length in
bounded memory) is fitted with the five terms of IEEE Std 952-1997 Annex C, each a power
of tau in the Allan variance (rate in deg/s, tau in s):

==================  =================================  ===========================
term                Allan variance                     reported as
==================  =================================  ===========================
quantisation Q      3 Q^2 / tau^2          (Q in deg)  ``quantisation_deg``
angle random walk   N^2 / tau       (N in deg/sqrt(s))  ``arw_deg_per_sqrt_h`` = 60 N
bias instability    (2 ln 2 / pi) B^2      (B in deg/s) ``bias_instability_deg_per_h`` = 3600 B
rate random walk    K^2 tau / 3    (K in deg/s/sqrt(s)) ``rate_random_walk_deg_per_h_per_sqrt_h``
rate ramp           R^2 tau^2 / 2        (R in deg/s^2) ``rate_ramp_deg_per_h_per_h`` = 3600^2 R
==================  =================================  ===========================

by non-negative least squares on the Allan variance, each value weighted by its own
uncertainty (its chi-squared degrees of freedom). Quantisation and rate ramp are
reported only where the record shows them: where the term makes at least
:data:`SHOWN_SHARE` of the fitted variance at some measured tau, and more than twice
that value's own uncertainty (else None).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.allan import AllanAccumulator, AllanDeviation
from art_gyro_calibration.analysis.progress import Progress
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

TERMS = ('quantisation', 'arw', 'bias_instability', 'rate_random_walk', 'rate_ramp')
# Powers of tau of each term's Allan variance, and its factor: variance = factor x value^2 x tau^power.
_POWERS = (-2.0, -1.0, 0.0, 1.0, 2.0)
_FACTORS = (3.0, 1.0, 2.0 * math.log(2.0) / math.pi, 1.0 / 3.0, 0.5)
# A term the fit gives at least this share of the Allan variance at some measured tau is shown by the record.
SHOWN_SHARE = 0.1
# The static-bias window is the shortest whose Allan deviation is within this factor of the least.
BIAS_WINDOW_TOLERANCE = 1.1
# The node's bias_samples and yaw_rate_stddev (rad/s) ranges (ros/parameters.py, which needs rclpy: a test checks
# that they agree).
BIAS_SAMPLES_RANGE = (2, 1_000_000)
YAW_RATE_STDDEV_RANGE = (1e-7, 1.0)
# Frame rates (Hz) a node's parameters are computed for: an RD2100 at 10 Hz to a KVH unit's 5 kHz, with room.
NODE_RATE_HZ_RANGE = (0.01, 100_000.0)
# Sample rates (Hz) of a gyro record; a time column giving another is in another unit (TIME_UNITS).
PLAUSIBLE_RATE_HZ = (0.5, 100_000.0)
TIME_UNITS = (('ms', 1e3), ('us', 1e6), ('ns', 1e9), ('minutes', 1 / 60), ('hours', 1 / 3600))
# The at-rest check: the record is cut into blocks of STILL_BLOCK_S; between two consecutive blocks at rest the
# mean differs by white noise, sigma sqrt(2 / B) for B samples of per-sample noise sigma (and by bias instability,
# far less over 10 s). A step beyond STILL_SIGMAS of that is motion: a rate table at 1 deg/s is 150 of them for an
# RD2100 at 10 Hz. sigma is read from the sample-to-sample differences with their extreme TRIM share on each side
# left out (a table's steps), and the trimmed variance scaled back to the whole normal's (TRIM_VARIANCE).
STILL_BLOCK_S = 10.0
STILL_SIGMAS = 8.0
TRIM = 0.01
TRIM_VARIANCE = 0.8735
CONFIDENCE = 0.683


@dataclass(frozen=True)
class NoiseTerms:
    """The IEEE Std 952 terms fitted, in deg and seconds (see the module's table); None: not shown."""

    quantisation_deg: float | None
    arw_dps_sqrt_s: float
    bias_instability_dps: float
    rate_random_walk_dps_per_sqrt_s: float
    rate_ramp_dps_per_s: float | None

    def values(self) -> NDArray[np.float64]:
        """The five values in :data:`TERMS` order, 0 for a term not shown."""
        return np.array([self.quantisation_deg or 0.0, self.arw_dps_sqrt_s, self.bias_instability_dps,
                         self.rate_random_walk_dps_per_sqrt_s, self.rate_ramp_dps_per_s or 0.0])

    def adev(self, tau_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """The fitted Allan deviation at ``tau_s`` (deg/s)."""
        return np.asarray(np.sqrt(self.parts(tau_s).sum(axis=0)), dtype=np.float64)

    def parts(self, tau_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Each term's Allan variance at ``tau_s``, one row per term of :data:`TERMS`."""
        tau = np.atleast_1d(np.asarray(tau_s, dtype=float))
        return np.array([f * v * v * tau ** p for f, v, p in zip(_FACTORS, self.values(), _POWERS)])

    def to_dict(self) -> dict[str, float | None]:
        """The terms in the units people read them in (``*_deg_per_h`` ...)."""
        return {
            'quantisation_deg': self.quantisation_deg,
            'arw_deg_per_sqrt_h': self.arw_dps_sqrt_s * math.sqrt(SECONDS_PER_HOUR),
            'bias_instability_deg_per_h': self.bias_instability_dps * DEG_PER_H_PER_DPS,
            'rate_random_walk_deg_per_h_per_sqrt_h': self.rate_random_walk_dps_per_sqrt_s * DEG_PER_H_PER_DPS
            * math.sqrt(SECONDS_PER_HOUR),
            'rate_ramp_deg_per_h_per_h': None if self.rate_ramp_dps_per_s is None
            else self.rate_ramp_dps_per_s * SECONDS_PER_HOUR ** 2,
        }


def fit_noise_terms(allan: AllanDeviation, sample_rate_hz: float) -> NoiseTerms:
    """The IEEE Std 952 terms that best explain ``allan``, each Allan variance weighted by its uncertainty.

    The variance of a value with ``edf`` degrees of freedom has a relative standard deviation
    of ``sqrt(2 / edf)``: the long taus, few clusters, weigh little.
    """
    from scipy.optimize import nnls  # type: ignore[import-untyped]  # scipy ships no types
    tau, avar = allan.tau_s, allan.adev ** 2
    if len(tau) < 3:
        raise ValueError(f'{len(tau)} Allan deviation values are too few to fit the noise terms')
    sigma = avar * np.sqrt(2.0 / allan.degrees_of_freedom(sample_rate_hz))
    design = np.column_stack([f * tau ** p for f, p in zip(_FACTORS, _POWERS)]) / sigma[:, None]
    squares, _ = nnls(design, avar / sigma)
    values = np.sqrt(squares)
    parts = np.array([f * s * tau ** p for f, s, p in zip(_FACTORS, squares, _POWERS)])
    # Shown: a share of the variance at some tau beyond both SHOWN_SHARE and twice that value's own uncertainty.
    shown = np.any(parts / parts.sum(axis=0) >= np.maximum(SHOWN_SHARE, 2.0 * sigma / avar), axis=1)
    return NoiseTerms(float(values[0]) if shown[0] else None, float(values[1]), float(values[2]),
                      float(values[3]), float(values[4]) if shown[4] else None)


# The Allan deviation of bias instability is this times the bias instability (IEEE Std 952: sqrt(2 ln 2 / pi)).
FLOOR_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)


def allan_floor_dps(allan: AllanDeviation, sample_rate_hz: float, min_tau_s: float = 0.0) -> float:
    """The bias instability read as the floor: the least of the fitted deviation from ``min_tau_s`` on, / 0.664.

    The fitted curve, not the measured points: the least of a few noisy long-tau values is
    biased low. Where white noise still falls at the longest tau, this is an upper bound of
    the bias instability (what the record can tell apart from it); where the floor is flat,
    it is the fitted term. ``calibrate fit``'s materiality and noise budget read it.
    """
    taus = allan.tau_s[allan.tau_s >= min(min_tau_s, float(allan.tau_s[-1]))]
    if len(allan.tau_s) < 3:
        return float(allan.adev[-len(taus):].min() / FLOOR_FACTOR)
    terms = fit_noise_terms(allan, sample_rate_hz)
    grid = np.geomspace(taus[0], taus[-1], 200)
    return float(terms.adev(grid).min() / FLOOR_FACTOR)


@dataclass(frozen=True)
class NodeParameters:
    """The node's parameters from the measured noise, at its rate ``rate_hz``."""

    rate_hz: float
    yaw_rate_stddev: float        # rad/s
    bias_samples: int
    bias_window_s: float
    bias_error_dps: float         # the Allan deviation at that window: the static bias's expected error
    limited_by: str               # '' or why the window is not the criterion's (record length, parameter range)

    def snippet(self) -> str:
        """A params file the node reads beside its others (``--params-file``)."""
        return ('/**:\n  ros__parameters:\n'
                f'    yaw_rate_stddev: {self.yaw_rate_stddev:.6g}   # rad/s: white noise at {self.rate_hz:g} Hz\n'
                f'    bias_samples: {self.bias_samples}   # {self.bias_window_s:g} s at {self.rate_hz:g} Hz: static '
                f'bias error {self.bias_error_dps * DEG_PER_H_PER_DPS:.3g} deg/h\n')


def node_parameters(terms: NoiseTerms, allan: AllanDeviation, rate_hz: float) -> NodeParameters:
    """``yaw_rate_stddev`` and ``bias_samples`` for a node that publishes at ``rate_hz``.

    ``yaw_rate_stddev`` is one sample's white noise at that rate (REP 145: the covariance from
    measurement): ``sqrt(N^2 f + 3 Q^2 f^2)``, the fitted white terms' Allan deviation at
    ``tau = 1/f``, where one sample is one average.

    ``bias_samples``: the node takes the static bias as the mean rate over a window T and
    uses it from then on. The Allan variance at T is by definition half the mean square
    difference between the mean over one window and the mean over the next,
    ``sigma^2(T) = E[(y_{k+1}(T) - y_k(T))^2] / 2`` (IEEE Std 952-1997, C.1): the error of a
    bias taken over T, seen over the next T. White noise makes it fall as ``T^-1/2``, rate
    random walk and ramp make it grow, so it has a least value, the best window (El-Sheimy,
    Hou and Niu, IEEE Trans. Instrum. Meas. 57(1), 2008, take the Allan minimum as the
    averaging time of a bias). Where bias instability makes the minimum a flat floor, the
    window is the shortest whose fitted deviation is within :data:`BIAS_WINDOW_TOLERANCE` of
    the least: the robot waits far less for a bias error at most 10 % larger. Searched only
    over the taus the record measured, and within the parameter's range.
    """
    check_node_rate(rate_hz)
    white = math.sqrt(terms.arw_dps_sqrt_s ** 2 * rate_hz + 3.0 * (terms.quantisation_deg or 0.0) ** 2 * rate_hz ** 2)
    low_s, high_s = BIAS_SAMPLES_RANGE[0] / rate_hz, BIAS_SAMPLES_RANGE[1] / rate_hz
    longest = float(allan.tau_s[-1])
    grid = np.geomspace(max(low_s, float(allan.tau_s[0])), max(min(high_s, longest), low_s), 400)
    model = terms.adev(grid)
    best = int(np.flatnonzero(model <= BIAS_WINDOW_TOLERANCE * model.min())[0])
    window = float(grid[best])
    limited = ''
    end = terms.parts(grid[-1])[:, 0]
    # The least at the end of what could be searched, where white noise could still lower it beyond the tolerance.
    if model[-1] < model[-2] and (end[0] + end[1]) / end.sum() > 1.0 - BIAS_WINDOW_TOLERANCE ** -2:
        limited = ('the bias error still falls at the longest tau: ' +
                   ('the parameter\'s range' if high_s < longest else 'a longer record would allow a longer window'))
    samples = int(np.clip(round(window * rate_hz), *BIAS_SAMPLES_RANGE))
    low, high = YAW_RATE_STDDEV_RANGE
    if not low <= math.radians(white) <= high:
        raise ValueError(f'the white noise fitted, {math.radians(white):.3g} rad/s per sample at {rate_hz:g} Hz, is '
                         f'outside what the node takes as yaw_rate_stddev ({low:g}..{high:g} rad/s): not the noise '
                         'of a gyro at rest')
    return NodeParameters(rate_hz, math.radians(white), samples, samples / rate_hz,
                          float(terms.adev(samples / rate_hz)[0]), limited)


def check_node_rate(rate_hz: float) -> None:
    """Refuse a node frame rate outside :data:`NODE_RATE_HZ_RANGE` (a ValueError naming it)."""
    low, high = NODE_RATE_HZ_RANGE
    if not low <= rate_hz <= high:
        raise ValueError(f'--node-rate-hz must be in {low:g}..{high:g} Hz (the node\'s frame rate), got {rate_hz:g}')


@dataclass(frozen=True)
class RecordStats:
    """How the record's samples are spaced: the Allan deviation assumes equal spacing."""

    samples: int
    duration_s: float
    sample_rate_hz: float
    gaps: int              # intervals longer than 1.5 nominal periods
    longest_gap_s: float
    mean_rate_dps: float


RateChunks = Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]


def check_sample_rate(rate_hz: float, where: str) -> None:
    """Refuse a record whose times give a sample rate no gyro has, saying in which unit they would be plausible."""
    low, high = PLAUSIBLE_RATE_HZ
    if low <= rate_hz <= high:
        return
    plausible = [f'{rate_hz * factor:.4g} Hz if they are {unit}' for unit, factor in TIME_UNITS
                 if low <= rate_hz * factor <= high]
    raise ValueError(f'{where}: the times give {rate_hz:.3g} samples per second, not a gyro\'s ({low:g}..{high:g} Hz): '
                     'the time column must be in seconds' + (f' ({"; ".join(plausible)})' if plausible else ''))


def table_at_rest(logs: Iterable[GyroLog], where: str) -> RateChunks:
    """The (t, rate) of a log's chunks; refuses a log whose ``ref_rate`` is not 0 throughout (a table turning)."""
    rows = 0
    for log in logs:
        if log.ref_rate is not None:
            moving = np.flatnonzero(log.ref_rate != 0.0)
            if len(moving):
                k = int(moving[0])
                raise ValueError(f'{where}: not at rest: ref_rate is {log.ref_rate[k]:g} deg/s at row {rows + k + 1} '
                                 f'(t = {log.t[k]:.6g} s): calibrate allan needs a record of the gyro at rest, '
                                 'not a rate-table run (record one, or cut out a part where ref_rate is 0)')
        rows += len(log)
        yield log.t, log.rate_dps


class _Stillness:
    """Whether a record is at rest: the steps between consecutive block means against what white noise allows."""

    def __init__(self, rate_hz: float) -> None:
        self.block = max(2, round(STILL_BLOCK_S * rate_hz))
        self._carry = np.empty(0)
        self._carry_t = math.nan
        self._means: list[NDArray[np.float64]] = []
        self._starts: list[NDArray[np.float64]] = []
        self._last = math.nan
        self._squares = 0.0
        self._count = 0

    def add(self, t: NDArray[np.float64], rate: NDArray[np.float64]) -> None:
        d = np.diff(rate) if math.isnan(self._last) else np.diff(np.concatenate(([self._last], rate)))
        self._last = float(rate[-1])
        if len(d) >= 1 / TRIM:
            low, high = np.quantile(d, [TRIM, 1.0 - TRIM])
            d = d[(d >= low) & (d <= high)]
        self._squares += float(np.dot(d, d))
        self._count += len(d)
        start_t = self._carry_t if len(self._carry) else float(t[0])
        x = np.concatenate((self._carry, rate))
        full = len(x) // self.block * self.block
        if full:
            self._means.append(x[:full].reshape(-1, self.block).mean(axis=1))
            # Each block's start time: the carried block's, then those of the chunk.
            firsts = np.arange(0, full, self.block) - len(self._carry)
            self._starts.append(np.where(firsts < 0, start_t, t[np.maximum(firsts, 0)]))
        self._carry = x[full:]
        self._carry_t = float(t[len(t) - len(self._carry)]) if len(self._carry) else math.nan

    def white_dps(self) -> float:
        """The per-sample white noise (deg/s) the trimmed differences give."""
        return math.sqrt(self._squares / self._count / TRIM_VARIANCE / 2.0) if self._count else 0.0

    def check(self, where: str) -> None:
        """Refuse a record with a step between consecutive blocks beyond what its white noise allows."""
        means = np.concatenate(self._means) if self._means else np.empty(0)
        if len(means) < 2:
            return
        bound = STILL_SIGMAS * self.white_dps() * math.sqrt(2.0 / self.block)
        steps = np.abs(np.diff(means))
        moving = np.flatnonzero(steps > bound)
        if len(moving):
            k = int(moving[0])
            starts = np.concatenate(self._starts)
            raise ValueError(
                f'{where}: not at rest: the mean rate steps by {steps[k]:.4g} deg/s between the {STILL_BLOCK_S:g} s '
                f'blocks from {starts[k]:.6g} s and {starts[k + 1]:.6g} s, where white noise of '
                f'{self.white_dps():.3g} deg/s a sample allows {bound:.3g} ({STILL_SIGMAS:g} sigma); '
                f'{len(moving)} of {len(steps)} steps are beyond it. calibrate allan needs a record of the gyro at '
                'rest: record one, or cut the still part out of this one')


def accumulate(chunks: RateChunks, accumulator: AllanAccumulator, progress: Callable[[int], None],
               where: str = 'the record') -> RecordStats:
    """Feed the chunks' rates to ``accumulator``; the spacing of their times ``t`` (s).

    Refuses (ValueError naming ``where``) times that go back, times in another unit than seconds, a record that
    is not at rest (:class:`_Stillness`) and a constant one.
    """
    first_t = last_t = math.nan
    nominal = math.nan
    gaps, longest, total = 0, 0.0, 0.0
    lowest, highest = math.inf, -math.inf
    still: _Stillness | None = None
    for t, rate in chunks:
        if not len(t):
            continue
        if math.isnan(first_t):
            first_t = float(t[0])
            steps = np.diff(t)
            nominal = float(np.median(steps)) if len(steps) else math.nan
            if nominal == 0.0:
                raise ValueError(f'{where}: most of its first {len(t)} times repeat the one before (from '
                                 f'{first_t:.9g} s): the times must be the samples\' own, in seconds')
            if nominal > 0:
                check_sample_rate(1.0 / nominal, where)
                still = _Stillness(1.0 / nominal)
        times = t if math.isnan(last_t) else np.concatenate(([last_t], t))
        dt = np.diff(times)
        back = np.flatnonzero(dt < 0)
        if len(back):
            k = int(back[0])
            number = accumulator.samples + k + len(t) - len(times) + 2   # 1 = the record's first sample
            raise ValueError(f'{where}: time goes back at sample {number}: {times[k + 1]:.9g} s after '
                             f'{times[k]:.9g} s; the Allan deviation needs the samples in the order taken')
        if len(dt) and nominal > 0:
            gaps += int(np.count_nonzero(dt > 1.5 * nominal))
            longest = max(longest, float(dt.max()))
        last_t = float(t[-1])
        accumulator.add(rate)
        if still is not None:
            still.add(t, rate)
        total += float(np.sum(rate))
        lowest, highest = min(lowest, float(rate.min())), max(highest, float(rate.max()))
        progress(accumulator.samples)
    n = accumulator.samples
    if n < 2 or not last_t > first_t:
        raise ValueError(f'{n} samples over {last_t - first_t if n else 0:g} s: too short for an Allan deviation')
    if lowest == highest:
        raise ValueError(f'{where}: every one of its {n} samples reads {lowest:g} deg/s: a constant record (a stuck '
                         'or all-zero stream) has no noise to analyse')
    if still is not None:
        still.check(where)
    duration = last_t - first_t
    return RecordStats(n, duration, (n - 1) / duration, gaps, longest if gaps else 0.0, total / n)


@dataclass(frozen=True)
class AllanResult:
    """What ``calibrate allan`` measured."""

    source: str
    stats: RecordStats
    allan: AllanDeviation
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    terms: NoiseTerms
    node: NodeParameters

    def to_dict(self) -> dict[str, Any]:
        """ALLAN.json."""
        return {
            'source': self.source,
            **self.terms.to_dict(),
            'record': {'samples': self.stats.samples, 'duration_s': self.stats.duration_s,
                       'sample_rate_hz': self.stats.sample_rate_hz, 'gaps': self.stats.gaps,
                       'longest_gap_s': self.stats.longest_gap_s, 'mean_rate_dps': self.stats.mean_rate_dps},
            'allan_deviation': {'tau_s': self.allan.tau_s.tolist(), 'adev_dps': self.allan.adev.tolist(),
                                'confidence': CONFIDENCE, 'low_dps': self.low.tolist(), 'high_dps': self.high.tolist(),
                                'terms': self.allan.terms.tolist(),
                                'fitted_dps': self.terms.adev(self.allan.tau_s).tolist()},
            'node_parameters': {'rate_hz': self.node.rate_hz, 'yaw_rate_stddev': self.node.yaw_rate_stddev,
                                'bias_samples': self.node.bias_samples, 'bias_window_s': self.node.bias_window_s,
                                'static_bias_error_deg_per_h': self.node.bias_error_dps * DEG_PER_H_PER_DPS,
                                'limited_by': self.node.limited_by},
            'params_snippet': self.node.snippet(),
        }


def allan_of_record(chunks: RateChunks, source: str, node_rate_hz: float | None = None,
                    progress_total: float | None = None, progress_stream: TextIO | None = sys.stderr,
                    temp_dir: str | None = None) -> AllanResult:
    """Allan deviation, noise terms and node parameters of a record at rest given as (t, rate deg/s) chunks.

    ``node_rate_hz``: the node's rate for its parameters (default: the record's).
    ``progress_total``: the samples expected, for a progress bar on a terminal.
    """
    bar = Progress(progress_stream, progress_total, f'calibrate allan: {Path(source).name}')
    with AllanAccumulator(directory=temp_dir) as accumulator:
        stats = accumulate(chunks, accumulator, bar.update, source)
        bar.done()
        allan = accumulator.result(stats.sample_rate_hz)
    low, high = allan.confidence(stats.sample_rate_hz, CONFIDENCE)
    terms = fit_noise_terms(allan, stats.sample_rate_hz)
    node = node_parameters(terms, allan, node_rate_hz or stats.sample_rate_hz)
    return AllanResult(source, stats, allan, low, high, terms, node)


def plot_allan(result: AllanResult, path: str | os.PathLike[str]) -> Path:
    """The Allan deviation with its confidence band, the fitted terms' slopes and their sum (PNG)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    allan = result.allan
    dph = DEG_PER_H_PER_DPS
    fig, ax = plt.subplots(figsize=(8, 5.5))
    ax.fill_between(allan.tau_s, result.low * dph, result.high * dph, color='tab:blue', alpha=0.25,
                    label=f'{100 * CONFIDENCE:.0f} % confidence')
    ax.loglog(allan.tau_s, allan.adev * dph, 'o-', color='tab:blue', ms=3, label='overlapping Allan deviation')
    tau = np.geomspace(allan.tau_s[0], allan.tau_s[-1], 200)
    parts = result.terms.parts(tau)
    named = result.terms.to_dict()
    labels = (f'quantisation {named["quantisation_deg"] or 0:.3g} deg (slope -1)',
              f'ARW {named["arw_deg_per_sqrt_h"]:.3g} deg/sqrt(h) (slope -1/2)',
              f'bias instability {named["bias_instability_deg_per_h"]:.3g} deg/h (0)',
              f'RRW {named["rate_random_walk_deg_per_h_per_sqrt_h"]:.3g} deg/h/sqrt(h) (+1/2)',
              f'rate ramp {named["rate_ramp_deg_per_h_per_h"] or 0:.3g} deg/h/h (+1)')
    for part, label, style in zip(parts, labels, (':', '--', '-.', '--', ':')):
        if np.any(part > 0):
            ax.loglog(tau, np.sqrt(part) * dph, style, lw=1.2, label=label)
    ax.loglog(tau, result.terms.adev(tau) * dph, 'k-', lw=1, label='fitted sum')
    window = result.node.bias_window_s
    ax.axvline(window, color='grey', lw=0.8)
    # At the top, beside the line: the deviation falls with tau, so the curve is low where the window is.
    ax.text(window, 0.98, f'bias window {window:.4g} s\n(bias_samples {result.node.bias_samples} at '
            f'{result.node.rate_hz:g} Hz) ', transform=ax.get_xaxis_transform(), va='top', ha='right', fontsize=8,
            color='dimgrey')
    ax.set_xlabel('averaging time tau (s)')
    ax.set_ylabel('Allan deviation (deg/h)')
    ax.set_title(f'{Path(result.source).name}: {result.stats.samples} samples at {result.stats.sample_rate_hz:.4g} Hz')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8, loc='lower left')
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
