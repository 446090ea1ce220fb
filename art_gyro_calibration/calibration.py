"""Calibration files: one ROS 2 parameters file per gyro serial number.

A file is ``/**: ros__parameters: {...}`` so that the node takes it with
``--params-file``; the offline tools read and write the same files. Parameters
(dotted names, as the node sees them):

- ``serial_number`` (str), ``rate_scale_factor`` (deg/s per count),
  ``temp_scale_factor`` (degC per count),
- ``polynomial.rows``, ``polynomial.columns``, ``polynomial.coefficients``
  (flat, row-major, exactly the report's matrix),
- optional ``temperature_range_c`` ([min, max], the calibrated range: the model clamps the temperature
  to it; ``calibrate fit`` writes the logged envelope), or optional ``temperature_warn_range_c`` (the
  range a calibration is expected to hold, used only to warn and count outside it: the report's
  calibrations, whose range the report does not print and whose polynomial applies at every
  temperature exactly as the report's program applies it); not both,
- optional, with ``temperature_range_c``: ``beyond_range.rows``, ``.columns``, ``.coefficients`` (a
  polynomial as ``polynomial.*``), ``.temperature_range_c`` and ``.source``: beyond the calibrated
  range the polynomial is held at the edge and continued by this one's temperature dependence
  (``calibrate fit`` writes the baseline's; see :class:`~art_gyro_calibration.model.Continuation`),
- optional ``filters.temperature_rate_tau_s``, ``filters.rate_change_tau_s`` and
  ``filters.temperature_rate_form`` (``local_quadratic``, which ``calibrate fit`` writes, or ``first_order``:
  a file that names no form was fitted with it, at 120 s unless it names a time constant;
  see :mod:`art_gyro_calibration.temperature_rate`),
- optional extended terms: ``extended.signals`` (list, one term per signal) and
  for each ``extended.<signal>.form``, ``.coefficients``, ``.powers`` and optional
  ``.rate_powers`` (power form), ``.time_constant_s`` (exp_decay form, and the lag of
  ``temperature_lag``); see :mod:`art_gyro_calibration.terms`. Terms the node would apply
  wrongly from some start are refused: a heading term, a warm-up counted from the run's start.
  A term on a signal the gyro does not give (a log column such as a supply voltage) runs on the
  node only when a topic feeds it (:func:`check_fed`).

Any other key is refused (a misspelt ``extnded:`` would silently drop the fitted terms),
and so is a model that overflows anywhere in the envelope it is used in (:func:`check_envelope`).
Files are read with :func:`read_yaml`: bounded in size, no YAML aliases.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import stat
import sys
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from art_gyro_calibration.frame import INT16_MIN
from art_gyro_calibration.model import ArtPolynomial, Continuation, ErrorModel
from art_gyro_calibration.signals import (DERIVED_SIGNALS, FIRST_ORDER_TAU_S, LAGGED_SIGNAL, POWER_ON_SIGNAL, SIGNALS,
                                          Envelope, SignalFilters)
from art_gyro_calibration.temperature_rate import FIRST_ORDER
from art_gyro_calibration.terms import FORMS, Term

PACKAGE = 'art_gyro_calibration'
TEMP_SCALE_FACTOR = 0.05  # degC per count, the same for every RD2100 (report, section 1)
# deg/s per count of most RD2100s (report, section 1): what ``calibrate fit`` writes when told no better.
DEFAULT_RATE_SCALE_FACTOR = 0.00305
SERIAL_PATTERN = re.compile(r'^[A-Za-z0-9_-]+$')
SIGNAL_PATTERN = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')
# A calibration or params file is a few kB: anything far larger is not one (and is not read whole).
MAX_YAML_BYTES = 1 << 20
# Nor is it nested deeper than a few levels (node entry, ros__parameters, extended.<signal>.<field>, a list).
MAX_YAML_DEPTH = 32
# An error quoting a file (a YAML error echoes the offending line) is cut to this many characters.
MAX_MESSAGE_CHARS = 400
# The rate is a signed 16-bit count: full scale is this many counts times rate_scale_factor.
FULL_SCALE_COUNTS = -INT16_MIN
# How long a node may run: the horizon of the time signal (and of the angle turned) in the envelope check.
TIME_HORIZON_S = 366 * 86400.0
# A frame claiming a temperature outside what any electronics survives is corrupt (its 8-bit
# checksum passed by luck) or the temperature field is not where this package assumes it: at
# +-1600 degC the polynomial alone would add 70-80 deg/s, so such a frame is dropped and counted
# (compensation.plausible). A calibration without a clamp is checked over this range.
PLAUSIBLE_TEMPERATURE_C = (-60.0, 130.0)
# The widest range of the units this package reads (deg/s): KVH DSP-1750/1760, 1725/1750/1775 measure +-490;
# an RD2100's range is its counts' full scale (about +-100). A rate beyond a unit's range is no measurement.
MAX_UNIT_RANGE_DPS = 490.0
# A signal from outside the gyro may stray beyond the range its term was fitted over by this share of that range on
# either side (an extrapolation a linear term bears) before its value is taken as wrong (Calibration.signal_limits).
SIGNAL_RANGE_MARGIN = 0.5
# Scale factors a calibration may hold: an RD2100's full scale between 1 deg/s and 1 count per deg/s (kvh_fog
# units send deg/s, factor 1.0); temperatures to between 0.001 and 1 degC per count (RD2100 0.05, kvh_fog 1.0).
RATE_SCALE_FACTOR_RANGE = (1.0 / FULL_SCALE_COUNTS, 1.0)
TEMP_SCALE_FACTOR_RANGE = (0.001, 1.0)
# Temperatures x rates at which the polynomial's correction is checked against the unit's range at load.
ENVELOPE_GRID = (41, 201)


def unit_range_dps(rate_scale_factor: float) -> float:
    """The range (deg/s) of a unit read at ``rate_scale_factor``: its counts' full scale, at most MAX_UNIT_RANGE_DPS."""
    return min(FULL_SCALE_COUNTS * rate_scale_factor, MAX_UNIT_RANGE_DPS)


