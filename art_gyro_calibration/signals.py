"""Signals an error term can depend on, computed causally from time, rate and temperature.

The node computes them sample by sample (:class:`SignalTracker`) and the offline tools
over a whole log (:func:`compute_signals`); both run the same recursions, so a term
fitted offline corrects the node's output the same way. A log too long for memory is
computed chunk by chunk: each chunk starts from the :class:`SignalState` the previous
one ended in (:meth:`Signals.end_state`), and gives the same values as the whole log.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.static_bias import refined_temperature_rate
from art_gyro_calibration.temperature_rate import (FIRST_ORDER, FORMS, LOCAL_QUADRATIC, SPAN_FACTOR, LocalQuadraticRate,
                                                   local_quadratic_rate)

# The signal whose value a term's own time constant sets: the temperature through a first-order lag.
LAGGED_SIGNAL = 'temperature_lag'
# The signal that counts from the gyro's power-on: only a run declared to start with it can judge a term on it.
POWER_ON_SIGNAL = 'time_since_power_on'

# A temperature count is 0.05 degC and a chamber ramps at about 1 degC/min: the first-order
# derivative needs minutes of smoothing to rise above the quantisation. A file that names no
# filter form was fitted with it, at this time constant unless it names one.
FIRST_ORDER_TAU_S = 120.0
# The local quadratic fit's time constant (:mod:`art_gyro_calibration.temperature_rate`): the lowest median
# error against the true rate over bench/bench_temperature_rate.py's profiles.
DEFAULT_TEMPERATURE_RATE_TAU_S = 20.0
# With the local quadratic temperature rate, the fit reads the temperature smoothed both ways over this (or the
# filter's time constant, if shorter): the counts' noise in the node's rate estimate dilutes a temperature-rate
# coefficient fitted on it by a few per cent, and the node's static-bias refinement, which takes the term's window
# value, has no such noise. (A file that names no form is fitted on the first-order filter as it was.)
FIT_SMOOTHING_S = 20.0
# A two-way smoothing's ends are point-reflected over this many time constants.
REFLECTED_TAUS = 10.0
# Angular acceleration of a rate table or robot settles within a second.
DEFAULT_RATE_CHANGE_TAU_S = 0.5


class RateCorrection(Protocol):
    """What corrects the rate the angle integrates: an error model."""

    def error(self, signals: Signals) -> NDArray[np.float64]:
        """Per sample of ``signals``, what the rate reads too much, deg/s."""


class TermLike(Protocol):
    """What names a term's signal: a term or a term's spec."""

    @property
    def signal(self) -> str: ...

    @property
    def time_constant_s(self) -> float: ...


@dataclass(frozen=True)
class SignalFilters:
    """The causal derivative filters: time constants (s) and the temperature rate's form.

    ``temperature_rate_form``: :data:`~art_gyro_calibration.temperature_rate.LOCAL_QUADRATIC` (new fits) or
    :data:`~art_gyro_calibration.temperature_rate.FIRST_ORDER` (``(x - s1) / tau``: a file that names no form).
    The rate change is always first order.
    """

    temperature_rate_tau_s: float = DEFAULT_TEMPERATURE_RATE_TAU_S
    rate_change_tau_s: float = DEFAULT_RATE_CHANGE_TAU_S
    temperature_rate_form: str = LOCAL_QUADRATIC

    def __post_init__(self) -> None:
        for name in ('temperature_rate_tau_s', 'rate_change_tau_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'filters.{name} must be a positive number of seconds, got {value!r}')
        if self.temperature_rate_form not in FORMS:
            raise ValueError(f'filters.temperature_rate_form must be one of {", ".join(FORMS)}, '
                             f'got {self.temperature_rate_form!r}')

    @property
    def refinement_scale_s(self) -> float:
        """The time scale of a static bias refinement (:class:`~art_gyro_calibration.static_bias.Refinement`).

        The first-order filter's own time constant (as every file before the local quadratic fit). The local
        quadratic fit settles within a few of its shorter ``tau`` (three lags of it), but the refinement's span
        also has to see a slope through 0.05 degC counts: the first-order default's minutes, or ``3 tau`` if longer.
        """
        tau_s = self.temperature_rate_tau_s
        return tau_s if self.temperature_rate_form == FIRST_ORDER else max(FIRST_ORDER_TAU_S, 3.0 * tau_s)


@dataclass(frozen=True)
class Envelope:
    """Where a calibration is meant to hold: the signals' ranges follow from it (:attr:`DerivedSignal.range`)."""

    temperature_range_c: tuple[float, float]
    full_scale_dps: float       # the rate's full scale, either sign
    filters: SignalFilters
    horizon_s: float            # how long a node may run


