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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

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
        refined = f', refined by {self.refined_dps:+.6f} deg/s' if self.refined_dps else ''
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

    The temperature from the window's start over ``span_s`` is fitted with a polynomial in
    time (:data:`REFINE_DEGREE`); its slope at each window sample replaces what the causal filter read there, and
    ``CalcStaticBiasDrift`` moves by the change of the temperature-rate ``terms``' mean.
    Samples come one at a time (:meth:`add`, the node) or as arrays (:meth:`add_many`);
    the refined bias applies from the first sample at or after :attr:`ready_at`.
    """

    __slots__ = ('bias', 'terms', 'span_s', 'center', 'ready_at', 'sums')

    def __init__(self, bias: StaticBias, terms: Sequence[Term], span_s: float) -> None:
        if bias.window is None:
            raise ValueError('a refinement needs the static bias window')
        window = bias.window
        self.bias = bias
        self.terms = tuple(terms)
        self.span_s = span_s
        self.center = 0.5 * float(window.t[0] + window.t[-1])
        self.ready_at = float(window.t[0]) + span_s
        # Sums of u^0..u^2d and T u^0..u^d, u = (t - center) / span: the normal equations of the polynomial.
        self.sums = [0.0] * (3 * REFINE_DEGREE + 2)
        self.add_many(window.t, window.temp_c)

    def add(self, t: float, temp_c: float) -> None:
        """One more sample of the temperature (before :attr:`ready_at`)."""
        u = (t - self.center) / self.span_s
        s = self.sums
        power = 1.0
        for k in range(2 * REFINE_DEGREE + 1):
            s[k] += power
            if k <= REFINE_DEGREE:
                s[2 * REFINE_DEGREE + 1 + k] += temp_c * power
            power *= u

    def add_many(self, t: NDArray[np.float64], temp_c: NDArray[np.float64]) -> None:
        """Many samples at once (all before :attr:`ready_at`)."""
        u = (np.asarray(t, dtype=float) - self.center) / self.span_s
        temp = np.asarray(temp_c, dtype=float)
        powers = [u ** k for k in range(2 * REFINE_DEGREE + 1)]
        for i, column in enumerate(powers + [temp * p for p in powers[:REFINE_DEGREE + 1]]):
            self.sums[i] += float(column.sum())

    def held(self, others_dps: Rate) -> Rate:
        """The modelled error before :attr:`ready_at`: ``others_dps`` (the other terms') plus these terms' window mean.

        The static bias took the true error of these terms over its window, where the causal
        filter read about 0; held there, the filter's rise over the next minutes is not
        subtracted a second time.
        """
        window = self.bias.window
        assert window is not None   # checked when made
        return others_dps + window.causal_dps

    def refined(self) -> StaticBias:
        """The static bias with ``CalcStaticBiasDrift`` recomputed; unchanged if the fit is not determined."""
        d = REFINE_DEGREE
        s = self.sums
        normal = np.array([[s[i + j] for j in range(d + 1)] for i in range(d + 1)])
        if s[0] < d + 1 or not np.all(np.isfinite(normal)) or np.linalg.cond(normal) > 1e12:
            return replace(self.bias, window=None)
        coefficients = np.linalg.solve(normal, s[2 * d + 1:])
        window = self.bias.window
        assert window is not None
        u = (window.t - self.center) / self.span_s
        derivative = np.polynomial.polynomial.polyder(coefficients)
        slope = np.asarray(np.polynomial.polynomial.polyval(u, derivative), dtype=np.float64) / self.span_s   # degC/s
        refit = float(sum(np.mean(t.evaluate(slope, window.rate_dps)) for t in self.terms))
        delta = refit - window.causal_dps
        return replace(self.bias, calc_static_bias_drift_dps=self.bias.calc_static_bias_drift_dps + delta,
                       window=None, refined_dps=delta)


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