class CalibrationError(ValueError):
    """A calibration that cannot be used, with where and why."""


@dataclass(frozen=True)
class Calibration:
    """Everything needed to turn raw counts into a compensated rate."""

    serial_number: str
    rate_scale_factor: float
    polynomial: ArtPolynomial
    temperature_range_c: tuple[float, float] | None   # the calibrated range, clamped to; None: no clamp
    temp_scale_factor: float = TEMP_SCALE_FACTOR
    terms: tuple[Term, ...] = ()
    filters: SignalFilters = field(default_factory=SignalFilters)
    temperature_warn_range_c: tuple[float, float] | None = None   # warned and counted outside, never clamped
    # Per signal from outside the gyro (a supply voltage): the range its term was fitted over (none: not known).
    signal_ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    continuation: Continuation | None = None   # beyond temperature_range_c (none: held at its edge)

    def signal_limits(self, signal: str) -> tuple[float, float]:
        """Where a value of ``signal`` is taken as the fit's: its fitted range widened by SIGNAL_RANGE_MARGIN.

        Beyond it the value is no longer the calibration's (24000 for 24 V: millivolts sent as volts): the node
        and ``calibrate apply`` apply the term at the limit and flag the rate. No range known: unlimited.
        """
        span = self.signal_ranges.get(signal)
        if span is None:
            return -math.inf, math.inf
        margin = SIGNAL_RANGE_MARGIN * (span[1] - span[0])
        return span[0] - margin, span[1] + margin

    def signal_problem(self, signal: str, value: float) -> str:
        """Why ``value`` of ``signal`` is not taken as it is (beyond :meth:`signal_limits`), or ''."""
        low, high = self.signal_limits(signal)
        if low <= value <= high:
            return ''
        fitted_low, fitted_high = self.signal_ranges[signal]
        return (f'{signal} {value:g} is beyond {low:g}..{high:g} (the range it was fitted over, '
                f'{fitted_low:g}..{fitted_high:g}, and half that each side): applied as {min(max(value, low), high):g}')

    @property
    def expected_range_c(self) -> tuple[float, float] | None:
        """Where the calibration is expected to hold: outside it the node warns and counts (None: nowhere known)."""
        return self.temperature_range_c if self.temperature_range_c is not None else self.temperature_warn_range_c

    @property
    def envelope_range_c(self) -> tuple[float, float]:
        """The temperatures the model is evaluated at: the clamp's range, else every plausible temperature."""
        return self.temperature_range_c if self.temperature_range_c is not None else PLAUSIBLE_TEMPERATURE_C

    @property
    def rate_range_dps(self) -> float:
        """The unit's range (deg/s): its counts' full scale, at most MAX_UNIT_RANGE_DPS; beyond it no rate is real."""
        return unit_range_dps(self.rate_scale_factor)

    @property
    def model(self) -> ErrorModel:
        """The error model: polynomial and extended terms."""
        return ErrorModel(self.polynomial, self.terms, self.temperature_range_c, self.continuation)

    @property
    def beyond_range(self) -> str:
        """What the model does beyond its calibrated range, in words."""
        if self.continuation is None:
            return 'compensated at its edge'
        source = f' ({self.continuation.source})' if self.continuation.source else ''
        return f'held at its edge and continued by the temperature dependence of the baseline{source}'

    def to_parameters(self) -> dict[str, Any]:
        """Flat dotted parameters, the inverse of :func:`from_parameters`."""
        params: dict[str, Any] = {
            'serial_number': self.serial_number,
            'rate_scale_factor': self.rate_scale_factor,
            'temp_scale_factor': self.temp_scale_factor,
            'polynomial.rows': self.polynomial.rows,
            'polynomial.columns': self.polynomial.columns,
            'polynomial.coefficients': [float(c) for c in self.polynomial.coefficients.ravel()],
        }
        for key, span in (('temperature_range_c', self.temperature_range_c),
                          ('temperature_warn_range_c', self.temperature_warn_range_c)):
            if span is not None:   # absent: no range known (the report prints none)
                params[key] = [float(v) for v in span]
        if self.continuation is not None:
            beyond = self.continuation
            params['beyond_range.rows'] = beyond.polynomial.rows
            params['beyond_range.columns'] = beyond.polynomial.columns
            params['beyond_range.coefficients'] = [float(c) for c in beyond.polynomial.coefficients.ravel()]
            if beyond.temperature_range_c is not None:
                params['beyond_range.temperature_range_c'] = [float(v) for v in beyond.temperature_range_c]
            params['beyond_range.source'] = beyond.source
        params['filters.temperature_rate_tau_s'] = self.filters.temperature_rate_tau_s
        params['filters.rate_change_tau_s'] = self.filters.rate_change_tau_s
        params['filters.temperature_rate_form'] = self.filters.temperature_rate_form
        if self.terms:
            params['extended.signals'] = [t.signal for t in self.terms]
        for t in self.terms:
            prefix = f'extended.{t.signal}.'
            params[prefix + 'form'] = t.form
            params[prefix + 'coefficients'] = [float(c) for c in t.coefficients]
            if t.form == 'power':
                params[prefix + 'powers'] = list(t.powers)
            if t.rate_powers != (0,):
                params[prefix + 'rate_powers'] = list(t.rate_powers)
            if t.form == 'exp_decay' or t.signal == LAGGED_SIGNAL:
                params[prefix + 'time_constant_s'] = t.time_constant_s
            if t.signal in self.signal_ranges:
                params[prefix + 'fitted_range'] = [float(v) for v in self.signal_ranges[t.signal]]
        return params