@dataclass(frozen=True)
class DerivedSignal:
    """One signal derived from (t, rate, temperature), once for every reader.

    :class:`Signals` (over a log) and :class:`SignalTracker` (the node, per sample) compute
    it as the attribute of its name; the calibration checks bound a term on it by ``range``;
    the fit's loop and screen read the flags.
    """

    name: str
    unit: str
    description: str
    range: Callable[[Envelope], tuple[float, float]]   # its bounds over a calibration's envelope
    per_sample: bool = True        # the node tracks it (the angle needs an absolute heading the node lacks)
    temperature: bool = False      # a temperature: clamped to the calibrated range, as the polynomial's is
    from_rate: bool = False        # computed from the measured rate alone (its own error, on a gyro at rest)
    squarable: bool = False        # the loop may grow its linear term a square (not a copy of the polynomial's)


def _temperature_range(e: Envelope) -> tuple[float, float]:
    low_c, high_c = e.temperature_range_c
    return low_c, high_c


def _temperature_rate_range(e: Envelope) -> tuple[float, float]:
    """The estimate is bounded by the span of ``x`` over ``tau``, times its form's factor (:mod:`.temperature_rate`)."""
    low_c, high_c = e.temperature_range_c
    filters = e.filters
    span_c = SPAN_FACTOR[filters.temperature_rate_form] * (high_c - low_c) / filters.temperature_rate_tau_s
    return -span_c, span_c


def _rate_change_range(e: Envelope) -> tuple[float, float]:
    change = 2.0 * e.full_scale_dps / e.filters.rate_change_tau_s
    return -change, change


SIGNALS: dict[str, DerivedSignal] = {s.name: s for s in (
    DerivedSignal('temperature', 'degC', 'the gyro\'s temperature', _temperature_range, temperature=True),
    DerivedSignal('temperature_rate', 'degC/s', 'the temperature\'s rate of change, causally filtered',
                  _temperature_rate_range, squarable=True),
    DerivedSignal('time', 's', 'seconds since the run\'s first sample (a linear drift needs no other origin)',
                  lambda e: (0.0, e.horizon_s)),
    DerivedSignal(POWER_ON_SIGNAL, 's', 'seconds since the gyro\'s power-on, infinite when the run did not start '
                  'with it (a warm-up has then decayed: a warm restart must not replay it)',
                  lambda e: (0.0, e.horizon_s)),
    DerivedSignal(LAGGED_SIGNAL, 'degC', 'the temperature through a first-order lag whose time constant the term '
                  'carries (a fibre coil that lags the sensor)', _temperature_range, temperature=True),
    DerivedSignal('rate', 'deg/s', 'the measured rate', lambda e: (-e.full_scale_dps, e.full_scale_dps),
                  from_rate=True),
    DerivedSignal('rate_abs', 'deg/s', 'the measured rate\'s magnitude', lambda e: (0.0, e.full_scale_dps),
                  from_rate=True),
    DerivedSignal('rate_sign', '', 'the measured rate\'s sign (-1, 0, 1)', lambda e: (-1.0, 1.0), from_rate=True),
    DerivedSignal('rate_change', 'deg/s^2', 'the measured rate\'s rate of change, causally filtered',
                  _rate_change_range, from_rate=True, squarable=True),
    DerivedSignal('angle', 'deg', 'the angle turned, the measured rate integrated',
                  lambda e: (-e.full_scale_dps * e.horizon_s, e.full_scale_dps * e.horizon_s), per_sample=False,
                  from_rate=True),
)}
# Their names, in the registry's order; any other name is an extra log column.
DERIVED_SIGNALS = tuple(SIGNALS)


