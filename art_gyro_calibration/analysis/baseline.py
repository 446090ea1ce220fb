"""Never worse than the calibration the gyro has: the refit judged against it, both as the node applies them.

A refit is fitted on the log it is judged on; the gyro's current calibration (the baseline:
its packaged file, or one given) was not. So both are judged held out: the log's time is
cut into blocks (the loop's held-out block length), dealt round-robin into
:data:`FOLDS` folds, and the refit (polynomial and terms, the shapes the loop chose) is
fitted again without each fold (its terms as fitted). The node's runs on the log (a cold start at its first
row when the log began at power-on, warm restarts from :data:`replay.RESTART_FRACTIONS`
of it, each run until the next starts) are replayed with each fold's fit exactly as the
node applies it (static bias over the run's first rows, bias included); every row's
error is the one of the fit that did not see it. The baseline is replayed as it is.

The polynomial is what is judged, so both sides carry the loop's terms: the refit with
its own, the baseline with the same shapes fitted on top of it (and a constant beside
them; their time constants fitted again against it: :func:`retuned_on_baseline`), each
fitted again without each fold. A refit whose polynomial is not better than
the baseline with those terms by the loop's materiality is not written: the file keeps
the baseline polynomial, with the terms on top of it if, held out the same way, they make
the baseline better by the materiality (a term that stands in for another effect on a
short log can help a little on it and harm a second run). Judged against the bare
baseline instead, a refit would win by what its terms remove, and a polynomial fitted
over the log's few degrees would replace the report's where nothing showed it wrong.
A slow bias wander of a short log, or a polynomial order too low for the gyro, is what
makes a refit worse than the baseline. The refit's terms keep their fit on the whole log
(a warm-up lives in the first block alone).

Between the two stands the baseline with its bias column refitted (:func:`rebiased`): the
report's rate terms (scale factor, non-linearity: fixed by the unit's coil and
electronics) kept, its bias's temperature dependence (which moves as a fibre coil ages)
fitted again with the terms on top. Its few coefficients a log pins where the whole
polynomial's twelve follow the log's wander. The simpler file is written unless the
richer one is better held out by the materiality: the baseline (with or without the
terms), the rebiased baseline, the refit. One run cannot tell a bias slope in temperature
from a drift in time (its chamber moves with the clock); several runs, at other chamber
temperatures and each with its own turn-on bias, can. So a fit of several runs judges the
rebiased baseline once more where the blocks did not show it better (:class:`PairedCheck`):
its bias column alone (the terms on both sides), on contiguous parts of each run, every
start to its run's end, the two files paired segment by segment.

Where the robot will run (the operating range: by default the logged temperatures) decides
where else it is judged. Held out on the log, the refit is judged only at the log's
temperatures. Beyond them a polynomial fitted over a narrow span can be far off, so the
written refit holds its value at the log's edge (its ``temperature_range_c``) and is
continued from there by the baseline's temperature dependence (:func:`continued`): the
correction the log measured at its edge, carried on the way the baseline, calibrated on a
rate table over the whole chamber range, says the error moves. Held at the edge instead, a
refit loses beyond it all the baseline moves there, and can be worse than a stale baseline.
The bias-refitted baseline is clamped and continued the same way. Beyond the log nothing
was measured, so nothing there is judged: over the operating range's part where the
baseline was calibrated (its ``temperature_range_c``) the report says how far the written
file and the baseline differ (:func:`beyond_log`), and over the rest (a
``temperature_warn_range_c`` is an assumption, not a calibration) how far they disagree
(:func:`unknown_beyond_log`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis import trace
from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.analysis.loop import LoopResult, retuned
from art_gyro_calibration.analysis.metrics import DEFAULT_SETTLE_S, FieldErrors, field_errors, steady_segments
from art_gyro_calibration.analysis.replay import RESTART_FRACTIONS, field_score_dps, own_restarts, replay_anyway
from art_gyro_calibration.analysis.runs import Run as LoggedRun
from art_gyro_calibration.analysis.runs import run_of_rows
from art_gyro_calibration.calibration import PLAUSIBLE_TEMPERATURE_C, Calibration, CalibrationError
from art_gyro_calibration.compensation import RunStart, run_signals
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ArtPolynomial, Continuation, ErrorModel
from art_gyro_calibration.signals import SignalFilters, Signals
from art_gyro_calibration.static_bias import DEFAULT_SAMPLES
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS

# Folds of held-out blocks: each fit sees three quarters of the log.
FOLDS = 4
# Verdicts.
REFIT, BASELINE, REBIASED = 'refit', 'baseline', 'baseline_bias_refitted'
# Temperature step (degC) of the grid on which the written file is compared with the baseline beyond the log.
BEYOND_STEP_C = 0.5
# The t its fall must reach over a several-run fit's (run, quarter) units for the bias-refitted baseline to be
# written by the paired judge (:class:`PairedCheck`).
PAIRED_T = 2.0


Span = tuple[float, float]


@dataclass(frozen=True)
class BeyondLog:
    """The file written against the baseline where the robot runs, the baseline is calibrated and the log is not.

    ``differ_dph``: the most the two differ there over the logged table rates and
    ``judged_c`` (the operating range beyond the log, within the baseline's calibrated
    range; deg/h), at ``at_temperature_c`` and ``at_rate_dps``. Continued by the baseline,
    the file differs from it there by the correction the log measured at its edge.
    """

    log_range_c: Span
    baseline_range_c: Span
    judged_c: tuple[Span, ...]
    differ_dph: float
    at_temperature_c: float
    at_rate_dps: float

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's ``baseline.beyond_log``."""
        return {'log_range_c': list(self.log_range_c), 'baseline_range_c': list(self.baseline_range_c),
                'judged_c': [list(span) for span in self.judged_c], 'differ_dph': self.differ_dph,
                'at_temperature_c': self.at_temperature_c, 'at_rate_dps': self.at_rate_dps}

    def describe(self) -> str:
        """One clause for the verdict's message."""
        (low, high), (b_low, b_high) = self.log_range_c, self.baseline_range_c
        return (f'the log covers {low:g}..{high:g} degC; beyond it over {_spans(self.judged_c)} degC of the '
                f'operating range, where the baseline is calibrated ({b_low:g}..{b_high:g} degC), the written file '
                f'differs from the baseline by up to {self.differ_dph:.2f} deg/h (at {self.at_temperature_c:g} degC '
                f'and {self.at_rate_dps:g} deg/s), the correction the log measured at its edge')


