"""The report's sample program: scale, compensate, and correct with the static bias.

:class:`Compensator` does it one sample at a time and :class:`FrameCorrector` one frame at a
time as the node must (drop, feed a static bias collection, correct); :func:`apply_calibration`
over a whole log or chunk after chunk of one (``calibrate apply``). Both give
``CompRate = GyroRate - StaticBiasDrift - comp + CalcStaticBiasDrift``, and both drop the
samples :func:`plausible` refuses, clamp the temperature to the calibrated range if the
calibration has one (the report's do not: their polynomial applies at every temperature), count
the samples outside the range it is expected to hold, and refine a static bias the temperature-rate terms need
refined (:class:`static_bias.Refinement`). How the run started (:class:`RunStart`) decides
whether a warm-up term applies. Signals from outside the gyro (a supply voltage) come in by
:class:`~art_gyro_calibration.signals.SignalFeed`: until each has had a value the terms on them
are left out and no static bias is collected, and while one is stale the answer says so
(:attr:`Compensator.current`).

Until the refinement is ready, the temperature-rate terms are not evaluated on the filter: the
static bias has taken the true Shupe error of the window (the causal filter read about 0 there),
so letting the filter's rise through its first minutes into the output would subtract that error
a second time (for minutes after a cold start with self-heating, when the error is largest). They
hold their window mean for a minute, then follow the refinement's provisional fit
(:meth:`static_bias.Refinement.error_one`): how far its slope moved since the window.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import overload

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import (MAX_UNIT_RANGE_DPS, PLAUSIBLE_TEMPERATURE_C, Calibration,
                                              check_fed, check_signals_available, unit_range_dps)
from art_gyro_calibration.frame import INT16_MAX, NOT_FINITE
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ErrorModel
from art_gyro_calibration.signals import (DERIVED_SIGNALS, SignalFeed, SignalFilters, Signals, SignalState,
                                          SignalTracker, compute_signals)
from art_gyro_calibration.static_bias import (DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, NO_BIAS,
                                              BiasWindow, Refinement, StaticBias, StaticBiasCollector,
                                              static_bias)


# Why a frame was not published (FrameCorrector.step's answer, counted per reason).
IMPLAUSIBLE_TEMPERATURE = 'implausible_temperature'
# The rate count at an end of its range (+-32767 on an RD2100): the true rate is anywhere beyond, so no value.
CLIPPED = 'clipped'
# A rate beyond the unit's range (Calibration.rate_range_dps): a corrupt message whose CRC passed, not a rate.
BEYOND_RANGE = 'beyond_range'


def rate_limits(rate_scale_factor: float) -> tuple[float, float]:
    """(clip, range) in deg/s: a rate of magnitude at least ``clip`` is clipped, one beyond ``range`` impossible.

    Clipped: within half a count of the 16-bit count's end (a log's rounded deg/s too), where the
    counts' end is the unit's (RD2100); a kvh_fog unit (1.0 deg/s per "count") has its range alone.
    """
    clip, span = (INT16_MAX - 0.5) * rate_scale_factor, unit_range_dps(rate_scale_factor)
    return (clip if clip < span else math.inf), span


def usable_rates(rate_dps: NDArray[np.float64], rate_scale_factor: float) -> NDArray[np.bool_]:
    """Per row of a log, whether ``calibrate fit`` may use its rate: not clipped, not beyond every unit's range.

    Clipped: the 16-bit count at its end, within half a count (what the node drops as CLIPPED). A rate
    beyond MAX_UNIT_RANGE_DPS is no unit's. Rows beyond the counts' range but within that (a simulated
    RD2100 log's table at 100 deg/s, beyond its 99.94) cannot come from a wire and are kept.
    """
    clip, _ = rate_limits(rate_scale_factor)
    size = np.abs(rate_dps)
    return ~((size >= clip) & (size <= (INT16_MAX + 1.5) * rate_scale_factor)) & (size <= MAX_UNIT_RANGE_DPS)


@overload
def plausible(temp_c: float) -> bool: ...


@overload
def plausible(temp_c: NDArray[np.float64]) -> NDArray[np.bool_]: ...


def plausible(temp_c: float | NDArray[np.float64]) -> bool | NDArray[np.bool_]:
    """Whether a sample (or each of an array of them) is kept: its temperature is physically possible."""
    low, high = PLAUSIBLE_TEMPERATURE_C
    return (low <= temp_c) & (temp_c <= high)


@dataclass(frozen=True)
class RunStart:
    """How a run began: ``powered_on_at_start`` if the gyro was switched on with it (a cold start).

    Unknown by default: a warm-up term then counts as decayed, so that a node restarted on a
    warm gyro never replays a warm-up into its static bias. Told it was a cold start, the
    warm-up decays from the run's first sample.
    """

    powered_on_at_start: bool = False


class Compensator:
    """Per-sample compensation with the signals the extended terms need, kept causally.

    ``outside_range`` counts the samples whose temperature was outside the calibration's
    :attr:`~Calibration.expected_range_c` (clamped only if it is a calibrated range); a
    refinement, once it happened, shows in ``bias.refined_dps`` (see ``bias``).

    ``feeds``: the signals from outside the gyro the terms need (a calibration with a term on
    one not fed is refused). Each sample takes their latest values; until every one has had a
    value, the model without their terms is used. :attr:`current` says whether the last sample
    had every feed's value no older than its limit (always True without feeds) and, once corrected
    (:meth:`correct`), a corrected rate within the unit's range.

    A corrected rate beyond the unit's range (:attr:`~Calibration.rate_range_dps`) is no rate the gyro can have
    measured, whatever produced it (a term, the polynomial, a bias): :meth:`correct` answers the rate
    uncorrected instead, not current, counted in ``beyond_unit_range`` (the last one in ``last_beyond_dps``);
    as :func:`apply_calibration` does, a rate itself beyond the range (a frame the node drops) is left as it is.
    """

    __slots__ = ('calibration', '_bias', '_model', '_tracker', '_rate_scale', '_temp_scale', '_range',
                 '_refinable', '_refinement', 'outside_range', '_feeds', '_limits', 'beyond_limits', '_unfed',
                 'current', '_unit_range', 'beyond_unit_range', 'last_beyond_dps')

    def __init__(self, calibration: Calibration, start: RunStart = RunStart(),
                 feeds: tuple[SignalFeed, ...] = ()) -> None:
        check_fed(calibration, [f.name for f in feeds], f'calibration {calibration.serial_number}')
        self.calibration = calibration
        self._model = calibration.model
        self._feeds = feeds
        # A fed value beyond the range its term was fitted over (and the margin) is applied at the limit and flagged.
        self._limits = tuple(calibration.signal_limits(f.name) for f in feeds)
        self.beyond_limits = [0] * len(feeds)   # per feed: samples whose value was beyond its limits
        # Until every feed has had a value: the model without their terms (the rate is then uncorrected anyway:
        # no static bias is collected before).
        names = {f.name for f in feeds}
        self._unfed = replace(self._model, terms=tuple(t for t in self._model.terms if t.signal not in names))
        self.current = True
        self._tracker = SignalTracker(calibration.filters, self._model.lags, start.powered_on_at_start,
                                      tuple(names))
        self._rate_scale = calibration.rate_scale_factor
        self._temp_scale = calibration.temp_scale_factor
        # No range known: nothing is outside it.
        self._range = calibration.expected_range_c or (-math.inf, math.inf)
        self._refinable = bool(self._model.refinable)
        self._refinement: Refinement | None = None
        self._bias: StaticBias = NO_BIAS
        self.outside_range = 0
        self._unit_range = calibration.rate_range_dps
        self.beyond_unit_range = 0
        self.last_beyond_dps = math.nan

    @property
    def refinable(self) -> bool:
        """Whether a static bias should keep its window: the model has temperature-rate terms."""
        return self._refinable

    @property
    def bias(self) -> StaticBias:
        """The static bias in use; setting one that kept its window starts its refinement.

        A refinement runs from the next sample: until its ``ready_at`` the temperature-rate terms
        are its provisional ones, and the sample at ``ready_at`` is the first corrected with the
        refined bias (:meth:`error`), which then replaces this one. Setting another bias drops it.
        """
        return self._bias

    @bias.setter
    def bias(self, bias: StaticBias) -> None:
        self._bias = bias
        self._refinement = Refinement(bias, self._model.refinable, self.calibration.filters.refinement_scale_s) \
            if bias.window is not None and self._refinable else None

    def scale(self, raw_rate: float, raw_temp: float) -> tuple[float, float]:
        """Counts (or a KVH unit's deg/s and degC) to (GyroRate deg/s, GyroTemp degC)."""
        return raw_rate * self._rate_scale, raw_temp * self._temp_scale

    def error(self, t: float, rate_dps: float, temp_c: float) -> float:
        """Advance the signals to this sample and return comp, its modelled error."""
        tracker = self._tracker
        tracker.update(t, rate_dps, temp_c)
        if self._feeds:
            model = self._read_feeds()
        else:
            model, self.current = self._model, True   # until correct() finds it beyond the unit's range
        low, high = self._range
        if not low <= temp_c <= high:
            self.outside_range += 1
        refinement = self._refinement
        if refinement is not None:
            if t < refinement.ready_at:
                return refinement.error_one(t, temp_c, rate_dps,
                                            model.error_one(tracker) - model.refinable_error_one(tracker))
            self._bias, self._refinement = refinement.refined(), None   # this sample is the first corrected with it
        return model.error_one(tracker)

    def _read_feeds(self) -> ErrorModel:
        """Take each feed's latest value and set :attr:`current`; the model to use (their terms only once fed).

        A value beyond its :meth:`~Calibration.signal_limits` is taken at the limit, and the sample is not current.
        """
        values = self._tracker.extras
        current = True
        for k, feed in enumerate(self._feeds):
            latest = feed.latest
            if latest is None:
                self.current = False
                return self._unfed
            value, received = latest
            low, high = self._limits[k]
            if not low <= value <= high:
                value = high if value > high else low
                self.beyond_limits[k] += 1
                current = False
            values[feed.name] = value
            if not feed.clock() - received <= feed.max_age_s:
                current = False
        self.current = current
        return self._model

    def causal_dps(self) -> float:
        """The temperature-rate terms' part of the last error (a static bias collection keeps it; 0 without them).

        Asked only while a collection runs: the hot path does not pay for it.
        """
        return self._model.refinable_error_one(self._tracker) if self._refinable else 0.0

    def correct(self, rate_dps: float, error_dps: float) -> float:
        """``CompRate`` with the current static bias; if beyond the unit's range, ``rate_dps`` and not current."""
        corrected = self._bias.correct(rate_dps, error_dps)
        span = self._unit_range
        if -span <= corrected <= span or not -span <= rate_dps <= span:   # the latter: a frame the node drops
            return corrected
        self.beyond_unit_range += 1
        self.last_beyond_dps = corrected
        self.current = False
        return rate_dps


class FrameCorrector:
    """The node's step for one frame: scale, drop, compensate, feed a static bias collection, correct.

    :meth:`step` answers '' for a frame to publish, whose values are then in ``rate_dps`` (the
    corrected rate) and ``temp_c``, or the reason it is dropped (:data:`IMPLAUSIBLE_TEMPERATURE`,
    :data:`CLIPPED`, :data:`BEYOND_RANGE`, :data:`NOT_FINITE`), counted in ``dropped``.
    :meth:`collect` feeds the frames kept to a static bias collection, those only whose extra
    signals (``feeds``, see :class:`Compensator`) are current: a bias taken without them (or with a stale value)
    would not match the terms on them. Answers and values live on the object, not in new tuples: it runs at 1 kHz.
    """

    __slots__ = ('compensator', 'collector', '_collected', 'dropped', 'last_drop_error', 'rate_dps', 'temp_c',
                 '_clip_dps', '_range_dps')

    def __init__(self, calibration: Calibration, start: RunStart = RunStart(),
                 feeds: tuple[SignalFeed, ...] = ()) -> None:
        self.compensator = Compensator(calibration, start, feeds)
        self.collector: StaticBiasCollector | None = None   # the collection fed, if one; None stops it
        self._collected: Callable[[StaticBiasCollector], None] = _nothing
        self.dropped = {IMPLAUSIBLE_TEMPERATURE: 0, CLIPPED: 0, BEYOND_RANGE: 0, NOT_FINITE: 0}
        self._clip_dps, self._range_dps = rate_limits(calibration.rate_scale_factor)
        self.last_drop_error = ''   # the arithmetic error of the last frame dropped as NOT_FINITE, if one
        self.rate_dps = math.nan
        self.temp_c = math.nan

    def collect(self, collector: StaticBiasCollector, collected: Callable[[StaticBiasCollector], None]) -> None:
        """Feed ``collector``; the frame that completes it calls ``collected`` before it is corrected.

        ``collected`` ends the collection (:meth:`end_collection`), with its bias if it found one.
        """
        self._collected = collected
        self.collector = collector

    def end_collection(self, bias: StaticBias | None) -> None:
        """The static bias hand-off: stop feeding the collection and, given ``bias``, put it in force.

        What a frame sees: the frames up to the one that completed the collection are corrected
        with the bias in force before; that frame (whose ``collected`` callback calls this, inside
        :meth:`step`) is the first corrected with ``bias``. If ``bias`` kept its window and the model
        has temperature-rate terms, its refinement starts with it (:attr:`Compensator.bias`): the
        next frames' temperature-rate terms follow it, and the frame at its ``ready_at`` is the first
        corrected with the refined bias. Without ``bias`` (motion, a stall, a stop) the bias in
        force, and a refinement of it, go on.

        No lock of its own: the bias is only ever put in force on the thread that runs :meth:`step`.
        Another thread (the node's timer giving up a stalled collection) ends one without a bias;
        a frame being stepped meanwhile may still feed it one sample, and its owner ignores a
        collection it ended. The node's static bias service calls this under its own lock, so that
        its state reads the bias and the collection's end together.
        """
        self.collector = None
        if bias is not None:
            self.compensator.bias = bias

    def step(self, raw_rate: float, raw_temp: float, t: float) -> str:
        """Correct the frame read at ``t`` (s); '' if it is to be published, else why not."""
        compensator = self.compensator
        rate_dps, temp_c = compensator.scale(raw_rate, raw_temp)
        if not plausible(temp_c):
            self.dropped[IMPLAUSIBLE_TEMPERATURE] += 1
            return IMPLAUSIBLE_TEMPERATURE
        size = abs(rate_dps)
        if size >= self._clip_dps:   # not a value: the rate may be anything beyond (no signal advanced by it)
            self.dropped[CLIPPED] += 1
            return CLIPPED
        if size > self._range_dps:
            self.dropped[BEYOND_RANGE] += 1
            return BEYOND_RANGE
        try:
            error_dps = compensator.error(t, rate_dps, temp_c)   # every sample: it advances the signals
        except ArithmeticError as e:
            error_dps = math.nan
            self.last_drop_error = f'{type(e).__name__}: {e}'
        if not math.isfinite(error_dps):
            self.dropped[NOT_FINITE] += 1
            return NOT_FINITE
        collector = self.collector
        if (collector is not None and compensator.current
                and collector.add(rate_dps, error_dps, t, temp_c, compensator.causal_dps())):
            self._collected(collector)
        self.rate_dps = compensator.correct(rate_dps, error_dps)   # with the bias this frame may have put in force
        self.temp_c = temp_c
        return ''


def _nothing(collector: StaticBiasCollector) -> None:
    """No collection was started: nothing to do (see :meth:`FrameCorrector.collect`)."""


def _refinable_error(model: ErrorModel, signals: Signals, rows: slice) -> NDArray[np.float64]:
    """The temperature-rate terms' part of the modelled error over ``rows`` of a log."""
    return np.asarray(sum(model.term_error(t, signals)[rows] for t in model.refinable))


@dataclass(frozen=True)
class Applied:
    """A log (or one chunk of it) after compensation: the kept samples' values, and what was dropped."""

    comp_dps: NDArray[np.float64]
    corrected_dps: NDArray[np.float64]
    bias: StaticBias            # the static bias at the chunk's end (refined, once it was)
    kept: NDArray[np.bool_]     # per row of the log: plausible, so compensated (the node drops the rest)
    signals: Signals            # the kept samples' signals (their end state is where the next chunk continues)
    outside_range: int = 0      # kept rows (this chunk and those before) outside the expected temperature range
    refinement: Refinement | None = None   # a static bias refinement still gathering temperatures
    start: RunStart = RunStart()
    held: Mapping[str, float] = field(default_factory=dict)   # per signal from outside the gyro: its last value
    # Per signal from outside the gyro, kept rows (this chunk and those before) that took another value than the
    # log's: (not finite: the last finite value held, beyond Calibration.signal_limits: applied at the limit).
    flagged: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    # Kept rows (this chunk and those before) whose rate is within the unit's range and corrected rate beyond it (or
    # not a number): written uncorrected, as the node publishes them flagged (Compensator.correct).
    beyond_unit_range: int = 0

    @property
    def state(self) -> SignalState:
        """The signals after the last kept sample: where the next chunk continues (asked of a chunk's alone)."""
        return self.signals.end_state()


def _fed_values(log: GyroLog, calibration: Calibration,
                after: Applied | None) -> tuple[GyroLog, dict[str, float], dict[str, tuple[int, int]]]:
    """``log`` with each signal from outside the gyro that a term needs as the node takes it; last values, counts.

    A value that is not finite holds the last finite one (the previous chunk's, or the first of the column);
    one beyond :meth:`~Calibration.signal_limits` is taken at the limit. Both are counted (:attr:`Applied.flagged`).
    """
    held = dict(after.held) if after is not None else {}
    flagged = dict(after.flagged) if after is not None else {}
    extras = dict(log.extras)
    for name in (t.signal for t in calibration.terms if t.signal in log.extras and t.signal not in DERIVED_SIGNALS):
        values = extras[name]
        bad = ~np.isfinite(values)
        not_finite = int(np.count_nonzero(bad))
        if not_finite:
            finite = np.flatnonzero(~bad)
            if name not in held and not finite.size:
                raise ValueError(f'column {name} has no finite value in its first {len(values)} rows: the term on it '
                                 'cannot be applied')
            first = held.get(name, float(values[finite[0]]) if finite.size else math.nan)
            index = np.maximum.accumulate(np.where(bad, 0, np.arange(len(values))))
            values = np.where(bad[index], first, values[index])   # rows before the first finite one: ``first``
        low, high = calibration.signal_limits(name)
        beyond = int(np.count_nonzero((values < low) | (values > high)))
        if beyond:
            values = np.clip(values, low, high)
        extras[name] = values
        held[name] = float(values[-1])
        before = flagged.get(name, (0, 0))
        flagged[name] = (before[0] + not_finite, before[1] + beyond)
    return replace(log, extras=extras), held, flagged


def _kept_rows(log: GyroLog) -> tuple[NDArray[np.bool_], GyroLog]:
    """The rows the node keeps (:func:`plausible`), and the log of them alone."""
    kept = plausible(log.temp_c)
    return kept, (log if kept.all() else log.slice(kept))


def run_signals(log: GyroLog, filters: SignalFilters, start: RunStart = RunStart()) -> Signals:
    """The signals :func:`apply_calibration` computes for a run from its first row (the rows the node keeps)."""
    _, log = _kept_rows(log)
    return compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, filters, None, start.powered_on_at_start)


def apply_calibration(log: GyroLog, calibration: Calibration, bias_samples: int,
                      max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                      max_std_dps: float = DEFAULT_MAX_STD_DPS, *, after: Applied | None = None,
                      start: RunStart = RunStart(), signals: Signals | None = None) -> Applied:
    """Static bias over the first ``bias_samples`` kept rows, then compensation of every kept row.

    Vectorised over the log, so not :class:`FrameCorrector` itself, which the node runs; a test
    (test_compensation) holds the two together on the same frames (within 2e-9 deg/s).
    Rows :func:`plausible` refuses are dropped, as the node drops their frames (clipped rates are
    not: ``calibrate fit`` excludes them before, see :func:`usable_rates`). A log read in chunks
    passes each chunk with ``after`` = the previous chunk's result (the first chunk
    holding at least ``bias_samples`` kept rows): its signals continue, and its bias is kept.
    ``start`` says how the run began (the first chunk's; later chunks continue it). A row whose corrected rate
    is beyond the unit's range is written uncorrected and counted (:attr:`Applied.beyond_unit_range`), as the node
    publishes it flagged. ``signals``: :func:`run_signals` of this log with ``calibration.filters`` and ``start``, made
    once for several calibrations replayed on one run (not for a later chunk; not where the calibration's limits
    move an extra signal's values: then computed here).
    """
    kept, log = _kept_rows(log)
    if after is None:
        if not 2 <= bias_samples <= len(log):
            raise ValueError(f'bias_samples must be between 2 and the {len(log)} plausible rows of the log, '
                             f'got {bias_samples}')
        check_signals_available(calibration, DERIVED_SIGNALS + tuple(log.extras))
    else:
        start = after.start
    given = log.extras
    log, last_values, flagged = _fed_values(log, calibration, after)
    model = calibration.model
    if signals is None or after is not None or any(log.extras[k] is not given[k] for k in given) \
            or (signals.filters, signals.powered_on_at_start, len(signals.t)) \
            != (calibration.filters, start.powered_on_at_start, len(log)):
        signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, calibration.filters,
                                  None if after is None else after.state, start.powered_on_at_start)
    comp = model.error(signals)
    low, high = calibration.expected_range_c or (-math.inf, math.inf)
    outside_range = int(np.count_nonzero((log.temp_c < low) | (log.temp_c > high))) \
        + (0 if after is None else after.outside_range)
    if after is None:
        n = bias_samples
        bias = static_bias(log.rate_dps[:n], comp[:n], max_mean_dps, max_std_dps)
        refinement = None
        if model.refinable:
            causal = _refinable_error(model, signals, slice(0, n))
            bias = replace(bias, window=BiasWindow(log.t[:n].copy(), log.rate_dps[:n].copy(), log.temp_c[:n].copy(),
                                                   float(np.mean(causal))))
            refinement = Refinement(bias, model.refinable, calibration.filters.refinement_scale_s)
        first = n   # the rows after the window feed the refinement
    else:
        bias, refinement, first = after.bias, after.refinement, 0
    if refinement is not None:
        ready = first + int(np.searchsorted(log.t[first:], refinement.ready_at, side='left'))
        held = slice(first, ready)
        if ready > first:   # until the refinement, the temperature-rate terms as it gives them
            comp[held] = refinement.error_many(log.t[held], log.temp_c[held], log.rate_dps[held],
                                               comp[held] - _refinable_error(model, signals, held))
    corrected = bias.correct(log.rate_dps, comp)
    if refinement is not None:
        if ready < len(log):
            bias, refinement = refinement.refined(), None
            corrected[ready:] = bias.correct(log.rate_dps[ready:], comp[ready:])
    # Of the rows the node would take (a rate beyond the unit's range it drops: a simulated table's 100 deg/s).
    span = calibration.rate_range_dps
    beyond = ~(np.abs(corrected) <= span) & (np.abs(log.rate_dps) <= span)
    if beyond.any():
        corrected[beyond] = log.rate_dps[beyond]
    beyond_unit_range = int(np.count_nonzero(beyond)) + (0 if after is None else after.beyond_unit_range)
    return Applied(comp, corrected, bias, kept, signals, outside_range, refinement, start, last_values,
                   flagged, beyond_unit_range)
