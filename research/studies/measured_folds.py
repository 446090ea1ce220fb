"""One gyro axis of the CATS record with one day held out: the package's loop on the others, errors on it.

:func:`run_fold` runs ``calibrate fit``'s loop (:func:`close_loop`) on the training days,
keeps a traced time term (drift or slow exponential) only if each training day alone
agrees with it (:func:`time_term_agreement`), and measures every model on the held-out
day four ways: as predicted, after a static bias taken at the start of the day or once
its handling transient has settled, and with the day's mean removed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.allan import AllanDeviation, allan_deviation
from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.analysis.loop import DEFAULT_MAX_EFFECTS, LoopOptions, LoopResult, close_loop
from art_gyro_calibration.analysis.replay import startup_check
from art_gyro_calibration.analysis.metrics import FieldErrors, field_errors, heading_error_deg
from art_gyro_calibration.analysis.report import STAGES
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ArtPolynomial, ErrorModel
from art_gyro_calibration.signals import SignalFilters, Signals, compute_signals
from art_gyro_calibration.static_bias import static_bias
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

from importers import segment_labels
from measured_record import BLOCK_S, RUN_GAP_S, block_segments, settled_start

ROWS, COLUMNS = 3, 1  # the report's three temperature powers; a still gyro has only rate power 0
BIAS_SAMPLES = 600  # 10 min at 1 Hz: a MEMS gyro's 0.1 deg/s per-sample noise needs that many
# The static bias's motion checks are off: the importer kept only still samples, and a model that
# extrapolates wildly on the held-out day must show as a large error, not stop the study.
MAX_MEAN_DPS = MAX_STD_DPS = float('inf')
# The handling transient is over when the temperature changes by at most this over the bias window.
SETTLED_C_PER_H = 1.0
# The loop screens bin means of this many seconds (its default is 1 s): every effect in question lives on
# hours, and 10-s bins cut its time 15-fold (checked on gyro y with day 3 held out: the same verdict and
# candidates, chance p 0.085 against 0.065).
LOOP_BIN_S = 10.0
# Two training days disagree on a term when their gains differ by more than this many standard errors.
AGREEMENT_SIGMAS = 2.0
# The loop's time terms: a drift counted from the run's start, a warm-up from the power-on.
TIME_SIGNALS = ('time', 'time_since_power_on')
WAYS = ('predicted', 'bias_start', 'bias_settled', 'mean_removed')
WAY_TITLES = {'predicted': 'as predicted (no bias removed)', 'bias_start': 'static bias at the start',
              'bias_settled': 'static bias after the transient', 'mean_removed': 'mean removed'}
STAGE_TITLES = {'uncalibrated': 'static bias only', 'art': 'ART polynomial (temperature powers)',
                'extended': 'ART + traced effects'}


@dataclass(frozen=True)
class SignalsSince(Signals):
    """Signals whose ``time`` counts from ``origin_s`` (the training log's first sample), not from this log's.

    The loop's time terms count from the first sample it was given; a held-out day
    before the training days must be evaluated on the same clock.
    """

    origin_s: float = 0.0

    @property
    def time(self) -> NDArray[np.float64]:
        """Seconds since ``origin_s``."""
        return self.t - self.origin_s


@dataclass(frozen=True)
class DayGain:
    """One training day's fit of a term: ``gain`` times the jointly fitted term, with its standard error."""

    day: int
    gain: float
    stderr: float
    judged: bool  # the term varies on this day by more than the bias instability


@dataclass(frozen=True)
class Agreement:
    """Whether the training days, each alone, agree on a traced time term."""

    term: Term
    days: tuple[DayGain, ...]
    kept: bool

    def describe(self) -> str:
        """One line: the per-day gains and the verdict."""
        parts = []
        for d in self.days:
            value = f'{d.gain:+.2f} +- {d.stderr:.2f}' if d.judged else 'flat'
            if d.judged and self.term.form == 'power' and self.term.powers == (1,):
                per_day = self.term.coefficients[0] * 86400.0
                value += f' ({per_day * d.gain:+.4f} +- {abs(per_day) * d.stderr:.4f} deg/s per day)'
            parts.append(f'day {d.day + 1}: {value}')
        return f'{"kept" if self.kept else "dropped"} ({"; ".join(parts)})'


def newey_west_slope(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """Slope of ``y = a + b x`` and its standard error robust to autocorrelated residuals (Newey-West).

    The Bartlett window spans the lags until the residual's autocorrelation falls below 1/e.
    """
    design = np.column_stack([np.ones_like(x), x])
    beta = np.linalg.lstsq(design, y, rcond=None)[0]
    u = y - design @ beta
    n = len(u)
    acf = np.correlate(u, u, 'full')[n - 1:] / max(float(u @ u), 1e-300)
    below = np.flatnonzero(acf < np.exp(-1.0))
    lags = int(min(below[0] if below.size else n // 4, n // 4))
    score = design * u[:, None]
    meat = score.T @ score
    for lag in range(1, lags + 1):
        cross = score[lag:].T @ score[:-lag]
        meat += (1.0 - lag / (lags + 1.0)) * (cross + cross.T)
    bread = np.linalg.inv(design.T @ design)
    cov = bread @ meat @ bread
    return float(beta[1]), float(np.sqrt(max(cov[1, 1], 0.0)))


def time_term_agreement(loop: LoopResult, term: Term, days: NDArray[np.int_], floor_dps: float) -> Agreement:
    """Fit the traced ``term`` on each training day alone and keep it only if the days agree.

    On each day, the 10-minute means of what the rest of the final model leaves are
    regressed on the term's own correction (a free constant per day: its bias), giving
    the day's gain relative to the joint fit (1 = the same). A day judges only if the
    term varies there by more than ``floor_dps`` (the bias instability): a warm-up that
    has died out before a day says nothing there. The term is kept only if every judging
    day confirms it (gain positive by :data:`AGREEMENT_SIGMAS` standard errors,
    autocorrelation-robust) and every two judging days agree within as many.
    """
    model = loop.extended.model
    rest = ErrorModel(model.polynomial, tuple(t for t in model.terms if t is not term))
    residual = loop.error - rest.error(loop.signals)
    correction = term.evaluate(loop.signals.get(term.signal))
    gains = []
    for day in np.unique(days):
        rows = np.flatnonzero(days == day)
        segments = block_segments(loop.signals.t[rows])
        x, y = segments.means(correction[rows]), segments.means(residual[rows])
        judged = len(x) >= 6 and float(np.ptp(x)) > floor_dps
        gain, stderr = newey_west_slope(x, y) if judged else (float('nan'), float('nan'))
        gains.append(DayGain(int(day), gain, stderr, judged))
    judging = [g for g in gains if g.judged]
    confirmed = all(g.gain > AGREEMENT_SIGMAS * g.stderr for g in judging) and all(
        abs(a.gain - b.gain) <= AGREEMENT_SIGMAS * np.hypot(a.stderr, b.stderr) for a, b in combinations(judging, 2))
    return Agreement(term, tuple(gains), confirmed)


@dataclass(frozen=True)
class Fold:
    """One gyro axis with one day held out: the loop on the others and every error on it."""

    axis: str
    day: int  # 0-based
    held_name: str
    log: GyroLog
    held: NDArray[np.bool_]
    loop: LoopResult
    agreements: tuple[Agreement, ...]
    models: dict[str, ErrorModel]  # per stage; 'extended' holds only the effects kept
    signals: SignalsSince
    bias_windows: dict[str, NDArray[np.int64]]  # 'bias_start', 'bias_settled': rows of the log
    span: NDArray[np.int64]  # rows of the log the errors are measured over
    errors: dict[tuple[str, str], NDArray[np.float64]]  # (stage, way) -> error over the span
    field: dict[tuple[str, str], FieldErrors]
    heading_1h_rms_deg: dict[tuple[str, str], float]
    allan: dict[str, AllanDeviation]
    restart_dropped: tuple[Term, ...] = ()   # the loop's terms its start-up check dropped (not in ``loop``)

    def comp(self, stage: str) -> NDArray[np.float64]:
        """Modelled error of every sample of the log for ``stage``."""
        return self.models[stage].error(self.signals)

    @property
    def bias_instability_dps(self) -> float:
        """The loop's bias instability of what ART leaves on the training days (deg/s)."""
        return self.loop.bias_instability_dph / DEG_PER_H_PER_DPS

    @property
    def kept_effects(self) -> tuple[Term, ...]:
        """The traced terms the final model keeps."""
        return self.models['extended'].terms


def sample_rate_hz(log: GyroLog) -> float:
    """The log's sample rate (Hz), from its median interval."""
    return 1.0 / float(np.median(np.diff(log.t)))


def record_allan(log: GyroLog) -> tuple[AllanDeviation, AllanDeviation]:
    """Allan deviation of a whole log's rate, and of what the ART polynomial fitted to all of it leaves."""
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, {}, SignalFilters())
    assert log.ref_rate is not None   # a record's: the gyro lay still
    residual = log.rate_dps - log.ref_rate
    residual = residual - fit_model(signals, residual, ROWS, COLUMNS).model.error(signals)
    run = segment_labels(log.t, RUN_GAP_S)
    return (allan_deviation(log.rate_dps, sample_rate_hz(log), run),
            allan_deviation(residual, sample_rate_hz(log), run))


def kept_model(loop: LoopResult, agreements: tuple[Agreement, ...], rows: int = ROWS) -> ErrorModel:
    """The loop's extended model, refitted without the time terms the training days disagree on."""
    dropped = {id(a.term) for a in agreements if not a.kept}
    if not dropped:
        return loop.extended.model
    specs = [TermSpec(t.signal, t.form, t.powers, t.time_constant_s) for t in loop.extended.model.terms
             if id(t) not in dropped]
    return fit_model(loop.signals, loop.error, rows, COLUMNS, specs, loop.segments.rows()).model


def run_fold(log: GyroLog, days: NDArray[np.int_], day: int, held_name: str, axis: str,
             max_effects: int = DEFAULT_MAX_EFFECTS, seed: int = 0, rows: int = ROWS,
             exclude: Sequence[str] = (), serial_number: str = 'CATS_gyro') -> Fold:
    """The loop on the rows whose ``days`` label is not ``day``, every stage and way on the others.

    The loop runs with its own defaults (materiality: the bias instability of what the
    ART polynomial leaves on the training rows). ``rows`` temperature powers (1 for a
    record without temperature); signals in ``exclude`` are never candidates.
    """
    held = days == day
    train = log.slice(~held)
    # The record starts at the power-on; training days after it do not (no warm-up is then a candidate).
    from_power_on = bool(train.t[0] == log.t[0])
    options = LoopOptions(serial_number=f'{serial_number}_{axis}', max_effects=max_effects, seed=seed,
                          exclude=tuple(exclude), bin_s=LOOP_BIN_S, from_power_on=from_power_on)
    loop = close_loop(train, rows, COLUMNS, options)
    # As calibrate fit: the terms the training days' own warm restarts are better without are dropped.
    loop, check, _ = startup_check(loop, train, BIAS_SAMPLES)
    restart_dropped = () if check is None else tuple(d.term for d in check.dropped)
    floor = loop.bias_instability_dph / DEG_PER_H_PER_DPS
    agreements = tuple(time_term_agreement(loop, term, days[~held], floor)
                       for term in loop.extended.model.terms if term.signal in TIME_SIGNALS)
    models = {'uncalibrated': ErrorModel(ArtPolynomial(np.zeros((1, 1)))),
              'art': loop.art.model, 'extended': kept_model(loop, agreements, rows)}
    # The node runs since power-on, the record's start: filters over the whole record, the loop's clock.
    signals = SignalsSince(log.t, log.rate_dps, log.temp_c, log.extras, loop.extended.filters,
                           powered_on_at_start=from_power_on, origin_s=float(train.t[0]))
    index = np.flatnonzero(held)
    settled = settled_start(log.t[index], log.temp_c[index], BIAS_SAMPLES, SETTLED_C_PER_H)
    windows = {'bias_start': index[:BIAS_SAMPLES], 'bias_settled': index[settled:settled + BIAS_SAMPLES]}
    span = index[settled + BIAS_SAMPLES:]
    assert log.ref_rate is not None   # a record's: the gyro lay still
    measured = log.rate_dps - log.ref_rate
    t_span = log.t[span]
    segments = block_segments(t_span)
    errors, field, heading_rms, allan = {}, {}, {}, {}
    for stage in STAGES:
        comp = models[stage].error(signals)
        predicted = measured - comp
        errors[stage, 'predicted'] = predicted[span]
        for way, window in windows.items():
            bias = static_bias(measured[window], comp[window], MAX_MEAN_DPS, MAX_STD_DPS)
            errors[stage, way] = bias.correct(measured[span], comp[span])
        errors[stage, 'mean_removed'] = predicted[span] - np.mean(predicted[span])
        for way in WAYS:
            field[stage, way] = field_errors(t_span, errors[stage, way], segments, 0)
            heading_rms[stage, way] = rolling_heading_rms(t_span, errors[stage, way], SECONDS_PER_HOUR)
        allan[stage] = allan_deviation(errors[stage, 'mean_removed'], sample_rate_hz(log),
                                       segment_labels(t_span, RUN_GAP_S))
    return Fold(axis, day, held_name, log, held, loop, agreements, models, signals, windows, span, errors, field,
                heading_rms, allan, restart_dropped)


def rolling_heading_rms(t: NDArray[np.float64], error: NDArray[np.float64], horizon_s: float,
                        every_s: float = BLOCK_S) -> float:
    """Rms of the heading error over ``horizon_s`` missions starting every ``every_s`` (deg).

    One mission's heading is a single draw of the white noise; over the day's missions
    the systematic part shows.
    """
    offsets = np.arange(0.0, t[-1] - t[0] - horizon_s, every_s)
    if not offsets.size:
        return float('nan')
    heading = heading_error_deg(t, error, 0, np.concatenate([offsets, offsets + horizon_s]))
    missions = heading[len(offsets):] - heading[:len(offsets)]
    return float(np.sqrt(np.mean(missions ** 2)))