@dataclass(frozen=True)
class UnknownBeyondLog:
    """The operating range that no log covers and the baseline was never calibrated over: nothing measured there.

    There both are applied as the node applies them (the file as written, the baseline held
    at its calibrated range's edge, or its polynomial as it is when it has none); neither is
    known to hold. ``disagree_dph``: the most the two differ over the logged
    table rates and ``ranges_c`` (deg/h), at ``at_temperature_c`` and ``at_rate_dps``: what a
    run there would have to settle, not a verdict.
    """

    log_range_c: Span
    baseline_range_c: Span | None
    ranges_c: tuple[Span, ...]
    disagree_dph: float
    at_temperature_c: float
    at_rate_dps: float

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's ``baseline.unknown_beyond_log``."""
        return {'log_range_c': list(self.log_range_c),
                'baseline_range_c': None if self.baseline_range_c is None else list(self.baseline_range_c),
                'ranges_c': [list(span) for span in self.ranges_c], 'disagree_dph': self.disagree_dph,
                'at_temperature_c': self.at_temperature_c, 'at_rate_dps': self.at_rate_dps,
                'message': self.describe()}

    def describe(self) -> str:
        """What is unknown, in one sentence."""
        calibrated = ('it has no calibrated temperature_range_c' if self.baseline_range_c is None else
                      'it was calibrated over {:g}..{:g} degC'.format(*self.baseline_range_c))
        return (f'no log covers {_spans(self.ranges_c)} degC of the operating range and the baseline was never '
                f'calibrated there ({calibrated}), so neither is judged there; the file written and '
                f'the baseline differ there by up to {self.disagree_dph:.2f} deg/h (at {self.at_temperature_c:g} degC '
                f'and {self.at_rate_dps:g} deg/s), which only a log over it can settle')


def _spans(spans: Sequence[Span]) -> str:
    """``10..14 and 50..54``."""
    return ' and '.join(f'{low:g}..{high:g}' for low, high in spans)


@dataclass(frozen=True)
class Run:
    """One run of the node on the fitted log: its name, rows [start, stop) and how it started."""

    name: str
    start: int
    stop: int
    run_start: RunStart


