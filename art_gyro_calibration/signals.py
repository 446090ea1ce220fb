"""Signals an error term can depend on, computed causally from time, rate and temperature.

The node computes them sample by sample (:class:`SignalTracker`) and the offline tools
over a whole log (:func:`compute_signals`); both run the same recursions, so a term
fitted offline corrects the node's output the same way.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

# Signals derived from (t, rate, temperature); any other name is an extra log column.
DERIVED_SIGNALS = ('temperature', 'temperature_rate', 'time', 'rate', 'rate_abs',
                   'rate_sign', 'rate_change', 'angle')

# A temperature count is 0.05 degC and a chamber ramps at about 1 degC/min: the
# derivative needs minutes of smoothing to rise above the quantisation.
DEFAULT_TEMPERATURE_RATE_TAU_S = 120.0
# Angular acceleration of a rate table or robot settles within a second.
DEFAULT_RATE_CHANGE_TAU_S = 0.5


@dataclass(frozen=True)
class SignalFilters:
    """Time constants of the causal derivative filters (first order, in seconds)."""

    temperature_rate_tau_s: float = DEFAULT_TEMPERATURE_RATE_TAU_S
    rate_change_tau_s: float = DEFAULT_RATE_CHANGE_TAU_S

    def __post_init__(self) -> None:
        for name in ('temperature_rate_tau_s', 'rate_change_tau_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'filters.{name} must be a positive number of seconds, got {value!r}')


@dataclass(frozen=True)
class Signals:
    """Every signal of a log, one array each, aligned with its samples.

    The derived signals are computed on first use, so a model without extended
    terms costs no filtering.
    """

    t: NDArray[np.float64]
    rate: NDArray[np.float64]
    temperature: NDArray[np.float64]
    extras: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)
    filters: SignalFilters = field(default_factory=SignalFilters)

    @cached_property
    def temperature_rate(self) -> NDArray[np.float64]:
        """Filtered temperature rate of change, degC/s."""
        return _derivative(self.t, self.temperature, self.filters.temperature_rate_tau_s)

    @cached_property
    def rate_change(self) -> NDArray[np.float64]:
        """Filtered rate of change of the measured rate, deg/s^2."""
        return _derivative(self.t, self.rate, self.filters.rate_change_tau_s)

    @cached_property
    def angle(self) -> NDArray[np.float64]:
        """Angle turned in degrees, trapezoidal integral of the measured rate."""
        out = np.zeros(len(self.rate))
        if len(self.rate) > 1:
            out[1:] = np.cumsum(0.5 * (self.rate[1:] + self.rate[:-1]) * np.diff(self.t))
        return out

    @property
    def time(self) -> NDArray[np.float64]:
        """Seconds since the first sample (power-on, as far as the log knows)."""
        return self.t - self.t[0]

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
        if name in DERIVED_SIGNALS:
            return np.asarray(getattr(self, name), dtype=float)
        try:
            return self.extras[name]
        except KeyError:
            raise KeyError(f'signal {name!r} is neither derived ({", ".join(DERIVED_SIGNALS)}) '
                           f'nor a column of the log ({", ".join(self.extras) or "none"})') from None

    def __len__(self) -> int:
        return len(self.t)


def _derivative(t: NDArray[np.float64], x: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """Causal first-order derivative ``(x - ema(x)) / tau``, the batch twin of ``_Derivative``."""
    out = np.zeros(len(x))
    if len(x) > 1:
        decay = -np.maximum(np.diff(t), 0.0) / tau_s   # log of each step's decay factor
        out[1:] = (x[1:] - first_order_smooth(x, decay)) / tau_s
    return out


# Span of log-decay one chunk of :func:`first_order_smooth` covers: exp(500) stays far from overflow.
_CHUNK_LOG_DECAY = 500.0
_CHUNK_ROWS = 1 << 16


def first_order_smooth(x: NDArray[np.float64], log_decay: NDArray[np.float64]) -> NDArray[np.float64]:
    """``s[i] = s[i-1] + (1 - exp(log_decay[i-1])) * (x[i] - s[i-1])`` from ``s[0] = x[0]``, for i >= 1.

    The recursion in closed form, ``s_i = D_i (s_0 + sum_j a_j x_j / D_j)`` with ``D`` the
    cumulative decay, vectorised over chunks short enough that ``1 / D`` stays finite. Each
    rounding error decays with the filter, so the result matches the per-sample loop to
    a few ulps of ``x / a``. Runs with numpy alone (the node's runtime has no scipy).
    """
    n = len(log_decay)
    # A step decaying by more than exp(-500) forgets the past: its gain is 1.0 either way.
    log_decay = np.maximum(log_decay, -_CHUNK_LOG_DECAY)
    gain = -np.expm1(log_decay)
    out = np.empty(n)
    level = float(x[0])
    start = 0
    while start < n:
        span = np.cumsum(log_decay[start:start + _CHUNK_ROWS])
        stop = start + max(1, int(np.searchsorted(-span, _CHUNK_LOG_DECAY, side='right')))
        cumulative = span[:stop - start]
        weights = gain[start:stop] * x[start + 1:stop + 1] * np.exp(-cumulative)
        out[start:stop] = np.exp(cumulative) * (level + np.cumsum(weights))
        level = float(out[stop - 1])
        start = stop
    return out


def compute_signals(t: ArrayLike, rate_dps: ArrayLike, temp_c: ArrayLike,
                    extras: Mapping[str, ArrayLike] | None = None,
                    filters: SignalFilters = SignalFilters()) -> Signals:
    """Signals of a log, each computed causally (a sample sees only the past)."""
    return Signals(t=np.asarray(t, dtype=float), rate=np.asarray(rate_dps, dtype=float),
                   temperature=np.asarray(temp_c, dtype=float),
                   extras={k: np.asarray(v, dtype=float) for k, v in (extras or {}).items()}, filters=filters)


class _Derivative:
    """Per-sample twin of ``_derivative``."""

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


class SignalTracker:
    """The derived signals of the latest sample, updated one sample at a time."""

    __slots__ = ('t0', 't', 'rate', 'temperature', 'angle', '_temperature_rate', '_rate_change')

    def __init__(self, filters: SignalFilters = SignalFilters()) -> None:
        self.t0: float | None = None
        self.t = 0.0
        self.rate = 0.0
        self.temperature = 0.0
        self.angle = 0.0
        self._temperature_rate = _Derivative(filters.temperature_rate_tau_s)
        self._rate_change = _Derivative(filters.rate_change_tau_s)

    def update(self, t: float, rate_dps: float, temp_c: float) -> None:
        """Advance to a new sample at time ``t`` (s)."""
        if self.t0 is None:
            self.t0 = t
            dt = 0.0
        else:
            dt = t - self.t
            self.angle += 0.5 * (rate_dps + self.rate) * dt
        self._temperature_rate.update(dt, temp_c)
        self._rate_change.update(dt, rate_dps)
        self.t, self.rate, self.temperature = t, rate_dps, temp_c

    def value(self, name: str) -> float:
        """Current value of derived signal ``name``."""
        if name == 'temperature':
            return self.temperature
        if name == 'temperature_rate':
            return self._temperature_rate.value
        if name == 'time':
            return self.t - (self.t0 if self.t0 is not None else self.t)
        if name == 'rate':
            return self.rate
        if name == 'rate_abs':
            return abs(self.rate)
        if name == 'rate_sign':
            return 1.0 if self.rate > 0.0 else -1.0 if self.rate < 0.0 else 0.0
        if name == 'rate_change':
            return self._rate_change.value
        if name == 'angle':
            return self.angle
        raise KeyError(f'signal {name!r} is not available per sample; derived signals are '
                       f'{", ".join(DERIVED_SIGNALS)}')