def _key_sets() -> tuple[frozenset[str], frozenset[str]]:
    """Keys :meth:`Calibration.to_parameters` writes: (the fixed ones, the fields of every extended term).

    Taken from a calibration with one term of every form, so a field added to ``to_parameters``
    is known here without a second list to keep in step.
    """
    # Every optional field set: a power term with rate powers on the lagged signal (which carries a time constant).
    shapes = {'power': ((1,), (0, 1)), 'exp_decay': ((), (0,)), 'harmonic': ((), (0,))}
    terms = tuple(Term(signal=LAGGED_SIGNAL if form == 'power' else f'signal_{form}', form=form,
                       coefficients=(0.0,) * Term.width(form, *shapes[form]), powers=shapes[form][0],
                       rate_powers=shapes[form][1], time_constant_s=1.0) for form in FORMS)
    sample = Calibration('SAMPLE', 1.0, ArtPolynomial([[0.0]]), (0.0, 1.0), terms=terms,
                         temperature_warn_range_c=(0.0, 1.0), signal_ranges={terms[0].signal: (0.0, 1.0)},
                         continuation=Continuation(ArtPolynomial([[0.0]]), (0.0, 1.0)))
    fixed, fields = set(), set()
    for key in sample.to_parameters():
        parts = key.split('.', 2)
        if parts[0] == 'extended' and len(parts) == 3:
            fields.add(parts[2])
        else:
            fixed.add(key)
    return frozenset(fixed), frozenset(fields)


CALIBRATION_KEYS, TERM_FIELDS = _key_sets()


def is_calibration_key(name: str) -> bool:
    """Whether ``name`` is a calibration parameter (for any extended signal name)."""
    parts = name.split('.', 2)
    if len(parts) == 3 and parts[0] == 'extended':
        return bool(SIGNAL_PATTERN.match(parts[1])) and parts[2] in TERM_FIELDS
    return name in CALIBRATION_KEYS