@dataclass(frozen=True)
class PairedCheck:
    r"""The baseline's bias column refitted against its own, the same terms on top of both, on a several-run fit.

    Each run of the fit is cut into :data:`FOLDS` contiguous quarters, each fitted without, and
    each start of the node replayed to its run's end; both files' errors are paired by steady
    segment (after the static bias). Over the runs :math:`r` and their segments :math:`i`,
    with :math:`a` the bias-refitted file's segment mean error and :math:`b` the baseline's (deg/h):

    .. math::

        d = \sqrt{\langle \langle (b_{ri} - a_{ri})^2 \rangle_i \rangle_r}, \qquad
        F = \langle \langle b_{ri}^2 - a_{ri}^2 \rangle_i \rangle_r, \qquad
        t = \bar F_u \big/ (s_{F_u} / \sqrt{n_u})

    with :math:`F_u` the fall over the segments of one (run, quarter) unit. Written when the two
    differ by more than the materiality of what the loop's model leaves (:math:`d > m`), the
    change removes at least half its own square (:math:`F \ge d^2 / 2`: it is mostly a
    correction, not a difference) and the fall holds over the units (:math:`t \ge`
    :data:`PAIRED_T`). Round-robin blocks an hour apart share a log's slow wander; a quarter
    held out asks the fit, as a mission does, to carry the bias's temperature dependence to
    hours it did not see, and the other runs, at other chamber temperatures and with their own
    turn-on bias, tell that dependence from the time since power-on, which one run cannot.
    """

    differ_dph: float
    fall_dph2: float
    t: float
    units: int
    materiality_dph: float

    @property
    def passed(self) -> bool:
        """The bias-refitted baseline is written."""
        return (self.differ_dph > self.materiality_dph and self.fall_dph2 >= 0.5 * self.differ_dph ** 2
                and self.t >= PAIRED_T)

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's ``baseline.bias_refitted_on_runs``."""
        return {'differ_dph': self.differ_dph, 'fall_dph2': self.fall_dph2, 't': self.t, 'units': self.units,
                'materiality_dph': self.materiality_dph, 'min_t': PAIRED_T, 'passed': self.passed}

    def describe(self) -> str:
        """One clause for the verdict's message."""
        return (f'judged on the runs (each cut into {FOLDS} contiguous parts, each fitted without; every start '
                f'replayed to its run\'s end; the same terms on both sides), the bias column refitted differs from '
                f'the baseline\'s by {self.differ_dph:.2f} deg/h (materiality {self.materiality_dph:.2f}), lowers '
                f'the steady segments\' mean square by {self.fall_dph2:.2f} (deg/h)^2 '
                f'({0.5 * self.differ_dph ** 2:.2f} wanted), t = {self.t:.1f} over {self.units} run parts '
                f'({PAIRED_T:g} wanted)')


@dataclass(frozen=True)
class BaselineCheck:
    """The refit against the baseline on the log's held-out blocks and runs, and what is written.

    Scores are :func:`replay.field_score_dps` in deg/h (rms over the runs of the systematic rms
    with the bias); ``on_top_dph`` is the baseline polynomial with the loop's terms fitted on
    top (None without terms). ``verdict``: :data:`REFIT` or :data:`BASELINE`.
    """

    source: str
    refit_dph: float
    baseline_dph: float
    on_top_dph: float | None
    materiality_dph: float
    verdict: str
    runs: tuple[tuple[Run, FieldErrors, FieldErrors], ...]
    calibration: Calibration
    message: str
    beyond: BeyondLog | None = None
    operating_c: Span | None = None
    unknown: UnknownBeyondLog | None = None
    rebiased_dph: float | None = None
    rebiased_on_runs: PairedCheck | None = None

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's ``baseline``."""
        def finite(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else x
        return {
            'source': self.source,
            'refit_field_dph': finite(self.refit_dph),
            'baseline_field_dph': finite(self.baseline_dph),
            'baseline_with_terms_field_dph': finite(self.on_top_dph),
            'baseline_bias_refitted_field_dph': finite(self.rebiased_dph),
            'materiality_dph': self.materiality_dph,
            'verdict': self.verdict,
            'written_polynomial': self.verdict,
            'written_terms': [t.signal for t in self.calibration.terms],
            'message': self.message,
            'operating_range_c': None if self.operating_c is None else list(self.operating_c),
            'beyond_log': None if self.beyond is None else self.beyond.to_dict(),
            'unknown_beyond_log': None if self.unknown is None else self.unknown.to_dict(),
            'bias_refitted_on_runs': None if self.rebiased_on_runs is None else self.rebiased_on_runs.to_dict(),
            'runs': [{'run': run.name, 'refit': refit.to_dict(), 'baseline': base.to_dict()}
                     for run, refit, base in self.runs],
        }


def operating_range(low: float, high: float) -> Span:
    """``--operating-range LO HI`` checked: finite degC the node takes, LO < HI."""
    p_low, p_high = PLAUSIBLE_TEMPERATURE_C
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f'--operating-range {low:g} {high:g}: both ends must be finite temperatures (degC)')
    if not low < high:
        raise ValueError(f'--operating-range {low:g} {high:g}: give LO < HI (degC)')
    if not (p_low <= low and high <= p_high):
        raise ValueError(f'--operating-range {low:g} {high:g}: outside the plausible {p_low:g}..{p_high:g} degC '
                         '(the node drops frames beyond it)')
    return low, high


def _outside(span: Span, cut: Span | None) -> list[Span]:
    """The parts of ``span`` outside ``cut`` (all of it without a ``cut``)."""
    if cut is None:
        return [span]
    (low, high), (c_low, c_high) = span, cut
    return [(a, b) for a, b in ((low, min(high, c_low)), (max(low, c_high), high)) if a < b]