@dataclass(frozen=True)
class SignalState:
    """Where the causal recursions stand after one sample: all a chunk needs from the log before it."""

    t0: float                   # time of the log's first sample (``time`` counts from it)
    t: float                    # the sample's time, rate and temperature
    rate: float
    temperature: float
    angle: float                # angle turned up to the sample, degrees
    temperature_level: float    # level of the temperature_rate filter (smoothed temperature)
    rate_level: float           # level of the rate_change filter (smoothed rate)
    lag_levels: tuple[tuple[float, float], ...] = ()   # (time constant, level) of each lagged temperature
    angle_rate: float | None = None   # the rate the angle integrates, when not the measured one
    temperature_levels: tuple[float, float] | None = None   # the local quadratic fit's s2, s3 (None: first order)


@dataclass(frozen=True)
class Signals:
    """Every signal of a log or of one chunk of it, one array each, aligned with its samples.

    The derived signals are computed on first use, so a model without extended
    terms costs no filtering. ``previous`` is the state after the sample before
    ``t[0]`` (None: ``t[0]`` is the log's first sample). ``powered_on_at_start``: the
    log starts at the gyro's power-on (a rate-table log does; a run started on a warm gyro
    does not). ``angle_correction``: the angle integrates the measured rate less this
    model's error (none: the measured rate); the loop gives its ART fit, so that a heading
    effect is fitted against the heading, not against the polynomial's own error
    integrated for hours. A model, not a corrected rate: a chunk computes its own rows.
    """

    t: NDArray[np.float64]
    rate: NDArray[np.float64]
    temperature: NDArray[np.float64]
    extras: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)
    filters: SignalFilters = field(default_factory=SignalFilters)
    previous: SignalState | None = None
    powered_on_at_start: bool = True
    angle_correction: RateCorrection | None = field(default=None, compare=False)
    # Several runs of one gyro, one after another (a several-run fit): (first row, began at power-on) of each,
    # the first at row 0; () for one run (``powered_on_at_start`` says how it began). Every causal recursion,
    # ``time`` and ``time_since_power_on`` restart at a run's first row (:meth:`runs`).
    run_starts: tuple[tuple[int, bool], ...] = ()
    # The fit's signals (``calibrate fit``), not the node's: over a run's first minutes the temperature rate is the
    # slope a node's static bias refinement takes there (:func:`static_bias.refined_temperature_rate`), not the
    # filter's rise from 0 (the node's refined bias never applies that rise).
    refined_start: bool = False
    _lags: dict[float, NDArray[np.float64]] = field(default_factory=dict, compare=False, repr=False)
    _levels: dict[str, float | None] = field(default_factory=dict, compare=False, repr=False)
    # States at the ends of chunks of the log (by chunk size), lags aside: :mod:`analysis.chunks` makes
    # each once. Not an init field, so that a replace()d Signals (another angle_correction) starts afresh.
    chunk_states: dict[int, list[SignalState]] = field(default_factory=dict, init=False, compare=False, repr=False)
    # The temperature rate of each of those chunks (by chunk size and chunk), the costliest signal and the same on
    # every pass: one array as long as the log, where each fit of a term on it filtered the log again.
    chunk_rates: dict[tuple[int, int], NDArray[np.float64]] = field(
        default_factory=dict, init=False, compare=False, repr=False)

    def runs(self) -> list[tuple[int, Signals]]:
        """(first row, signals) of each run: each starts afresh, as at a log's first sample (one run: this one)."""
        if not self.run_starts:
            return [(0, self)]
        stops = [first for first, _ in self.run_starts[1:]] + [len(self.t)]
        return [(a, Signals(t=self.t[a:b], rate=self.rate[a:b], temperature=self.temperature[a:b],
                            extras={k: v[a:b] for k, v in self.extras.items()}, filters=self.filters,
                            powered_on_at_start=cold, angle_correction=self.angle_correction,
                            refined_start=self.refined_start))
                for (a, cold), b in zip(self.run_starts, stops)]

    def _joined(self, signal: Callable[[Signals], NDArray[np.float64]]) -> NDArray[np.float64]:
        """``signal`` of each run (:meth:`runs`), one after another."""
        return np.concatenate([signal(run) for _, run in self.runs()])

    @cached_property
    def temperature_rate(self) -> NDArray[np.float64]:
        """Filtered temperature rate of change, degC/s (:attr:`SignalFilters.temperature_rate_form`).

        With :attr:`refined_start`, a run's first minutes hold the refinement's slope instead.
        """
        if self.run_starts:
            return self._joined(lambda run: run.temperature_rate)
        rate = self._filtered_temperature_rate()
        refined = refined_temperature_rate(self.t, self.temperature, self.filters.refinement_scale_s) \
            if self.refined_start and self.previous is None else None
        if refined is None:
            return rate
        out = rate.copy()
        out[:len(refined)] = refined
        return out

    def _filtered_temperature_rate(self) -> NDArray[np.float64]:
        """The temperature rate filter's output, as the node's per-sample filter gives it."""
        tau_s = self.filters.temperature_rate_tau_s
        if self.filters.temperature_rate_form == FIRST_ORDER:
            return self._derivative(self.temperature, 'temperature_level', tau_s)
        previous = self.previous
        if previous is None:
            level = self._smoothed(self.temperature, None, tau_s)
            level2 = self._smoothed(level, None, tau_s)
            level3 = self._smoothed(level2, None, tau_s)
            start = (float(level[0]), float(level[0])) if len(level) else (0.0, 0.0)
            dt = np.diff(self.t, prepend=self.t[:1])
        else:
            if previous.temperature_levels is None:
                raise ValueError('the local quadratic temperature rate continues only from a state with its levels')
            start = previous.temperature_levels
            level = self._smoothed(self.temperature, previous.temperature_level, tau_s)
            level2 = self._smoothed(level, start[0], tau_s)
            level3 = self._smoothed(level2, start[1], tau_s)
            dt = np.diff(self.t, prepend=previous.t)
        if len(level):
            self._levels.update(temperature_level=float(level[-1]), temperature_level2=float(level2[-1]),
                                temperature_level3=float(level3[-1]))
        return local_quadratic_rate((level, level2, level3), start, dt, tau_s)

    @cached_property
    def rate_change(self) -> NDArray[np.float64]:
        """Filtered rate of change of the measured rate, deg/s^2."""
        if self.run_starts:
            return self._joined(lambda run: run.rate_change)
        return self._derivative(self.rate, 'rate_level', self.filters.rate_change_tau_s)

    def _derivative(self, x: NDArray[np.float64], level_name: str, tau_s: float) -> NDArray[np.float64]:
        """``(x - level) / tau`` of the first-order filter; only the last level is kept (for :meth:`end_state`).

        A long log's level would be one more array as long as the log, held for one number.
        """
        start = None if self.previous is None else getattr(self.previous, level_name)
        out = self._smoothed(x, start, tau_s)
        self._levels[level_name] = float(out[-1]) if len(out) else start
        np.subtract(x, out, out=out)   # in place: the level is not kept
        out /= tau_s
        return out

    def _smoothed(self, x: NDArray[np.float64], level: float | None, tau_s: float) -> NDArray[np.float64]:
        """Level of the first-order filter of ``x`` at each sample, continuing from ``level``.

        A derivative is ``(x - level) / tau`` (the batch twin of ``_Derivative``); at a
        log's first sample the level is the sample itself, so the derivative is 0.
        """
        if level is None:
            if len(x) < 2:
                return x.copy()
            decay = _log_decay(self.t, tau_s)
            out = np.empty(len(x))
            out[0] = x[0]
            first_order_smooth(x, decay, out[1:])
            return out
        if not len(x):
            return x.copy()
        assert self.previous is not None   # a level to continue from comes from the previous chunk
        return first_order_smooth(np.concatenate((np.array([level]), x)),
                                  _log_decay(np.concatenate((np.array([self.previous.t]), self.t)), tau_s))

    def forget(self) -> None:
        """Drop the derived signals computed so far; they are computed again when asked for.

        Over a long log each is as long as the log: a caller that works chunk by chunk
        (:mod:`art_gyro_calibration.analysis.chunks`) need not hold them.
        """
        for name in ('temperature_rate', 'rate_change', 'angle'):
            self.__dict__.pop(name, None)
        self._lags.clear()

    def lagged_temperature(self, tau_s: float) -> NDArray[np.float64]:
        """The temperature through a first-order lag of ``tau_s`` (degC), starting at the first sample's."""
        if tau_s not in self._lags and self.run_starts:
            self._lags[tau_s] = self._joined(lambda run: run.lagged_temperature(tau_s))
        if tau_s not in self._lags:
            levels = dict(self.previous.lag_levels) if self.previous is not None else {}
            self._lags[tau_s] = self._smoothed(self.temperature, levels.get(tau_s), tau_s)
        return self._lags[tau_s]

    def for_term(self, term: TermLike) -> NDArray[np.float64]:
        """The signal a term (or a term's spec) is evaluated on: its own lag for ``temperature_lag``."""
        if term.signal == LAGGED_SIGNAL:
            return self.lagged_temperature(term.time_constant_s)
        return self.get(term.signal)

    @property
    def time_since_power_on(self) -> NDArray[np.float64]:
        """Seconds since the gyro's power-on: ``time``, or infinite if the log did not start at power-on."""
        if self.run_starts:
            return self._joined(lambda run: run.time_since_power_on)
        return self.time if self.powered_on_at_start else np.full(len(self.t), np.inf)

    @cached_property
    def angle(self) -> NDArray[np.float64]:
        """Angle turned in degrees, trapezoidal integral of the measured rate (less ``angle_correction``'s error)."""
        if self.run_starts:
            return self._joined(lambda run: run.angle)
        rate = self._angle_rate
        if self.previous is None:
            if not len(rate):
                return np.zeros(0)
            start, t = 0.0, self.t
        else:
            before = self.previous.rate if self.angle_correction is None else self.previous.angle_rate
            if before is None:
                raise ValueError('the angle of a corrected rate continues only from a state that has that rate')
            start = self.previous.angle
            t, rate = np.concatenate(([self.previous.t], self.t)), np.concatenate(([before], rate))
        # One running sum from the start value, so a chunked log adds in the same order as a whole one.
        out = np.cumsum(np.concatenate(([start], 0.5 * (rate[1:] + rate[:-1]) * np.diff(t))))
        return out if self.previous is None else out[1:]

    @property
    def time(self) -> NDArray[np.float64]:
        """Seconds since the first sample (power-on, as far as the log knows)."""
        if self.run_starts:
            return self._joined(lambda run: run.time)
        return self.t - (self.t[0] if self.previous is None else self.previous.t0)

    def end_state(self) -> SignalState:
        """The state after the last sample: pass it to :func:`compute_signals` for the next chunk."""
        if self.run_starts:
            return self.runs()[-1][1].end_state()
        if not len(self.t):
            if self.previous is None:
                raise ValueError('signals of no samples have no state')
            return self.previous
        return SignalState(t0=float(self.t[0]) if self.previous is None else self.previous.t0,
                           t=float(self.t[-1]), rate=float(self.rate[-1]), temperature=float(self.temperature[-1]),
                           angle=float(self.angle[-1]),
                           temperature_level=self._level_at_end('temperature_rate', 'temperature_level'),
                           rate_level=self._level_at_end('rate_change', 'rate_level'),
                           lag_levels=self.lag_levels(),
                           angle_rate=None if self.angle_correction is None else float(self._angle_rate[-1]),
                           temperature_levels=self._quadratic_levels())

    @property
    def _angle_rate(self) -> NDArray[np.float64]:
        """The rate the angle integrates."""
        return self.rate if self.angle_correction is None else self.rate - self.angle_correction.error(self)

    def lag_levels(self) -> tuple[tuple[float, float], ...]:
        """(time constant, level after the last sample) of each lagged temperature computed so far."""
        return tuple((tau, float(lag[-1])) for tau, lag in sorted(self._lags.items()))

    def _quadratic_levels(self) -> tuple[float, float] | None:
        """The local quadratic fit's s2, s3 after the last sample (None for the first-order filter)."""
        if self.filters.temperature_rate_form == FIRST_ORDER:
            return None
        return self._level_at_end('temperature_rate', 'temperature_level2'), \
            self._level_at_end('temperature_rate', 'temperature_level3')

    def _level_at_end(self, derivative: str, level: str) -> float:
        """The level after the last sample of the filter of ``derivative`` (computed if not yet)."""
        getattr(self, derivative)
        value = self._levels[level]
        assert value is not None   # computing the derivative set it
        return float(value)

    @property
    def rate_abs(self) -> NDArray[np.float64]:
        """Magnitude of the measured rate, deg/s."""
        return np.abs(self.rate)

    @property
    def rate_sign(self) -> NDArray[np.float64]:
        """Sign of the measured rate (-1, 0, 1)."""
        return np.sign(self.rate)

    def names(self) -> tuple[str, ...]:
        """All signal names available, derived ones first."""
        return DERIVED_SIGNALS + tuple(self.extras)

    def get(self, name: str) -> NDArray[np.float64]:
        """Signal ``name``: a derived one or an extra column of the log."""
        if name == LAGGED_SIGNAL:
            raise KeyError(f'signal {LAGGED_SIGNAL!r} needs its time constant: use for_term or lagged_temperature')
        if name in DERIVED_SIGNALS:
            return np.asarray(getattr(self, name), dtype=float)
        try:
            return self.extras[name]
        except KeyError:
            raise KeyError(f'signal {name!r} is neither derived ({", ".join(DERIVED_SIGNALS)}) '
                           f'nor a column of the log ({", ".join(self.extras) or "none"})') from None

    def __len__(self) -> int:
        return len(self.t)


