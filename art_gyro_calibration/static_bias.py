"""Static bias drift calibration: the report's ``StaticBias()`` with a check that the gyro was still.

Before every mission the gyro sits still for ``n`` samples (100 = 10 s at 10 Hz).
``StaticBiasDrift`` is the mean scaled rate (it holds the bias of the day and the
Earth's rate) and ``CalcStaticBiasDrift`` the mean modelled error over the same
samples; the output is ``rate - StaticBiasDrift - error + CalcStaticBiasDrift``.

A model with temperature-rate terms (the Shupe effect) meets a problem the report's
polynomial does not have: over the first seconds the causal temperature-rate filter has
seen no history and reads about 0, while a freshly powered gyro self-heats. The
static bias then absorbs the Shupe error of its window for the whole mission. So the
window is kept, and once the temperature has been followed for a few filter time
constants (:class:`Refinement`) the rate of temperature over the window is estimated
from both sides of it, and ``CalcStaticBiasDrift`` is recomputed with it, once.

Until then the filter's first minutes cannot serve either: it rises from 0 and, on a decaying
self-heating, overshoots. So the temperature-rate terms are evaluated on the slope of the same
polynomial, fitted provisionally to the temperatures seen so far, at the sample and over the window.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.units import DEG_PER_H_PER_DPS

DEFAULT_SAMPLES = 100
# At rest an RD2100 reads its modelled error plus well under 0.02 deg/s of bias drift and
# Earth rate, with a per-sample noise of a few counts (0.00305 deg/s each) at 10 Hz. So the
# motion check is on the mean of rate - error: beyond these bounds the robot was moving,
# not the gyro drifting (the modelled error alone reaches 0.1 deg/s at some temperatures).
DEFAULT_MAX_MEAN_DPS = 0.1
DEFAULT_MAX_STD_DPS = 0.05
# A refinement fits the temperature over this many temperature-rate filter time constants from
# the window's start (long enough to see a slope through 0.05 degC counts) with a polynomial in time of this
# degree. A quadratic read the slope of a self-heating of 6 degC with a 5 min time constant 9 % low at the
# window: 3.7 deg/h of a Shupe effect of 0.6 deg/s per degC/s, in the bias for the whole mission; a cubic 1 %,
# its noise 0.05 deg/h (0.05 degC counts).
REFINE_SPAN_TAUS = 3.0
REFINE_DEGREE = 3
# Before the refinement, the polynomial is fitted provisionally to the temperatures seen so far once they span this many
# filter time constants from the window's start (1 min by default): over 20 s, one 0.05 degC count of a slow warm-up
# swings a cubic's slope by 30 deg/h of a 0.6 deg/s per degC/s Shupe term (measured). Until then the terms hold their
# window mean. It is solved again every PROVISIONAL_STEP_S of the samples' time (once a second at 1 kHz too).
PROVISIONAL_TAUS = 0.5
PROVISIONAL_STEP_S = 1.0

# One sample (the node) or a whole log (apply_calibration).
Rate = TypeVar('Rate', float, NDArray[np.float64])


class MotionError(ValueError):
    """The samples of a static bias collection show the gyro was turning."""


class NoNoiseError(ValueError):
    """The samples of a static bias collection do not vary at all: a stuck or all-zero stream, not a gyro."""


# A spread of the rate below this (deg/s) over at least ZERO_SPREAD_MIN_SAMPLES samples is none at all (rounding of
# the running sums aside): every gyro's noise moves a sample by counts (an RD2100's is 0.003 deg/s).
ZERO_SPREAD_DPS = 1e-6
ZERO_SPREAD_MIN_SAMPLES = 10


if TYPE_CHECKING:
    from art_gyro_calibration.terms import Term


@dataclass(frozen=True)
class BiasWindow:
    """The samples a static bias was taken over, kept to refine it.

    ``causal_dps`` is the mean of the temperature-rate terms over them, as the causal filter gave them.
    """

    t: NDArray[np.float64]
    rate_dps: NDArray[np.float64]
    temp_c: NDArray[np.float64]
    causal_dps: float


@dataclass(frozen=True)
class StaticBias:
    """Result of one static bias collection (deg/s); ``refined_dps`` is what a refinement added."""

    static_bias_drift_dps: float
    calc_static_bias_drift_dps: float
    samples: int
    rate_std_dps: float
    window: BiasWindow | None = field(default=None, compare=False, repr=False)
    refined_dps: float = 0.0

    def correct(self, rate_dps: Rate, error_dps: Rate) -> Rate:
        """``CompRate`` of the report, for one sample or arrays of them."""
        return rate_dps - self.static_bias_drift_dps - error_dps + self.calc_static_bias_drift_dps

    def describe(self) -> str:
        """One line for people: the values found."""
        # In deg/h to 3 significant digits: a refinement is often far below the 1e-6 deg/s printed beside it.
        refined = f', refined by {self.refined_dps * DEG_PER_H_PER_DPS:+.3g} deg/h' if self.refined_dps else ''
        return (f'StaticBiasDrift={self.static_bias_drift_dps:.6f} deg/s, '
                f'CalcStaticBiasDrift={self.calc_static_bias_drift_dps:.6f} deg/s{refined} '
                f'over {self.samples} samples (rate std {self.rate_std_dps:.6f} deg/s)')


NO_BIAS = StaticBias(0.0, 0.0, 0, 0.0)


def static_bias(rate_dps: ArrayLike, error_dps: ArrayLike,
                max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                max_std_dps: float = DEFAULT_MAX_STD_DPS) -> StaticBias:
    """Static bias over still samples; raises :class:`MotionError` if they show motion."""
    rate = np.asarray(rate_dps, dtype=float)
    error = np.asarray(error_dps, dtype=float)
    if rate.size == 0 or rate.shape != error.shape:
        raise ValueError(f'static bias needs equally many rates and errors, got {rate.shape} and {error.shape}')
    return _checked(float(rate.mean()), float(error.mean()), float(rate.std()), rate.size,
                    max_mean_dps, max_std_dps)


class StaticBiasCollector:
    """Collects a static bias one sample at a time, as the node receives frames.

    With ``keep_window`` it also keeps each sample's time, rate and temperature and the
    temperature-rate terms' part of its error (a :class:`BiasWindow`, for a :class:`Refinement`).
    """

    __slots__ = ('samples', 'max_mean_dps', 'max_std_dps', '_n', '_sum_rate', '_sum_sq', '_sum_error',
                 '_window', '_sum_causal')

    def __init__(self, samples: int = DEFAULT_SAMPLES, max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                 max_std_dps: float = DEFAULT_MAX_STD_DPS, keep_window: bool = False) -> None:
        if samples < 2:
            raise ValueError(f'a static bias needs at least 2 samples, got {samples}')
        self.samples = samples
        self.max_mean_dps = max_mean_dps
        self.max_std_dps = max_std_dps
        self._n = 0
        self._sum_rate = 0.0
        self._sum_sq = 0.0
        self._sum_error = 0.0
        self._sum_causal = 0.0
        self._window = np.empty((3, samples)) if keep_window else None

    def add(self, rate_dps: float, error_dps: float, t: float = 0.0, temp_c: float = 0.0,
            causal_dps: float = 0.0) -> bool:
        """Add a sample; True once ``samples`` have been collected."""
        if self._window is not None:
            self._window[:, self._n] = t, rate_dps, temp_c
            self._sum_causal += causal_dps
        self._n += 1
        self._sum_rate += rate_dps
        self._sum_sq += rate_dps * rate_dps
        self._sum_error += error_dps
        return self._n >= self.samples

    @property
    def count(self) -> int:
        """Samples collected so far."""
        return self._n

    def result(self) -> StaticBias:
        """The static bias of the collected samples; raises :class:`MotionError` on motion, NoNoiseError on none."""
        n = self._n
        mean = self._sum_rate / n
        std = math.sqrt(max(self._sum_sq / n - mean * mean, 0.0))
        bias = _checked(mean, self._sum_error / n, std, n, self.max_mean_dps, self.max_std_dps)
        # The node's collections only: a log (calibrate apply, a synthetic test) may be noise-free by design.
        if std < ZERO_SPREAD_DPS and n >= ZERO_SPREAD_MIN_SAMPLES:
            raise NoNoiseError(f'rate spread {std:.3g} deg/s over {n} samples: no gyro is that quiet (every '
                               f'sample {mean:g} deg/s): a stuck or all-zero stream (wrong baud rate?)')
        if self._window is None:
            return bias
        t, rate, temp = self._window[:, :n].copy()
        return replace(bias, window=BiasWindow(t, rate, temp, self._sum_causal / n))


class Refinement:
    """Refines a static bias once the temperature around its window is known (see the module's docstring).

    The temperature from the window's start over :data:`REFINE_SPAN_TAUS` times ``tau_s`` (the filters'
    :attr:`~art_gyro_calibration.signals.SignalFilters.refinement_scale_s`: 120 s at either filter's default, by
    which the constants here were measured) is fitted with a polynomial in time (:data:`REFINE_DEGREE`); its slope
    at each window sample replaces what the causal filter read there, and ``CalcStaticBiasDrift`` moves by the
    change of the temperature-rate ``terms``' mean.
    Until :attr:`ready_at` the terms' part of the modelled error is :meth:`error_one` (the node, a sample at a
    time) or :meth:`error_many` (arrays): the provisional fit's slope at the sample less its mean over the window,
    on top of the window's mean as the filter gave it. The refined bias applies from the first sample at or
    after :attr:`ready_at`.
    """

    __slots__ = ('bias', 'terms', 'span_s', 'center', 'ready_at', 'sums', 'provisional_from', 'tick', 'slope',
                 'window_terms_dps')

    def __init__(self, bias: StaticBias, terms: Sequence[Term], tau_s: float) -> None:
        if bias.window is None:
            raise ValueError('a refinement needs the static bias window')
        window = bias.window
        self.bias = bias
        self.terms = tuple(terms)
        self.span_s = refinement_span_s(tau_s)
        self.center = 0.5 * float(window.t[0] + window.t[-1])
        self.ready_at = float(window.t[0]) + self.span_s
        self.provisional_from = float(window.t[0]) + PROVISIONAL_TAUS * tau_s
        # Sums of u^0..u^2d and T u^0..u^d, u = (t - center) / span: the normal equations of the polynomial.
        self.sums = _columns(window.t, window.temp_c, self.center, self.span_s).sum(axis=0)
        # The provisional fit: the step it was last solved in (-1: not yet), its slope's coefficients in u
        # (degC/s) and the terms' mean over the window on that slope.
        self.tick = -1
        self.slope: NDArray[np.float64] | None = None
        self.window_terms_dps = 0.0

    def error_one(self, t: float, temp_c: float, rate_dps: float, others_dps: float) -> float:
        """Add one sample (before :attr:`ready_at`); the modelled error: ``others_dps`` (the other terms') and these.

        The static bias took the true error of these terms over its window; the filter read about 0 there
        and rises over the next minutes, so its value would subtract that error a second time.
        """
        u = (t - self.center) / self.span_s
        sums = self.sums
        power = 1.0
        for k in range(2 * REFINE_DEGREE + 1):
            sums[k] += power
            if k <= REFINE_DEGREE:
                sums[2 * REFINE_DEGREE + 1 + k] += temp_c * power
            power *= u
        if t >= self.provisional_from:
            tick = math.floor((t - self.provisional_from) / PROVISIONAL_STEP_S)
            if tick != self.tick:
                self.tick = tick
                self._provisional(sums)
        window = self.bias.window
        assert window is not None   # checked when made
        slope = self.slope
        if slope is None:
            return others_dps + window.causal_dps
        rate_of_temp = 0.0
        for c in slope[::-1]:
            rate_of_temp = rate_of_temp * u + c
        return (others_dps + window.causal_dps - self.window_terms_dps
                + sum(term.evaluate_one(rate_of_temp, rate_dps) for term in self.terms))

    def error_many(self, t: NDArray[np.float64], temp_c: NDArray[np.float64], rate_dps: NDArray[np.float64],
                   others_dps: NDArray[np.float64]) -> NDArray[np.float64]:
        """:meth:`error_one` over arrays of samples (all before :attr:`ready_at`), as the node does them in turn."""
        window = self.bias.window
        assert window is not None
        sums = self.sums + np.cumsum(_columns(t, temp_c, self.center, self.span_s), axis=0)
        tick = np.where(t >= self.provisional_from, np.floor((t - self.provisional_from) / PROVISIONAL_STEP_S), -1)
        # Solved again where the step differs from the last solved one (a sample before provisional_from keeps it).
        counted = np.flatnonzero(tick >= 0)
        last = np.concatenate(([self.tick], tick[counted]))
        solved = counted[last[1:] != last[:-1]]
        # Per sample, the provisional fit in force: -1 the one before these samples, else an index into solved.
        in_force = np.searchsorted(solved, np.arange(len(t)), side='right') - 1
        solved_slopes, determined = _slopes(sums[solved], self.span_s)
        solved_means = np.zeros(len(solved))
        if determined.any():
            solved_means[determined] = self._window_terms(solved_slopes[determined])
        # Rows: the solves, then the fit in force before these samples (-1). A solve not determined keeps the last.
        slopes = np.vstack((solved_slopes, self.slope if self.slope is not None else np.zeros(REFINE_DEGREE)))
        means = np.append(solved_means, self.window_terms_dps)
        has = np.append(determined, self.slope is not None)
        kept = np.maximum.accumulate(np.where(determined, np.arange(len(solved)), -1))
        row = np.append(kept, -1)[in_force]
        if determined.any():
            self.slope, self.window_terms_dps = solved_slopes[kept[-1]].copy(), float(solved_means[kept[-1]])
        out = others_dps + window.causal_dps
        fitted = has[row]
        if fitted.any():
            u = (t[fitted] - self.center) / self.span_s
            rate_of_temp = np.asarray(np.polynomial.polynomial.polyval(u, slopes[row[fitted]].T, tensor=False),
                                      dtype=np.float64)
            terms = np.zeros(len(rate_of_temp))
            for term in self.terms:
                terms += term.evaluate(rate_of_temp, rate_dps[fitted])
            out[fitted] += terms - means[row[fitted]]
        if len(t):
            self.sums = sums[-1].copy()
            self.tick = int(last[-1])
        return np.asarray(out, dtype=np.float64)

    def _provisional(self, sums: NDArray[np.float64]) -> None:
        """Solve the fit for the samples summed in ``sums``; if it is not determined, keep the last."""
        slope = _slope(sums, self.span_s)
        if slope is not None:
            self.slope, self.window_terms_dps = slope, float(self._window_terms(slope[None])[0])

    def _window_terms(self, slopes: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per row of ``slopes``: the terms' mean over the window with the temperature rate it gives each sample."""
        window = self.bias.window
        assert window is not None
        n = len(window.t)
        rate_of_temp = np.asarray(np.polynomial.polynomial.polyval((window.t - self.center) / self.span_s, slopes.T),
                                  dtype=np.float64).ravel()
        rate = np.tile(window.rate_dps, len(slopes))
        total = np.zeros(len(slopes))
        for term in self.terms:
            total += term.evaluate(rate_of_temp, rate).reshape(-1, n).mean(axis=1)
        return total

    def refined(self) -> StaticBias:
        """The static bias with ``CalcStaticBiasDrift`` recomputed; unchanged if the fit is not determined."""
        slope = _slope(self.sums, self.span_s)
        if slope is None:
            return replace(self.bias, window=None)
        window = self.bias.window
        assert window is not None
        delta = float(self._window_terms(slope[None])[0]) - window.causal_dps
        return replace(self.bias, calc_static_bias_drift_dps=self.bias.calc_static_bias_drift_dps + delta,
                       window=None, refined_dps=delta)


def refinement_span_s(tau_s: float) -> float:
    """How long a refinement fits the temperature from the window's start (``tau_s``: the filters' refinement scale)."""
    return REFINE_SPAN_TAUS * tau_s


def _columns(t: NDArray[np.float64], temp_c: NDArray[np.float64], center: float, span_s: float) -> NDArray[np.float64]:
    """Per sample, what it adds to the sums of a refinement's normal equations (u = (t - center) / span_s)."""
    u = (np.asarray(t, dtype=float) - center) / span_s
    powers = u[:, None] ** np.arange(2 * REFINE_DEGREE + 1)
    return np.concatenate((powers, np.asarray(temp_c, dtype=float)[:, None] * powers[:, :REFINE_DEGREE + 1]), axis=1)


def _slope(sums: NDArray[np.float64], span_s: float) -> NDArray[np.float64] | None:
    """The derivative in time of the polynomial the sums fit (coefficients in u, degC/s); None if not determined."""
    slopes, determined = _slopes(sums[None], span_s)
    return slopes[0] if determined[0] else None


def _slopes(sums: NDArray[np.float64], span_s: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per row of ``sums``: the derivative in time of the polynomial they fit (as :func:`_slope`), and if determined.

    Rows not determined (too few samples, not finite, ill-conditioned) give zeros.
    """
    d = REFINE_DEGREE
    normal = sums[:, np.add.outer(np.arange(d + 1), np.arange(d + 1))]
    determined = (sums[:, 0] >= d + 1) & np.all(np.isfinite(normal), axis=(1, 2))
    determined[determined] = np.linalg.cond(normal[determined]) <= 1e12
    slopes = np.zeros((len(sums), d))
    if determined.any():
        coefficients = np.linalg.solve(normal[determined], sums[determined, 2 * d + 1:, None])[..., 0]
        slopes[determined] = coefficients[:, 1:] * np.arange(1, d + 1) / span_s
    return slopes, determined


def refined_temperature_rate(t: NDArray[np.float64], temp_c: NDArray[np.float64],
                             tau_s: float) -> NDArray[np.float64] | None:
    """The temperature rate a node's refinement takes at a run's samples before it is ready (degC/s); None if none.

    The slope of the polynomial :class:`Refinement` fits to the run's temperatures from its first
    sample until it is ready (``tau_s``: the filters'
    :attr:`~art_gyro_calibration.signals.SignalFilters.refinement_scale_s`). The node's refined
    static bias takes the temperature-rate terms on that slope over its window, not on the
    filter's rise from 0; a fit that read the filter there would fit that rise as an effect
    (a 30 s warm-up) the node never sees. Its provisional slopes between window and refinement
    are this one on fewer samples.
    """
    span_s = refinement_span_s(tau_s)
    if not len(t):
        return None
    k = int(np.searchsorted(t, t[0] + span_s, side='left'))
    slope = _slope(_columns(t[:k], temp_c[:k], float(t[0]), span_s).sum(axis=0), span_s)
    if slope is None:
        return None
    return np.asarray(np.polynomial.polynomial.polyval((t[:k] - t[0]) / span_s, slope), dtype=np.float64)


def _checked(mean: float, mean_error: float, std: float, n: int,
             max_mean_dps: float, max_std_dps: float) -> StaticBias:
    if not (math.isfinite(mean) and math.isfinite(std) and math.isfinite(mean_error)):
        raise ValueError(f'static bias over {n} samples: not finite (mean rate {mean}, mean modelled error '
                         f'{mean_error}, rate spread {std} deg/s): a rate or modelled error is NaN or infinite')
    if abs(mean - mean_error) > max_mean_dps:
        raise MotionError(f'mean compensated rate {mean - mean_error:.4f} deg/s over {n} samples exceeds '
                          f'{max_mean_dps} deg/s: the gyro is turning')
    if std > max_std_dps:
        raise MotionError(f'rate spread {std:.4f} deg/s over {n} samples exceeds {max_std_dps} deg/s: '
                          'the gyro is moving')
    return StaticBias(mean, mean_error, n, std)