def _grid(spans: Sequence[Span], rates_dps: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Temperatures every :data:`BEYOND_STEP_C` over ``spans`` (ends included) by ``rates_dps`` and rest."""
    temps = np.concatenate([np.linspace(a, b, max(int(np.ceil((b - a) / BEYOND_STEP_C)), 1) + 1) for a, b in spans])
    temp, rate = np.meshgrid(temps, np.union1d(rates_dps, [0.0]), indexing='ij')
    return temp, rate


def continued(refit: Calibration, baseline: Calibration, source: str) -> Calibration:
    """``refit``, clamped to the log's temperatures, continued beyond them by ``baseline``'s polynomial.

    A refit with no clamp, or a baseline whose polynomial does not move with temperature, is returned as it is.
    """
    if refit.temperature_range_c is None or baseline.polynomial.rows < 2:
        return refit
    return replace(refit, continuation=Continuation(baseline.polynomial, baseline.temperature_range_c, source))


def beyond_log(written: Calibration, baseline: Calibration, rates_dps: NDArray[np.float64],
               operating_c: Span) -> BeyondLog | None:
    """The file written against the baseline beyond the log's temperatures, at ``rates_dps`` and at rest.

    Compared over ``operating_c`` beyond the log, where the baseline is calibrated (its
    ``temperature_range_c``). None where there is no such place: the file is not clamped,
    the baseline was calibrated nowhere, or the log covers the operating range there.
    """
    log_range, baseline_range = written.temperature_range_c, baseline.temperature_range_c
    if log_range is None or baseline_range is None:
        return None
    span = (max(operating_c[0], baseline_range[0]), min(operating_c[1], baseline_range[1]))
    judged = _outside(span, log_range) if span[0] < span[1] else []
    if not judged:
        return None
    temp, rate = _grid(judged, rates_dps)
    differ = np.abs(written.model.polynomial_error(rate, temp)
                    - baseline.model.polynomial_error(rate, temp)) * DEG_PER_H_PER_DPS
    i = np.unravel_index(int(np.argmax(differ)), differ.shape)
    return BeyondLog(log_range, baseline_range, tuple(judged), float(differ[i]), float(temp[i]), float(rate[i]))


def unknown_beyond_log(written: Calibration, baseline: Calibration, rates_dps: NDArray[np.float64],
                       operating_c: Span) -> UnknownBeyondLog | None:
    """How far the file written and the baseline, as the node applies them, disagree where nothing was measured.

    That is ``operating_c`` beyond both the log and the baseline's calibrated range. None where
    there is no such place, or the file is not clamped to a log's range.
    """
    log_range, baseline_range = written.temperature_range_c, baseline.temperature_range_c
    if log_range is None:
        return None
    unknown = [part for beyond in _outside(operating_c, log_range) for part in _outside(beyond, baseline_range)]
    if not unknown:
        return None
    temp, rate = _grid(unknown, rates_dps)
    disagree = np.abs(written.model.polynomial_error(rate, temp)
                      - baseline.model.polynomial_error(rate, temp)) * DEG_PER_H_PER_DPS
    i = np.unravel_index(int(np.argmax(disagree)), disagree.shape)
    return UnknownBeyondLog(log_range, baseline_range, tuple(unknown), float(disagree[i]), float(temp[i]),
                            float(rate[i]))


def _unasked(written: Calibration, baseline: Calibration, operating_c: Span | None,
             operating: Span | None) -> str:
    """A clause for a refit written where no operating range was given and the baseline was calibrated wider.

    How far the written file and the baseline differ over the rest of the baseline's calibrated
    range is said only when the robot is said to run there.
    """
    calibrated = baseline.temperature_range_c
    if operating_c is not None or operating is None or calibrated is None or not _outside(calibrated, operating):
        return ''
    return (f', beyond the log {written.beyond_range}; the baseline was calibrated over {calibrated[0]:g}..'
            f'{calibrated[1]:g} degC: give --operating-range if the robot runs beyond the log, to see how far the '
            'two differ there')


def check_baseline(baseline: Calibration, source: str, log_rate_scale: float, log_temp_scale: float) -> None:
    """Refuse a baseline that reads the log's counts with other scale factors than the fit (names the file)."""
    if (baseline.rate_scale_factor, baseline.temp_scale_factor) != (log_rate_scale, log_temp_scale):
        raise CalibrationError(
            f'{source}: baseline rate_scale_factor {baseline.rate_scale_factor:g} and temp_scale_factor '
            f'{baseline.temp_scale_factor:g} differ from the fit\'s {log_rate_scale:g} and {log_temp_scale:g}: '
            'a baseline must read the log as the fit does (give --rate-scale-factor or another --baseline)')


def node_runs(log: GyroLog, result: LoopResult, bias_samples: int = DEFAULT_SAMPLES,
              fractions: Sequence[float] = RESTART_FRACTIONS) -> list[Run]:
    """The node's runs on the fitted log: its start (if the table rests there) and warm restarts, end to end.

    A fit of several runs (``result.runs``): each run's own, none across two.
    """
    if len(result.runs) > 1:
        return [replace(run, name=f'{part.name}: {run.name}', start=part.first_row + run.start,
                        stop=part.first_row + run.stop)
                for part in result.runs
                for run in node_runs(log.slice(slice(part.first_row, part.stop)),
                                     replace(result, runs=(), start=RunStart(part.powered_on_at_start)),
                                     bias_samples, fractions)]
    assert log.ref_rate is not None
    starts: list[tuple[str, int, RunStart]] = []
    if bias_samples <= len(log) and not np.any(log.ref_rate[:bias_samples]):
        cold = result.start.powered_on_at_start
        starts.append(('from the log\'s start' + (' (power-on)' if cold else ''), 0, result.start))
    for start_s, _ in own_restarts(log, bias_samples, fractions):
        row = int(np.searchsorted(log.t, log.t[0] + start_s))
        if not starts or row > starts[-1][1] + bias_samples:
            starts.append((f'restarted at {start_s / 60.0:.0f} min', row, RunStart()))
    stops = [s[1] for s in starts[1:]] + [len(log)]
    return [Run(name, a, b, run_start) for (name, a, run_start), b in zip(starts, stops)
            if b - a > 2 * bias_samples]


def folds_of(t: NDArray[np.float64], block_s: float, folds: int = FOLDS) -> NDArray[np.int64]:
    """Each row's fold: blocks of ``block_s`` dealt round-robin (fewer folds when the log has fewer blocks)."""
    block = np.floor((t - t[0]) / max(block_s, 1e-9)).astype(np.int64)
    return np.asarray(block % max(min(folds, int(block[-1]) + 1), 1), dtype=np.int64)


def _specs(terms: Sequence[Term]) -> list[TermSpec]:
    """The shapes of ``terms`` (their fields less the coefficients)."""
    return [TermSpec(**{f.name: getattr(t, f.name) for f in fields(TermSpec)}) for t in terms]


def _refit(result: LoopResult, written: Calibration, terms_error: NDArray[np.float64],
           train: NDArray[np.int64]) -> Calibration:
    """``written`` with its polynomial fitted again on the rows ``train``, its terms as they are.

    The terms keep their fit on the whole log: a warm-up lives in the first block alone, and
    a fit without that block could not know it; the polynomial is what is judged.
    """
    p = written.polynomial
    fit = fit_model(result.signals, result.error - terms_error, p.rows, p.columns, (), train)
    return replace(written, polynomial=fit.model.polynomial)


def retuned_on_baseline(result: LoopResult, base_error: NDArray[np.float64],
                        specs: Sequence[TermSpec]) -> list[TermSpec]:
    """``specs`` with their time constants (a warm-up's, a lag's) fitted again on top of the baseline polynomial.

    The loop tuned them beside its own polynomial, whose share of a slow effect moved them (a warm-up and the
    self-heating's temperature rate decay together after power-on). Held there, an amplitude fitted on top of the
    baseline trades for the time constant and misses the term's value at power-on, which the node's static bias
    then carries for the whole mission.
    """
    if not any(s.time_constant_s > 0.0 for s in specs):
        return list(specs)
    return retuned(trace.Binned(result.signals, result.error - base_error, result.segments, 1, 1), list(specs))


def _on_top(result: LoopResult, baseline: Calibration, base_error: NDArray[np.float64],
            specs: Sequence[TermSpec], train: NDArray[np.int64]) -> Calibration:
    """The baseline polynomial with ``specs`` fitted on top of it on the rows ``train`` (a constant beside them).

    The constant is not written: the static bias takes any constant out.
    """
    fit = fit_model(result.signals, result.error - base_error, 1, 1, specs, train)
    return replace(baseline, terms=fit.model.terms, filters=result.art.filters)


def rebiased(result: LoopResult, baseline: Calibration, base_error: NDArray[np.float64],
             specs: Sequence[TermSpec], train: NDArray[np.int64], log_range_c: Span | None,
             source: str) -> Calibration:
    """The baseline with its bias column (rate**0) fitted again on the rows ``train``, and ``specs`` on top of it.

    Like a refit, clamped to the log's temperatures (``log_range_c``) and continued beyond them by the baseline.
    """
    p = baseline.polynomial
    fit = fit_model(result.signals, result.error - base_error, p.rows, 1, specs, train)
    coefficients = p.coefficients.copy()
    coefficients[:, -1] += fit.model.polynomial.coefficients[:, 0]
    calibration = replace(baseline, polynomial=ArtPolynomial(coefficients), terms=fit.model.terms,
                          filters=result.art.filters)
    if log_range_c is None:
        return calibration
    return continued(replace(calibration, temperature_range_c=log_range_c, temperature_warn_range_c=None,
                             continuation=None), baseline, source)


def _replay_run(log: GyroLog, calibration: Calibration, bias_samples: int, settle_s: float,
                start: RunStart, signals: Signals) -> tuple[NDArray[np.float64], NDArray[np.bool_], bool]:
    """Per-row error (NaN where the node drops the row), kept rows and whether the node refused the static bias."""
    r, refused = replay_anyway(log, calibration, bias_samples, settle_s, start, signals=signals)
    error = np.full(len(log), np.nan)
    error[r.applied.kept] = r.error_dps
    return error, r.applied.kept, refused


def _field(log: GyroLog, error: NDArray[np.float64], kept: NDArray[np.bool_], bias_samples: int,
           settle_s: float, refused: bool) -> FieldErrors:
    """Field errors of one run's per-row error (the node's kept rows)."""
    seen = log if kept.all() else log.slice(kept)
    assert seen.ref_rate is not None
    out = field_errors(seen.t, error[kept], steady_segments(seen.t, seen.ref_rate, settle_s), bias_samples)
    return replace(out, bias_refused=refused)


def _run_error(part: GyroLog, run: Run, fold: NDArray[np.int64], calibrations: Sequence[Calibration],
               bias_samples: int, settle_s: float, shared: dict[SignalFilters, Signals]
               ) -> tuple[NDArray[np.float64], NDArray[np.bool_], bool]:
    """``run``'s per-row error (its rows ``part``), each row's of ``calibrations[fold of the row]``; kept, refused.

    ``shared``: the run's signals per filter set, made once for every calibration replayed on it.
    """
    error = np.full(len(part), np.nan)
    kept = np.ones(len(part), dtype=bool)
    refused = False
    for k, calibration in enumerate(calibrations):
        mine = fold[run.start:run.stop] == k if len(calibrations) > 1 else np.ones(len(part), dtype=bool)
        if not mine.any():
            continue
        if calibration.filters not in shared:
            shared[calibration.filters] = run_signals(part, calibration.filters, run.run_start)
        e, kept, was_refused = _replay_run(part, calibration, bias_samples, settle_s, run.run_start,
                                           shared[calibration.filters])
        error[mine] = e[mine]
        refused = refused or was_refused
    return error, kept, refused


def held_out(log: GyroLog, runs: Sequence[Run], fold: NDArray[np.int64], calibrations: Sequence[Calibration],
             bias_samples: int, settle_s: float) -> list[FieldErrors]:
    """Field errors per run where each row's error is that of ``calibrations[fold of the row]``."""
    out = []
    for run in runs:
        part = log.slice(slice(run.start, run.stop))
        error, kept, refused = _run_error(part, run, fold, calibrations, bias_samples, settle_s, {})
        out.append(_field(part, error, kept, bias_samples, settle_s, refused))
    return out


def run_quarters(t: NDArray[np.float64], runs: Sequence[LoggedRun], folds: int = FOLDS) -> NDArray[np.int64]:
    """Each row's fold: its run's time cut into ``folds`` contiguous parts."""
    fold = np.zeros(len(t), dtype=np.int64)
    for run in runs:
        tt = t[run.first_row:run.stop]
        span = max(float(tt[-1] - tt[0]), 1e-9)
        fold[run.first_row:run.stop] = np.minimum(np.floor(folds * (tt - tt[0]) / span), folds - 1)
    return fold


def _segment_errors(log: GyroLog, runs: Sequence[Run], fold: NDArray[np.int64],
                    rich: Sequence[Calibration], simple: Sequence[Calibration], bias_samples: int,
                    settle_s: float) -> list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]]:
    """Per run: ``rich``'s and ``simple``'s mean errors (deg/h) over its steady segments after the static bias, folds.

    A segment where the node dropped a row is NaN.
    """
    out = []
    for run in runs:
        shared: dict[SignalFilters, Signals] = {}
        part = log.slice(slice(run.start, run.stop))
        a = _run_error(part, run, fold, rich, bias_samples, settle_s, shared)[0]
        b = _run_error(part, run, fold, simple, bias_samples, settle_s, shared)[0]
        assert part.ref_rate is not None
        later = steady_segments(part.t, part.ref_rate, settle_s).after(bias_samples)
        out.append((later.means(a) * DEG_PER_H_PER_DPS, later.means(b) * DEG_PER_H_PER_DPS,
                    fold[run.start + later.starts]))
    return out