# Span of log-decay one chunk of :func:`first_order_smooth` covers: exp(500) stays far from overflow.
_CHUNK_LOG_DECAY = 500.0
# Steps of :func:`first_order_smooth` taken per chunk at most: bounds its temporaries. Where a chunk ends, the
# closed form restarts: the value sets the rounding of the smoothed signals, and every fit's numbers with them.
_SMOOTH_CHUNK_ROWS = 1 << 16


def _log_decay(t: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """Log of each step's decay factor, ``-max(dt, 0) / tau``, in one array (a long log's temporaries add up)."""
    out = np.diff(t)
    np.maximum(out, 0.0, out=out)
    out /= -tau_s
    return out


def first_order_smooth(x: NDArray[np.float64], log_decay: NDArray[np.float64],
                       out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """``s[i] = s[i-1] + (1 - exp(log_decay[i-1])) * (x[i] - s[i-1])`` from ``s[0] = x[0]``, for i >= 1.

    The recursion in closed form, ``s_i = s_0 + D_i sum_j a_j (x_j - s_0) / D_j`` with ``D`` the
    cumulative decay, vectorised over chunks short enough that ``1 / D`` stays finite. Each
    rounding error decays with the filter, so the result matches the per-sample loop to
    a few ulps of ``(x - s_0) / a``. Runs with numpy alone (the node's runtime has no scipy).
    ``out``: where to write the result (len(log_decay) values); no array but it spans ``x``.
    """
    n = len(log_decay)
    out = np.empty(n) if out is None else out
    level = float(x[0])
    start = 0
    while start < n:
        # A step decaying by more than exp(-500) forgets the past: its gain is 1.0 either way.
        step = np.maximum(log_decay[start:start + _SMOOTH_CHUNK_ROWS], -_CHUNK_LOG_DECAY)
        span = np.cumsum(step)
        stop = start + max(1, int(np.searchsorted(-span, _CHUNK_LOG_DECAY, side='right')))
        cumulative = span[:stop - start]
        # On x less the level the chunk starts from: the sum's rounding scales with |x - level|, not |x|.
        weights = -np.expm1(step[:stop - start]) * (x[start + 1:stop + 1] - level) * np.exp(-cumulative)
        out[start:stop] = level + np.exp(cumulative) * np.cumsum(weights)
        level = float(out[stop - 1])
        start = stop
    return out


def smoothed_both_ways(t: NDArray[np.float64], x: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """``x`` through a first-order filter of ``tau_s`` forwards, then backwards: averaged, and no lag.

    The ends are point-reflected over :data:`REFLECTED_TAUS` time constants, so a slope at an end is kept.
    """
    if len(x) < 3:
        return x.copy()
    head = max(int(np.searchsorted(t, t[0] + REFLECTED_TAUS * tau_s)), 2)
    tail = min(int(np.searchsorted(t, t[-1] - REFLECTED_TAUS * tau_s)), len(x) - 3)
    tt = np.concatenate((2.0 * t[0] - t[head - 1:0:-1], t, 2.0 * t[-1] - t[-2:tail:-1]))
    xx = np.concatenate((2.0 * x[0] - x[head - 1:0:-1], x, 2.0 * x[-1] - x[-2:tail:-1]))
    forwards = np.empty(len(xx))
    forwards[0] = xx[0]
    first_order_smooth(xx, _log_decay(tt, tau_s), forwards[1:])
    backwards = np.empty(len(xx))
    backwards[0] = forwards[-1]
    first_order_smooth(forwards[::-1], _log_decay(-tt[::-1], tau_s), backwards[1:])
    return backwards[::-1][head - 1:head - 1 + len(x)].copy()


def compute_signals(t: ArrayLike, rate_dps: ArrayLike, temp_c: ArrayLike,
                    extras: Mapping[str, ArrayLike] | None = None,
                    filters: SignalFilters = SignalFilters(), state: SignalState | None = None,
                    powered_on_at_start: bool = True, run_starts: tuple[tuple[int, bool], ...] = (),
                    refined_start: bool = False) -> Signals:
    """Signals of a log, each computed causally (a sample sees only the past).

    For a log read in chunks, ``state`` is the previous chunk's :meth:`Signals.end_state`
    (None for the first chunk); the chunks' signals then equal the whole log's. ``run_starts``:
    the log is several runs, one after another (:attr:`Signals.run_starts`). ``refined_start``: the
    fit's signals (:attr:`Signals.refined_start`) of a whole log; with the local quadratic temperature rate, on its
    temperature smoothed both ways (:func:`smoothed_both_ways`, over :data:`FIT_SMOOTHING_S`), each run apart.
    """
    if run_starts and (state is not None or run_starts[0][0] != 0):
        raise ValueError('several runs start afresh at row 0: no state to continue from')
    times, temperature = np.asarray(t, dtype=float), np.asarray(temp_c, dtype=float)
    if refined_start and filters.temperature_rate_form == LOCAL_QUADRATIC:   # the fit's, of a whole log
        if state is not None:
            raise ValueError('the fit\'s signals are of a whole log: no state to continue from')
        tau_s = min(filters.temperature_rate_tau_s, FIT_SMOOTHING_S)
        bounds = [first for first, _ in run_starts[1:]]
        temperature = np.concatenate([smoothed_both_ways(a, b, tau_s) for a, b in
                                      zip(np.split(times, bounds), np.split(temperature, bounds))])
    return Signals(t=times, rate=np.asarray(rate_dps, dtype=float), temperature=temperature,
                   extras={k: np.asarray(v, dtype=float) for k, v in (extras or {}).items()}, filters=filters,
                   previous=state, powered_on_at_start=powered_on_at_start, run_starts=run_starts,
                   refined_start=refined_start)


class _Derivative:
    """Per-sample twin of the derivatives of :class:`Signals`."""

    __slots__ = ('tau_s', 'smooth', 'value')

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.smooth: float | None = None
        self.value = 0.0

    def update(self, dt: float, x: float) -> None:
        if self.smooth is None:
            self.smooth = x
            return
        self.smooth += -math.expm1(-max(dt, 0.0) / self.tau_s) * (x - self.smooth)
        self.value = (x - self.smooth) / self.tau_s


class SignalFeed:
    """An extra signal the node receives from outside the gyro (a supply voltage by topic): its latest value.

    :meth:`put` runs on the thread that receives the value, :attr:`latest` is read per frame on
    another: one tuple swapped whole, so a frame never sees a value with another's time. A value
    that is not finite (a BatteryState's NaN, "unknown") is counted, never held: the last finite
    value stays, and ages. Its age is on ``clock`` (s; a monotonic one: the frames' own times follow the
    ROS clock, which may step or be simulated); older than ``max_age_s``, the value is stale.
    """

    __slots__ = ('name', 'max_age_s', 'clock', 'latest', 'received', 'not_finite')

    def __init__(self, name: str, max_age_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not (math.isfinite(max_age_s) and max_age_s > 0.0):
            raise ValueError(f'signal {name}: max_age_s must be a positive number of seconds, got {max_age_s!r}')
        self.name = name
        self.max_age_s = max_age_s
        self.clock = clock
        self.latest: tuple[float, float] | None = None   # (value, clock when received); None until the first
        self.received = 0       # finite values held
        self.not_finite = 0     # values refused as not finite

    def put(self, value: float) -> bool:
        """Hold ``value``, received now; False (and counted) if it is not a finite number."""
        if not math.isfinite(value):
            self.not_finite += 1
            return False
        self.latest = (value, self.clock())
        self.received += 1
        return True

    def problem(self) -> str:
        """Why there is no current value now (none yet, or how old the last is); '' when there is one."""
        latest = self.latest
        if latest is None:
            return f'no {self.name} received yet'
        age = self.clock() - latest[1]
        if age <= self.max_age_s:
            return ''
        return f'the last {self.name} ({latest[0]:g}) is {age:.1f} s old (max_age_s {self.max_age_s:g})'


class SignalTracker:
    """The derived signals of the latest sample, updated one sample at a time.

    ``lags``: the time constants of the lagged temperatures the model needs. The angle is
    not tracked: a heading term needs an absolute heading, which the node does not have.
    ``extras``: the names of signals fed from outside (:class:`SignalFeed`), whose values the
    caller sets in :attr:`extras` (NaN until it does).
    """

    __slots__ = ('t0', 't', 'rate', 'temperature', 'power_on_offset_s', '_temperature_rate', '_rate_change',
                 '_lags', 'extras')

    def __init__(self, filters: SignalFilters = SignalFilters(), lags: tuple[float, ...] = (),
                 powered_on_at_start: bool = False, extras: tuple[str, ...] = ()) -> None:
        self.t0: float | None = None
        self.t = 0.0
        self.rate = 0.0
        self.temperature = 0.0
        # Added to ``time`` for ``time_since_power_on``: infinite when power-on is unknown (a warm gyro).
        self.power_on_offset_s = 0.0 if powered_on_at_start else math.inf
        tau_s = filters.temperature_rate_tau_s
        self._temperature_rate: _Derivative | LocalQuadraticRate = \
            _Derivative(tau_s) if filters.temperature_rate_form == FIRST_ORDER else LocalQuadraticRate(tau_s)
        self._rate_change = _Derivative(filters.rate_change_tau_s)
        self._lags = {tau: _Derivative(tau) for tau in lags}
        self.extras = dict.fromkeys(extras, math.nan)

    def update(self, t: float, rate_dps: float, temp_c: float) -> None:
        """Advance to a new sample at time ``t`` (s)."""
        if self.t0 is None:
            self.t0 = t
            dt = 0.0
        else:
            dt = t - self.t
        self._temperature_rate.update(dt, temp_c)
        self._rate_change.update(dt, rate_dps)
        for lag in self._lags.values():
            lag.update(dt, temp_c)
        self.t, self.rate, self.temperature = t, rate_dps, temp_c

    def for_term(self, term: TermLike) -> float:
        """Current value of the signal ``term`` is evaluated on (its own lag for ``temperature_lag``)."""
        if term.signal == LAGGED_SIGNAL:
            lag = self._lags[term.time_constant_s]
            return lag.smooth if lag.smooth is not None else self.temperature
        return self.value(term.signal)

    @property
    def temperature_rate(self) -> float:
        """Filtered temperature rate of change, degC/s."""
        return self._temperature_rate.value

    @property
    def time(self) -> float:
        """Seconds since the first sample."""
        return self.t - (self.t0 if self.t0 is not None else self.t)

    @property
    def time_since_power_on(self) -> float:
        """Seconds since the gyro's power-on: infinite when it is unknown."""
        return self.time + self.power_on_offset_s

    @property
    def rate_abs(self) -> float:
        """Magnitude of the measured rate, deg/s."""
        return abs(self.rate)

    @property
    def rate_sign(self) -> float:
        """Sign of the measured rate (-1, 0, 1)."""
        return 1.0 if self.rate > 0.0 else -1.0 if self.rate < 0.0 else 0.0

    @property
    def rate_change(self) -> float:
        """Filtered rate of change of the measured rate, deg/s^2."""
        return self._rate_change.value

    def value(self, name: str) -> float:
        """Current value of signal ``name``: a derived one (the attribute of its name) or an extra."""
        signal = SIGNALS.get(name)
        if signal is None and name in self.extras:
            return self.extras[name]
        if signal is None or not signal.per_sample or name == LAGGED_SIGNAL:
            raise KeyError(f'signal {name!r} is not available per sample; the node tracks '
                           f'{", ".join(n for n, s in SIGNALS.items() if s.per_sample and n != LAGGED_SIGNAL)}, '
                           f'{LAGGED_SIGNAL} (with a time constant) and the extra signals it is fed '
                           f'({", ".join(self.extras) or "none"})')
        return cast(float, getattr(self, name))
