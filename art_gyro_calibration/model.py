"""The ART error model: the report's polynomial in rate and temperature, plus extended terms.

The error is what the gyro reads too much, in deg/s; compensation subtracts it
(``CompRate = GyroRate - StaticBiasDrift - comp + CalcStaticBiasDrift``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.signals import LAGGED_SIGNAL, SIGNALS, Signals, SignalTracker
from art_gyro_calibration.terms import Term


class ArtPolynomial:
    """``CompFunction`` of the report, for any ROWS x COLUMNS.

    ``coefficients[j][i]`` multiplies ``temp**(rows-1-j) * rate**(columns-1-i)``:
    rows are powers of temperature and columns powers of rate, highest first.
    """

    def __init__(self, coefficients: ArrayLike) -> None:
        c = np.array(coefficients, dtype=float, ndmin=2)
        if c.ndim != 2 or c.size == 0:
            raise ValueError(f'polynomial coefficients must be a non-empty matrix, got shape {c.shape}')
        if not np.all(np.isfinite(c)):
            raise ValueError('polynomial coefficients must be finite numbers')
        c.setflags(write=False)
        self.coefficients: NDArray[np.float64] = c
        # Per rate power, the temperature coefficients as plain floats: the per-sample path
        # then runs on Python floats with no array allocation.
        self._columns = tuple(tuple(float(x) for x in c[:, i]) for i in range(c.shape[1]))

    @property
    def rows(self) -> int:
        """Number of temperature powers."""
        return int(self.coefficients.shape[0])

    @property
    def columns(self) -> int:
        """Number of rate powers."""
        return int(self.coefficients.shape[1])

    def error(self, rate_dps: ArrayLike, temp_c: ArrayLike) -> NDArray[np.float64]:
        """Return comp(rate, temp) in deg/s for arrays (Horner in temperature, then in rate)."""
        rate = np.asarray(rate_dps, dtype=float)
        temp = np.asarray(temp_c, dtype=float)
        comp = np.zeros(np.broadcast_shapes(rate.shape, temp.shape))
        for column in self._columns:
            per_temp = np.full(temp.shape, column[0])
            for c in column[1:]:
                per_temp *= temp
                per_temp += c
            comp *= rate
            comp += per_temp
        return comp

    def error_one(self, rate_dps: float, temp_c: float) -> float:
        """Return comp(rate, temp) for one sample, on floats."""
        comp = 0.0
        for column in self._columns:
            per_temp = 0.0
            for c in column:
                per_temp = per_temp * temp_c + c
            comp = comp * rate_dps + per_temp
        return comp

    def __repr__(self) -> str:
        return f'ArtPolynomial(rows={self.rows}, columns={self.columns})'


def _clamped(temp: NDArray[np.float64], span: tuple[float, float] | None) -> NDArray[np.float64]:
    """``temp`` held within ``span`` (as it is without one)."""
    return temp if span is None else np.clip(temp, *span)


def _clamped_one(temp: float, span: tuple[float, float] | None) -> float:
    """:func:`_clamped` for one sample, on floats."""
    if span is None:
        return temp
    low, high = span
    return low if temp < low else high if temp > high else temp


@dataclass(frozen=True)
class Continuation:
    """Beyond a calibrated range, another polynomial's temperature dependence (the baseline's), continued from the edge.

    A refit fitted over a log's few degrees is held at the log's edge; the gyro's previous
    calibration (the report's polynomial, fitted on a rate table over the whole chamber
    range) knows how the error moves beyond it. Outside the range the error is the refit's
    at the edge plus how much ``polynomial`` moves from the edge to the temperature:
    ``comp(rate, edge) + B(rate, T) - B(rate, edge)``, with ``B`` itself held at the edge of
    ``temperature_range_c`` when it has one. Inside the range nothing changes.
    """

    polynomial: ArtPolynomial
    temperature_range_c: tuple[float, float] | None = None
    source: str = ''

    def step(self, rate: NDArray[np.float64], temp: NDArray[np.float64],
             edge: NDArray[np.float64]) -> NDArray[np.float64]:
        """``B(rate, temp) - B(rate, edge)`` for arrays (0 where ``temp`` is ``edge``)."""
        span = self.temperature_range_c
        return self.polynomial.error(rate, _clamped(temp, span)) - self.polynomial.error(rate, _clamped(edge, span))

    def step_one(self, rate: float, temp: float, edge: float) -> float:
        """:meth:`step` for one sample."""
        span = self.temperature_range_c
        return self.polynomial.error_one(rate, _clamped_one(temp, span)) - \
            self.polynomial.error_one(rate, _clamped_one(edge, span))


# Signals that are temperatures: clamped to the calibrated range with the polynomial's.
_TEMPERATURES = tuple(name for name, signal in SIGNALS.items() if signal.temperature)
# The terms a static bias taken while the temperature-rate filter still starts up gets wrong.
_REFINABLE = 'temperature_rate'


@dataclass(frozen=True)
class ErrorModel:
    """The report's polynomial plus the extended terms found beyond it.

    With ``temperature_range_c`` the temperatures are clamped to it, as PX4 and ArduPilot
    clamp their thermal calibrations: outside the calibrated range a polynomial
    extrapolates wildly, its value at the edge is the better guess. Without it (the
    report's calibrations, whose range the report does not give) the model is evaluated at
    every temperature, exactly as the report's program does. With ``continuation`` the
    polynomial is held at the edge and continued beyond it (:class:`Continuation`).
    """

    polynomial: ArtPolynomial
    terms: tuple[Term, ...] = ()
    temperature_range_c: tuple[float, float] | None = None
    continuation: Continuation | None = None

    @property
    def lags(self) -> tuple[float, ...]:
        """Time constants of the lagged temperatures the terms need."""
        return tuple(t.time_constant_s for t in self.terms if t.signal == LAGGED_SIGNAL)

    @property
    def refinable(self) -> tuple[Term, ...]:
        """The terms on the temperature rate, which a static bias refinement re-evaluates."""
        return tuple(t for t in self.terms if t.signal == _REFINABLE)

    def term_error(self, term: Term, signals: Signals) -> NDArray[np.float64]:
        """One term's modelled error over a log."""
        x = signals.for_term(term)
        return term.evaluate(_clamped(x, self.temperature_range_c) if term.signal in _TEMPERATURES else x, signals.rate)

    def polynomial_error(self, rate_dps: ArrayLike, temp_c: ArrayLike) -> NDArray[np.float64]:
        """The polynomial's part of the error, as the model applies it: clamped, and continued beyond the edge."""
        rate, temp = np.asarray(rate_dps, dtype=float), np.asarray(temp_c, dtype=float)
        edge = _clamped(temp, self.temperature_range_c)
        comp = self.polynomial.error(rate, edge)
        if self.continuation is not None:
            comp += self.continuation.step(rate, temp, edge)
        return comp

    def error(self, signals: Signals) -> NDArray[np.float64]:
        """Modelled error in deg/s of every sample of a log."""
        comp = self.polynomial_error(signals.rate, signals.temperature)
        for term in self.terms:
            comp += self.term_error(term, signals)
        return comp

    def error_one(self, tracker: SignalTracker) -> float:
        """Modelled error of the sample ``tracker`` was last updated with."""
        edge = _clamped_one(tracker.temperature, self.temperature_range_c)
        comp = self.polynomial.error_one(tracker.rate, edge)
        if self.continuation is not None and edge != tracker.temperature:
            comp += self.continuation.step_one(tracker.rate, tracker.temperature, edge)
        span = self.temperature_range_c
        for term in self.terms:
            x = tracker.for_term(term)
            comp += term.evaluate_one(_clamped_one(x, span) if term.signal in _TEMPERATURES else x, tracker.rate)
        return comp

    def refinable_error_one(self, tracker: SignalTracker) -> float:
        """The part of :meth:`error_one` the temperature-rate terms make."""
        return sum(t.evaluate_one(tracker.for_term(t), tracker.rate) for t in self.refinable)