def paired_check(segments: Sequence[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]],
                 materiality_dph: float) -> PairedCheck:
    """:class:`PairedCheck` of :func:`_segment_errors`' output (segments NaN in either left out)."""
    squares, falls, unit_falls = [], [], []
    for rich, simple, fold in segments:
        ok = np.isfinite(rich) & np.isfinite(simple)
        if not ok.any():
            continue
        a, b, k = rich[ok], simple[ok], fold[ok]
        fall = b ** 2 - a ** 2
        squares.append(float(np.mean((b - a) ** 2)))
        falls.append(float(np.mean(fall)))
        unit_falls += [float(np.mean(fall[k == q])) for q in np.unique(k)]
    units = np.asarray(unit_falls)
    spread = float(units.std(ddof=1)) if len(units) > 1 else 0.0
    t = float(units.mean()) / (spread / math.sqrt(len(units))) if spread > 0.0 else 0.0
    return PairedCheck(math.sqrt(float(np.mean(squares))) if squares else 0.0,
                       float(np.mean(falls)) if falls else 0.0, t, len(units), materiality_dph)


def rebiased_on_runs(log: GyroLog, result: LoopResult, runs: Sequence[Run], baseline: Calibration,
                     base_error: NDArray[np.float64], specs: Sequence[TermSpec], log_range_c: Span | None,
                     source: str, bias_samples: int, settle_s: float) -> PairedCheck:
    """``baseline`` with its bias column refitted against it on a several-run fit's runs: :class:`PairedCheck`.

    ``specs`` are fitted on top of both (``baseline``'s own terms dropped), so that the bias column alone is
    judged. ``runs``: the node's runs on the log (each until the next start); here each goes on to its run's end.
    """
    quarter = run_quarters(log.t, result.runs)
    index = result.segments.rows()
    trains = [index[quarter[index] != k] for k in range(FOLDS)]
    stops = [result.runs[k].stop for k in run_of_rows(result.runs, np.array([run.start for run in runs]))]
    to_end = [replace(run, stop=stop) for run, stop in zip(runs, stops)]
    rich = [rebiased(result, baseline, base_error, specs, train, log_range_c, source) for train in trains]
    simple = [_on_top(result, baseline, base_error, specs, train) for train in trains] if specs \
        else [replace(baseline, terms=(), filters=result.art.filters)]
    return paired_check(_segment_errors(log, to_end, quarter, rich, simple, bias_samples, settle_s),
                        result.residual_materiality_dph or result.materiality_dph)