def closest(name: str, candidates: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` with the candidate closest to a misspelt ``name``, or ''."""
    match = difflib.get_close_matches(name, sorted(candidates), n=1, cutoff=0.6)
    return f' (did you mean {match[0]!r}?)' if match else ''


def check_known_keys(params: Mapping[str, Any], where: str) -> None:
    """Refuse any key that is not a calibration parameter, naming the closest valid one."""
    signals = params.get('extended.signals', [])
    signals = [s for s in signals if isinstance(s, str)] if isinstance(signals, (list, tuple)) else []
    valid = set(CALIBRATION_KEYS) | {f'extended.{s}.{f}' for s in signals for f in TERM_FIELDS}
    for key in params:
        if key not in valid:
            raise CalibrationError(f'{where}: unknown key {key!r}{closest(key, valid)}')


def _get(params: Mapping[str, Any], key: str, where: str) -> Any:
    if key in params:
        return params[key]
    raise CalibrationError(f'{where}: missing parameter {key!r}')


def _number(value: Any, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CalibrationError(f'{where}: {key} must be a finite number, got {value!r}')
    return float(value)


def _integer(value: Any, key: str, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise CalibrationError(f'{where}: {key} must be a whole number >= 1, got {value!r}')
    return value


def _list(value: Any, key: str, where: str, of: str) -> list[Any]:
    # A list in YAML, a list or an array.array as a ROS parameter; a string or scalar is refused here,
    # not by a TypeError further on.
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, '__iter__'):
        raise CalibrationError(f'{where}: {key} must be a list of {of}, got {value!r}')
    return list(value)


def _numbers(value: Any, key: str, where: str) -> list[float]:
    return [_number(v, f'{key}[{i}]', where) for i, v in enumerate(_list(value, key, where, 'numbers'))]


def from_parameters(params: Mapping[str, Any], where: str) -> Calibration:
    """Build and check a calibration from flat dotted parameters; ``where`` names their source.

    Unknown keys and a model that is not finite over its envelope are refused.
    """
    check_known_keys(params, where)
    serial = _get(params, 'serial_number', where)
    if not isinstance(serial, str) or not SERIAL_PATTERN.match(serial):
        raise CalibrationError(f'{where}: serial_number must be letters, digits, _ or -, got {serial!r}')
    rate_scale = _number(_get(params, 'rate_scale_factor', where), 'rate_scale_factor', where)
    temp_scale = _number(_get(params, 'temp_scale_factor', where), 'temp_scale_factor', where)
    if rate_scale <= 0 or temp_scale <= 0:
        raise CalibrationError(f'{where}: scale factors must be positive, got rate {rate_scale}, '
                               f'temperature {temp_scale}')
    for key, value, (low, high), what in (
            ('rate_scale_factor', rate_scale, RATE_SCALE_FACTOR_RANGE,
             f'deg/s per count: a full scale of {FULL_SCALE_COUNTS * rate_scale:g} deg/s'),
            ('temp_scale_factor', temp_scale, TEMP_SCALE_FACTOR_RANGE, 'degC per count')):
        if not low <= value <= high:
            raise CalibrationError(f'{where}: {key} must be in {low:.6g}..{high:g}, got {value:g} ({what}): '
                                   'no gyro this package reads')
    polynomial = _polynomial(params, 'polynomial', where)
    temp_range = _range(params, 'temperature_range_c', where)
    warn_range = _range(params, 'temperature_warn_range_c', where)
    if temp_range is not None and warn_range is not None:
        raise CalibrationError(f'{where}: temperature_range_c (calibrated: clamped to) and temperature_warn_range_c '
                               '(expected: warned outside, never clamped) are both given: keep one')
    try:
        # A file that names no form was written before the local quadratic fit: its first-order filter, exactly.
        form = params.get('filters.temperature_rate_form', FIRST_ORDER)
        filters = SignalFilters(
            _number(params.get('filters.temperature_rate_tau_s',
                               FIRST_ORDER_TAU_S if form == FIRST_ORDER else SignalFilters.temperature_rate_tau_s),
                    'filters.temperature_rate_tau_s', where),
            _number(params.get('filters.rate_change_tau_s', SignalFilters.rate_change_tau_s),
                    'filters.rate_change_tau_s', where),
            form)
    except ValueError as e:
        raise CalibrationError(f'{where}: {e}') from None
    terms = _terms(params, where)
    calibration = Calibration(
        serial_number=serial, rate_scale_factor=rate_scale, temp_scale_factor=temp_scale, polynomial=polynomial,
        temperature_range_c=temp_range, temperature_warn_range_c=warn_range,
        terms=terms, filters=filters, signal_ranges=_signal_ranges(params, terms, where),
        continuation=_continuation(params, temp_range, where))
    check_envelope(calibration, where)
    return calibration


def _polynomial(params: Mapping[str, Any], prefix: str, where: str) -> ArtPolynomial:
    """``<prefix>.rows``, ``.columns`` and ``.coefficients`` (row-major) as a polynomial."""
    rows = _integer(_get(params, f'{prefix}.rows', where), f'{prefix}.rows', where)
    columns = _integer(_get(params, f'{prefix}.columns', where), f'{prefix}.columns', where)
    key = f'{prefix}.coefficients'
    coefficients = _numbers(_get(params, key, where), key, where)
    if len(coefficients) != rows * columns:
        raise CalibrationError(f'{where}: {key} has {len(coefficients)} numbers, '
                               f'rows x columns = {rows} x {columns} needs {rows * columns}')
    return ArtPolynomial(np.reshape(coefficients, (rows, columns)))


def _continuation(params: Mapping[str, Any], temp_range: tuple[float, float] | None,
                  where: str) -> Continuation | None:
    """The ``beyond_range.*`` polynomial, which only a calibrated ``temperature_range_c`` has a beyond for."""
    keys = [key for key in params if key.startswith('beyond_range.')]
    if not keys:
        return None
    if temp_range is None:
        raise CalibrationError(f'{where}: {keys[0]} continues the polynomial beyond temperature_range_c, which is '
                               'not given: give the calibrated range or drop beyond_range')
    source = params.get('beyond_range.source', '')
    if not isinstance(source, str):
        raise CalibrationError(f'{where}: beyond_range.source must be a string, got {source!r}')
    return Continuation(_polynomial(params, 'beyond_range', where),
                        _range(params, 'beyond_range.temperature_range_c', where), source)


def _range(params: Mapping[str, Any], key: str, where: str) -> tuple[float, float] | None:
    """An optional [min, max] (degC, or a signal's unit): absent is None (no range known), anything else checked."""
    if key not in params:
        return None
    span = _numbers(params[key], key, where)
    if len(span) != 2 or not span[0] < span[1]:
        raise CalibrationError(f'{where}: {key} must be [min, max] with min < max, got {span}')
    return span[0], span[1]


def _signal_ranges(params: Mapping[str, Any], terms: Sequence[Term], where: str) -> dict[str, tuple[float, float]]:
    """The ``extended.<signal>.fitted_range`` given, for signals from outside the gyro only (optional: older files)."""
    ranges = {}
    for term in terms:
        key = f'extended.{term.signal}.fitted_range'
        span = _range(params, key, where)
        if span is None:
            continue
        if term.signal in SIGNALS:
            raise CalibrationError(f'{where}: {key}: {term.signal} is derived from the gyro\'s frames, whose range '
                                   'the calibration knows: a fitted range is for a signal from outside the gyro')
        ranges[term.signal] = span
    return ranges


def signal_envelope(calibration: Calibration, signal: str) -> tuple[float, float] | None:
    """Range of a derived signal over the calibration's envelope; None for a signal with no known range.

    The envelope: the temperature in :attr:`Calibration.envelope_range_c`, the rate within +-full scale, a run of
    up to TIME_HORIZON_S; each signal's range over it is the registry's (:data:`signals.SIGNALS`).
    A log column (a supply voltage) has no known range.
    """
    derived = SIGNALS.get(signal)
    if derived is None:
        return None
    return derived.range(Envelope(calibration.envelope_range_c, FULL_SCALE_COUNTS * calibration.rate_scale_factor,
                                  calibration.filters, TIME_HORIZON_S))


def check_envelope(calibration: Calibration, where: str) -> None:
    """Refuse a model that overflows or is not finite anywhere in its envelope (see :func:`signal_envelope`).

    Each part is bounded by the sum of its monomials' magnitudes at the envelope's extremes,
    so a finite bound means a finite value everywhere inside.
    """
    low_c, high_c = calibration.envelope_range_c
    rate_max = FULL_SCALE_COUNTS * calibration.rate_scale_factor
    polynomials = [('polynomial', calibration.polynomial, calibration.envelope_range_c)]
    if calibration.continuation is not None:
        beyond = calibration.continuation
        polynomials.append(('beyond_range', beyond.polynomial,
                            beyond.temperature_range_c or PLAUSIBLE_TEMPERATURE_C))
    for key, poly, (low, high) in polynomials:
        temp_max = max(abs(low), abs(high))
        with np.errstate(over='ignore', invalid='ignore'):
            temp_powers = temp_max ** np.arange(poly.rows - 1, -1, -1, dtype=float)
            rate_powers = rate_max ** np.arange(poly.columns - 1, -1, -1, dtype=float)
            bound = float(np.sum(np.abs(poly.coefficients) * np.outer(temp_powers, rate_powers)))
        if not math.isfinite(bound):
            raise CalibrationError(f'{where}: {key}.coefficients: the polynomial overflows within the envelope '
                                   f'({low:g}..{high:g} degC, +-{rate_max:g} deg/s full scale)')
        _check_correction(poly, key, (low, high), calibration.rate_range_dps, where)
    for term in calibration.terms:
        envelope = signal_envelope(calibration, term.signal)
        if envelope is None:
            continue   # a log column (supply voltage): no known range
        low, high = envelope
        c = np.abs(np.asarray(term.coefficients, dtype=float))
        with np.errstate(over='ignore', invalid='ignore'):
            if term.form == 'power':   # c[j * len(q) + k] multiplies x**p[j] * rate**q[k]
                monomials = np.outer(max(abs(low), abs(high)) ** np.asarray(term.powers, dtype=float),
                                     rate_max ** np.asarray(term.rate_powers, dtype=float))
                bound = float(np.sum(c * monomials.ravel()))
            elif term.form == 'exp_decay':
                bound = float(c[0] * np.exp(-low / term.time_constant_s))
            else:
                bound = float(np.sum(c))
        if not math.isfinite(bound):
            raise CalibrationError(f'{where}: extended.{term.signal}: the {term.form} term overflows for '
                                   f'{term.signal} in {low:g}..{high:g} (the envelope: {low_c:g}..{high_c:g} '
                                   f'degC, +-{rate_max:g} deg/s, {TIME_HORIZON_S / 86400:g} days)')


def _check_correction(poly: ArtPolynomial, key: str, range_c: tuple[float, float], span: float,
                      where: str) -> None:
    """Refuse a polynomial whose correction exceeds the unit's range (+-``span``) somewhere in its envelope.

    Over a grid of the temperatures it is evaluated at (``range_c``: the clamp's range, else
    every plausible temperature) and rates (the unit's range): a correction larger than
    every rate the unit can read (a 1e300 coefficient) turns any reading into nonsense,
    published as a plausible value.
    """
    temps = np.linspace(*range_c, ENVELOPE_GRID[0])
    rates = np.linspace(-span, span, ENVELOPE_GRID[1])
    # Finite: check_envelope bounded every monomial first.
    size = np.abs(poly.error(rates[np.newaxis, :], temps[:, np.newaxis]))
    t, r = np.unravel_index(int(np.argmax(size)), size.shape)
    if not size[t, r] <= span:
        raise CalibrationError(f'{where}: {key}.coefficients: a correction of {size[t, r]:.4g} deg/s (at '
                               f'{temps[t]:g} degC, {rates[r]:g} deg/s) exceeds the unit\'s range of +-{span:g} '
                               'deg/s within the calibrated envelope: not a calibration of this gyro')


def _terms(params: Mapping[str, Any], where: str) -> tuple[Term, ...]:
    signals = _list(params.get('extended.signals', []), 'extended.signals', where, 'signal names')
    if not all(isinstance(s, str) and SIGNAL_PATTERN.match(s) for s in signals):
        raise CalibrationError(f'{where}: extended.signals must be a list of signal names, got {signals!r}')
    if len(set(signals)) != len(signals):
        raise CalibrationError(f'{where}: extended.signals names a signal twice: {signals}')
    terms = []
    for signal in signals:
        prefix = f'extended.{signal}.'
        form = _get(params, prefix + 'form', where)
        powers = _whole_numbers(params.get(prefix + 'powers', []), prefix + 'powers', where)
        rate_powers = _whole_numbers(params.get(prefix + 'rate_powers', [0]), prefix + 'rate_powers', where)
        try:
            term = Term(
                signal=signal, form=form,
                coefficients=tuple(_numbers(_get(params, prefix + 'coefficients', where),
                                            prefix + 'coefficients', where)),
                powers=tuple(powers),
                time_constant_s=_number(params.get(prefix + 'time_constant_s', 0.0),
                                        prefix + 'time_constant_s', where),
                rate_powers=tuple(rate_powers))
        except ValueError as e:
            raise CalibrationError(f'{where}: {e}') from None
        _check_start_up_safe(term, prefix, where)
        terms.append(term)
    return tuple(terms)


def _whole_numbers(value: Any, key: str, where: str) -> list[int]:
    numbers = _list(value, key, where, 'whole numbers')
    if not all(isinstance(p, int) and not isinstance(p, bool) for p in numbers):
        raise CalibrationError(f'{where}: {key} must be whole numbers, got {numbers!r}')
    return numbers


def _check_start_up_safe(term: Term, prefix: str, where: str) -> None:
    """Refuse a term the node would apply wrongly from whatever state it starts in."""
    # A signal the node does not track: the angle, which would need an absolute heading.
    if term.form == 'harmonic' or (term.signal in SIGNALS and not SIGNALS[term.signal].per_sample):
        raise CalibrationError(f'{where}: {prefix}form: a term of the heading needs an absolute heading, which '
                               'the node does not have (calibrate fit reports such an effect, it does not write it)')
    if term.form == 'exp_decay' and term.signal == 'time':
        raise CalibrationError(f'{where}: {prefix}form: a warm-up decays from the gyro\'s power-on, not from the '
                               f'node\'s start: use the signal {POWER_ON_SIGNAL} (the node applies it when '
                               'told powered_on_at_start)')


def flatten(tree: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested YAML mappings to dotted parameter names, as ROS 2 does."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _nest(params: Mapping[str, Any]) -> dict[str, Any]:
    tree: dict[str, Any] = {}
    for name, value in params.items():
        node = tree
        *parents, leaf = name.split('.')
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return tree


def shorten(text: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how much was left out."""
    return text if len(text) <= limit else f'{text[:limit]}... ({len(text) - limit} more characters)'


class _TooDeep(yaml.YAMLError):
    """A YAML document nested deeper than MAX_YAML_DEPTH, said in one line."""


class _NoAliasLoader(yaml.SafeLoader):
    """A safe loader as rcl reads a params file: no aliases, no key given twice, numbers as ``strtod`` spells them.

    Aliases: a few hundred bytes of nested ones expand to gigabytes. A key given twice would
    silently keep the last (an all-zero polynomial over the fitted one). YAML 1.1 reads ``1e-300``
    (no dot, no exponent sign) as a string where rcl reads a double: such numbers are floats here too.
    """

    depth = 0   # of the node being composed: the composer recurses, so a deep file would end in a RecursionError

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()   # type: ignore[no-untyped-call]
            raise yaml.composer.ComposerError(None, None, f'found alias *{event.anchor}: YAML aliases are not '
                                              'allowed here', event.start_mark)
        if self.depth >= MAX_YAML_DEPTH:
            mark = self.peek_event().start_mark   # type: ignore[no-untyped-call]
            raise _TooDeep(f'nested deeper than {MAX_YAML_DEPTH} levels (line {mark.line + 1}, column '
                           f'{mark.column + 1})')
        self.depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            lines: dict[Any, int] = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node)
                try:
                    first = lines.setdefault(key, key_node.start_mark.line + 1)
                except TypeError:
                    continue   # an unhashable key: refused by the base class
                if first != key_node.start_mark.line + 1:
                    raise yaml.constructor.ConstructorError(
                        None, None, f'key {shorten(repr(key), 80)} given twice, on lines {first} and '
                        f'{key_node.start_mark.line + 1}', key_node.start_mark)
        return super().construct_mapping(node, deep)


# A decimal number with an exponent but no dot or no exponent sign (1e-300, 2.5e3, .5E2), which rcl's strtod reads
# as a double and YAML 1.1 as a string; the numbers YAML 1.1 already reads keep its resolvers.
_NoAliasLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float', re.compile(r'^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$'),
    list('-+0123456789.'))


def _read_regular(path: str | os.PathLike[str], limit: int) -> bytes:
    """At most ``limit`` + 1 bytes of a regular file; anything else (a FIFO, a device) is refused unread.

    Opened without blocking and checked on the open descriptor, so a FIFO cannot hang the reader
    (a node at start-up ignoring SIGINT), nor a path swapped between the check and the read.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, 'O_NOCTTY', 0))
    with open(fd, 'rb') as stream:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise CalibrationError(f'{path}: is {special_file_kind(mode)}, not a regular file')
        return stream.read(limit + 1)


def special_file_kind(mode: int) -> str:
    """What a file that is not a regular one is, for a message ('a FIFO', 'a character device', ...)."""
    kinds = ((stat.S_ISDIR, 'a directory'), (stat.S_ISFIFO, 'a FIFO'), (stat.S_ISCHR, 'a character device'),
             (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket'))
    return next((name for test, name in kinds if test(mode)), 'a special file')


def read_yaml(path: str | os.PathLike[str], what: str = 'file') -> Any:
    """Parse a small YAML file safely: regular, within MAX_YAML_BYTES and MAX_YAML_DEPTH, no alias, no key twice.

    Anything else is a :class:`CalibrationError` naming the file and a readable part of the problem.
    """
    where = str(path)
    try:
        data = _read_regular(path, MAX_YAML_BYTES)
    except OSError as e:
        raise CalibrationError(f'{where}: cannot read: {e.strerror}') from None
    if len(data) > MAX_YAML_BYTES:
        raise CalibrationError(f'{where}: larger than {MAX_YAML_BYTES} bytes: not a {what}')
    try:
        return yaml.load(data.decode('utf-8'), Loader=_NoAliasLoader)
    except UnicodeDecodeError as e:
        raise CalibrationError(f'{where}: not UTF-8 text (byte {e.start}): not a {what}') from None
    except _TooDeep as e:
        raise CalibrationError(f'{where}: not a {what}: {e}') from None
    except yaml.YAMLError as e:
        raise CalibrationError(f'{where}: not valid YAML: {shorten(str(e))}') from None


def load_calibration(path: str | os.PathLike[str], expected_serial: str | None = None) -> Calibration:
    """Read and check a calibration file, which must be for ``expected_serial`` if given."""
    where = str(path)
    doc = read_yaml(path, 'calibration file')
    if not isinstance(doc, Mapping) or len(doc) != 1:
        raise CalibrationError(f'{where}: expected one node entry such as "/**:" with ros__parameters')
    (node_name, body), = doc.items()
    if not isinstance(body, Mapping) or not isinstance(body.get('ros__parameters'), Mapping):
        raise CalibrationError(f'{where}: entry {shorten(repr(node_name))} has no ros__parameters mapping')
    calibration = from_parameters(flatten(body['ros__parameters']), where)
    if expected_serial is not None and calibration.serial_number != expected_serial:
        raise CalibrationError(f'{where}: serial_number is {calibration.serial_number!r}, '
                               f'expected {expected_serial!r}')
    return calibration


def dump_calibration(calibration: Calibration, header: str = '') -> str:
    """Text of a calibration file; ``header`` lines become comments."""
    comments = ''.join(f'# {line}\n' for line in header.splitlines())
    doc = {'/**': {'ros__parameters': _nest(calibration.to_parameters())}}
    return comments + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)


def write_calibration(path: str | os.PathLike[str], calibration: Calibration, header: str = '') -> None:
    """Write a calibration file that the node and the offline tools both load."""
    Path(path).write_text(dump_calibration(calibration, header), encoding='utf-8')


def config_dirs() -> list[Path]:
    """Where packaged ``config/<SERIAL>.yaml`` files may be, most specific first.

    An ament (colcon) install lists its prefix in ``AMENT_PREFIX_PATH``; a pip install
    puts the data files under ``sys.prefix``; a source checkout has them beside the package.
    """
    dirs = [Path(p) / 'share' / PACKAGE / 'config'
            for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    dirs.append(Path(sys.prefix) / 'share' / PACKAGE / 'config')
    dirs.append(Path(__file__).resolve().parent.parent / 'config')
    return dirs


def find_calibration_file(serial_number: str) -> Path:
    """Path of the packaged calibration of ``serial_number``."""
    if not SERIAL_PATTERN.match(serial_number):
        raise CalibrationError(f'serial_number {serial_number!r} is not a valid serial number')
    searched = config_dirs()
    for d in searched:
        candidate = d / f'{serial_number}.yaml'
        if candidate.is_file():
            return candidate
    raise CalibrationError(f'no calibration file {serial_number}.yaml in ' + ', '.join(map(str, searched)))


def resolve_calibration_url(url: str) -> Path:
    """The file a ``calibration_file`` parameter names (the ``camera_info_url`` pattern).

    ``package://<package>/<path>`` is a file of an installed package's share directory;
    ``file:///abs/path`` and a plain path are that file.
    """
    if url.startswith('package://'):
        package, _, relative = url[len('package://'):].partition('/')
        if not package or not relative:
            raise CalibrationError(f'calibration_file {url!r}: expected package://<package>/<path>')
        shares = [Path(p) / 'share' / package for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
        if package == PACKAGE:
            shares += [d.parent for d in config_dirs()]
        for share in shares:
            if (share / relative).is_file():
                return share / relative
        raise CalibrationError(f'calibration_file {url!r}: no {relative} in ' + ', '.join(map(str, shares)))
    path = url[len('file://'):] if url.startswith('file://') else url
    return Path(path).expanduser()


def load_packaged_calibration(serial_number: str) -> Calibration:
    """Load the packaged calibration of a gyro by its KVH serial number."""
    return load_calibration(find_calibration_file(serial_number), expected_serial=serial_number)


def check_signals_available(calibration: Calibration, available: tuple[str, ...] = DERIVED_SIGNALS) -> None:
    """Refuse a calibration whose terms need signals that are not ``available``."""
    missing = [t.signal for t in calibration.terms if t.signal not in available]
    if missing:
        raise CalibrationError(f'calibration {calibration.serial_number}: extended terms need '
                               f'signals {missing} that are not available here ({", ".join(available)})')


# How a topic's message gives an extra signal's value (node parameter extra_signals.<signal>.type).
EXTRA_SIGNAL_TYPES = {'float64': 'std_msgs/Float64 data', 'battery_state': 'sensor_msgs/BatteryState voltage'}


def extra_signal_parameter(signal: str, field: str = 'topic') -> str:
    """The node parameter that says where extra signal ``signal`` comes from (``topic``, ``type``, ``max_age_s``)."""
    return f'extra_signals.{signal}.{field}'


def extra_signals(calibration: Calibration) -> tuple[str, ...]:
    """The signals the terms need that the gyro does not give: log columns (a supply voltage) the node must be fed."""
    return tuple(t.signal for t in calibration.terms if t.signal not in SIGNALS)


def node_parameters_needed(calibration: Calibration) -> dict[str, str]:
    """The node parameters a calibration needs set beyond its own, with what each must say (none: {})."""
    types = ' or '.join(EXTRA_SIGNAL_TYPES)
    return {name: what for signal in extra_signals(calibration) for name, what in (
        (extra_signal_parameter(signal), f'the topic that carries {signal} (relative names follow the namespace)'),
        (extra_signal_parameter(signal, 'type'), f'its message: {types}'))}


def check_fed(calibration: Calibration, fed: Collection[str], where: str) -> None:
    """Refuse a calibration with a term on an extra signal that no topic feeds, naming the node parameter to set.

    ``fed``: the extra signals the node receives. Without one, the node could not apply the term.
    """
    missing = [s for s in extra_signals(calibration) if s not in fed]
    if missing:
        raise CalibrationError(
            f'{where}: extended terms need {", ".join(missing)}, which the gyro does not measure: set the node '
            f'parameter {" and ".join(map(extra_signal_parameter, missing))} to the topic that carries it (and '
            f'{extra_signal_parameter(missing[0], "type")}: {" or ".join(EXTRA_SIGNAL_TYPES)}), or use a calibration '
            'without the term (calibrate fit writes one only with --node-signal)')