class BaselineComparisonError(ValueError):
    """The refit cannot be judged against the baseline: neither is chosen (nothing is written)."""


def _check_comparable(source: str, refit_dph: float, baseline_dph: float,
                      pairs: Sequence[tuple[Run, FieldErrors, FieldErrors]]) -> None:
    """Refuse scores no verdict can rest on: one not a number, or both infinite (both refused a static bias).

    A comparison with NaN is false whichever way it is asked, so it would keep whichever side the code
    falls back to, however wrong: the reason is said instead.
    """
    scores = (refit_dph, baseline_dph)
    if not any(math.isnan(x) for x in scores) and not (math.isinf(refit_dph) and math.isinf(baseline_dph)):
        return
    runs = '; '.join(f'{run.name}: refit {refit.systematic_rms_dps * DEG_PER_H_PER_DPS:.4g}, baseline '
                     f'{base.systematic_rms_dps * DEG_PER_H_PER_DPS:.4g} deg/h'
                     + (' (static bias refused)' if refit.bias_refused or base.bias_refused else '')
                     for run, refit, base in pairs)
    why = ('the node would refuse the static bias with either' if math.isinf(refit_dph) and math.isinf(baseline_dph)
           else 'a score is not a number')
    raise BaselineComparisonError(
        f'the refit cannot be judged against the baseline {source} ({refit_dph:.4g} against {baseline_dph:.4g} '
        f'deg/h held out: {why}; {runs}): nothing written; check the log (calibrate fit drops rows that are not '
        'finite) or give another --baseline')


def compare_with_baseline(log: GyroLog, result: LoopResult, written: Calibration, baseline: Calibration,
                          source: str, bias_samples: int = DEFAULT_SAMPLES, settle_s: float = DEFAULT_SETTLE_S,
                          operating_c: Span | None = None) -> BaselineCheck | None:
    """Judge ``written`` (the refit) against ``baseline`` held out on ``log`` and over ``operating_c``; decide.

    ``operating_c``: where the robot will run (default: the log's range, the refit's clamp).
    None when the log has no run the node could start (no rest of ``bias_samples`` rows) or
    fewer than two held-out blocks.
    """
    runs = node_runs(log, result, bias_samples)
    fold = folds_of(log.t, result.held_out_block_s)
    folds = int(fold.max()) + 1
    if not runs or folds < 2:
        return None
    index = result.segments.rows()
    trains = [index[fold[index] != k] for k in range(folds)]
    specs = _specs(written.terms)
    base_error = baseline.model.polynomial_error(result.signals.rate, result.signals.temperature)
    on_top = retuned_on_baseline(result, base_error, specs)
    no_polynomial = ArtPolynomial(np.zeros((1, 1)))
    terms_error = ErrorModel(no_polynomial, written.terms, written.temperature_range_c).error(result.signals)
    refits = [_refit(result, written, terms_error, train) for train in trains]
    refit_runs = held_out(log, runs, fold, refits, bias_samples, settle_s)
    base_runs = held_out(log, runs, fold, [baseline], bias_samples, settle_s)
    refit_dph = field_score_dps(refit_runs) * DEG_PER_H_PER_DPS
    baseline_dph = field_score_dps(base_runs) * DEG_PER_H_PER_DPS
    on_top_dph: float | None = None
    if specs:
        on_tops = [_on_top(result, baseline, base_error, on_top, train) for train in trains]
        on_top_dph = field_score_dps(held_out(log, runs, fold, on_tops, bias_samples, settle_s)) * DEG_PER_H_PER_DPS
    rebiased_dph: float | None = None
    if baseline.polynomial.rows > 1:   # a bias with no temperature dependence is all the static bias's
        rebiaseds = [rebiased(result, baseline, base_error, on_top, train, written.temperature_range_c, source)
                     for train in trains]
        rebiased_dph = field_score_dps(held_out(log, runs, fold, rebiaseds, bias_samples, settle_s)) \
            * DEG_PER_H_PER_DPS
    materiality = result.materiality_dph
    pairs = tuple(zip(runs, refit_runs, base_runs))
    operating = operating_c if operating_c is not None else written.temperature_range_c
    _check_comparable(source, refit_dph, baseline_dph, pairs)
    for what, score in ((f'with the terms {", ".join(s.signal for s in specs)} fitted on top of it', on_top_dph),
                        ('with its bias column refitted', rebiased_dph)):
        if score is not None and math.isnan(score):
            raise BaselineComparisonError(
                f'the refit cannot be judged against the baseline {source}: the baseline {what} scores {score:.4g} '
                'deg/h held out: nothing written; check the log (calibrate fit drops rows that are not finite) or '
                'give another --baseline')

    def check(verdict: str, calibration: Calibration, message: str) -> BaselineCheck:
        # Beyond the log: how far the file written and the baseline differ (nothing for the baseline itself).
        beyond = unknown = None
        if verdict != BASELINE:
            if operating is not None:
                beyond = beyond_log(calibration, baseline, result.segments.rate, operating)
                unknown = unknown_beyond_log(calibration, baseline, result.segments.rate, operating)
            message += _unasked(calibration, baseline, operating_c, operating) + \
                ('' if beyond is None else f'; {beyond.describe()}')
        return BaselineCheck(source, refit_dph, baseline_dph, on_top_dph, materiality, verdict, pairs, calibration,
                             message, beyond, operating, unknown, rebiased_dph, on_runs)

    # The baseline polynomial at its best: with the terms on top when they help it, its bias refitted when that helps.
    terms_help = on_top_dph is not None and on_top_dph + materiality < baseline_dph
    bar_dph = on_top_dph if terms_help and on_top_dph is not None else baseline_dph
    unchanged_dph = bar_dph
    with_terms = f' with the terms {", ".join(s.signal for s in specs)}' if specs else ''
    bar = f'the baseline {source}{with_terms} fitted on top of it' if terms_help else f'the baseline {source}'
    rebias_helps = rebiased_dph is not None and rebiased_dph + materiality < bar_dph
    if rebias_helps and rebiased_dph is not None:
        bar_dph, bar = rebiased_dph, f'the baseline {source} with its bias column refitted{with_terms}'
    on_runs: PairedCheck | None = None
    if refit_dph + materiality < bar_dph:
        return check(REFIT, continued(written, baseline, source),
                     f'the refit is better than {bar} held out on this log: {refit_dph:.2f} against {bar_dph:.2f} '
                     f'deg/h (materiality {materiality:.2f} deg/h); the refit is written')
    verdict = (f'the refit polynomial is not better than {bar} by the materiality held out on this log '
               f'({refit_dph:.2f} against {bar_dph:.2f} deg/h; materiality {materiality:.2f} deg/h)')
    dropped = f' (its own terms {", ".join(t.signal for t in baseline.terms)} are not kept)' if baseline.terms else ''
    rebias = (f'{verdict}: the written file keeps the baseline\'s rate terms{dropped} and refits its bias '
              f'column{with_terms}')
    if rebias_helps:
        return check(REBIASED, rebiased(result, baseline, base_error, on_top, index, written.temperature_range_c,
                                        source),
                     f'{rebias} ({bar_dph:.2f} against {unchanged_dph:.2f} deg/h with the bias unchanged, held out)')
    if rebiased_dph is not None and len(result.runs) > 1:
        # Several runs tell a bias slope in temperature from a drift in time: the paired judge on the runs' parts.
        on_runs = rebiased_on_runs(log, result, runs, baseline, base_error, on_top, written.temperature_range_c,
                                   source, bias_samples, settle_s)
        if on_runs.passed:
            return check(REBIASED, rebiased(result, baseline, base_error, on_top, index, written.temperature_range_c,
                                            source),
                         f'{rebias}: not better by the materiality held out on blocks ({rebiased_dph:.2f} against '
                         f'{bar_dph:.2f} deg/h), but {on_runs.describe()}')
    calibration = replace(baseline, terms=(), filters=written.filters)
    kept_terms = ''
    if specs:
        if terms_help:
            calibration = _on_top(result, baseline, base_error, on_top, index)
            kept_terms = f'; the terms {", ".join(s.signal for s in specs)} are fitted on top of it ' \
                         f'({on_top_dph:.2f} against {baseline_dph:.2f} deg/h without them, held out)'
        else:
            kept_terms = f'; the terms {", ".join(s.signal for s in specs)} fitted on top of it did not make it ' \
                         f'better by the materiality ({on_top_dph:.2f} against {baseline_dph:.2f} deg/h, held out) ' \
                         'and are not written'
    not_rebiased = '' if on_runs is None else \
        f'; its bias column refitted is not written: {on_runs.describe()}'
    return check(BASELINE, calibration,
                 f'{verdict}: the written file keeps the baseline polynomial{dropped}{kept_terms}{not_rebiased}')
