"""Field replay: a calibration applied to another run of the same gyro exactly as the node applies it.

A calibration is good when it makes *another* run better, started in any state: the
node takes its static bias over the run's first ``bias_samples`` rows (refused if the
gyro moved), starts its causal signals at the run's first sample, and corrects every
sample after, as told how the run started (:class:`compensation.RunStart`: a warm-up
applies only after a power-on at the start). :func:`replay` does that through the node's
own batch path (:func:`compensation.apply_calibration`) and measures the output against
the table with :func:`metrics.field_errors`: bias included, nothing removed.

:func:`validate` replays the report's calibration (the ART polynomial alone) and the
extended one on each validation run, and drops from the extended calibration every
term without which the runs are better (refitting the rest on the fitted log).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.analysis.loop import LoopResult
from art_gyro_calibration.analysis.metrics import DEFAULT_SETTLE_S, FieldErrors, field_errors, steady_segments
from art_gyro_calibration.calibration import Calibration
from art_gyro_calibration.compensation import Applied, RunStart, apply_calibration
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.static_bias import DEFAULT_MAX_MEAN_DPS, DEFAULT_SAMPLES
from art_gyro_calibration.terms import Term


@dataclass(frozen=True)
class Replay:
    """One calibration on one run: the node's output, its error against the table (per kept row), field errors."""

    applied: Applied
    error_dps: NDArray[np.float64]
    field: FieldErrors


def replay(log: GyroLog, calibration: Calibration, bias_samples: int = DEFAULT_SAMPLES,
           settle_s: float = DEFAULT_SETTLE_S, start: RunStart = RunStart(),
           max_mean_dps: float = DEFAULT_MAX_MEAN_DPS) -> Replay:
    """Apply ``calibration`` to ``log`` as the node does and measure it from the end of the static bias.

    ``start``: how the run began, as the node is told (a warm-up applies only from a declared
    power-on). The rows the node would drop (:func:`compensation.plausible`) are left out.
    Raises :class:`static_bias.MotionError` when the run's first ``bias_samples`` rows show motion.
    """
    if log.ref_rate is None:
        raise LogError('the log has no ref_rate column: a replay measures against the rate table\'s true rate')
    applied = apply_calibration(log, calibration, bias_samples, max_mean_dps, start=start)
    seen = log if applied.kept.all() else log.slice(applied.kept)
    error = applied.corrected_dps - seen.ref_rate
    return Replay(applied, error, field_errors(seen.t, error, steady_segments(seen.t, seen.ref_rate, settle_s),
                                               bias_samples))


def restart(log: GyroLog, start_s: float) -> GyroLog:
    """The run as a node started ``start_s`` after its first sample sees it (a warm restart)."""
    if not 0.0 <= start_s < log.t[-1] - log.t[0]:
        raise ValueError(f'start {start_s} s is not within the log\'s {log.t[-1] - log.t[0]:.1f} s')
    return log.slice(slice(int(np.searchsorted(log.t, log.t[0] + start_s)), None))


def without_terms(calibration: Calibration) -> Calibration:
    """The report's calibration: the same polynomial and scale factors, no extended terms."""
    return replace(calibration, terms=())


@dataclass(frozen=True)
class Dropped:
    """A term dropped because the validation runs were better without it."""

    term: Term
    reason: str


@dataclass(frozen=True)
class Validation:
    """Field errors per validation run and calibration, and the calibration to write."""

    calibration: Calibration
    runs: tuple[dict[str, FieldErrors], ...]
    dropped: tuple[Dropped, ...]


def field_score_dps(errors: Sequence[FieldErrors]) -> float:
    """One number to compare calibrations on the validation runs: rms of their systematic rms (bias included)."""
    return float(np.sqrt(np.mean([e.systematic_rms_dps ** 2 for e in errors])))


def validate(result: LoopResult, logs: Sequence[GyroLog], bias_samples: int = DEFAULT_SAMPLES,
             settle_s: float = DEFAULT_SETTLE_S, start: RunStart = RunStart()) -> Validation:
    """Replay ``result``'s calibrations on ``logs``; drop each term the runs are better without.

    Terms are dropped one at a time, the one whose removal helps most first; the rest are
    refitted jointly with the polynomial on the fitted log (the loop's signals, error and
    steady rows) before the next comparison. Calibrations per run: ``art``, ``extended``
    and, when terms were dropped, ``validated`` (the one to write). ``start``: how the runs started.
    """
    if not logs:
        raise ValueError('validation needs at least one run')

    def field(calibration: Calibration) -> list[FieldErrors]:
        return [replay(log, calibration, bias_samples, settle_s, start).field for log in logs]

    art, extended = field(result.art), field(result.extended)
    current, current_errors = result.extended, extended
    dropped: list[Dropped] = []
    while current.terms:
        options = [_refit(result, current.terms[:i] + current.terms[i + 1:]) for i in range(len(current.terms))]
        scores = [field_score_dps(field(c)) for c in options]
        best = int(np.argmin(scores))
        score = field_score_dps(current_errors)
        if scores[best] >= score:
            break
        term = current.terms[best]
        dropped.append(Dropped(term, f'the validation runs are better without it: systematic rms with the bias '
                                     f'{score * 3600.0:.2f} deg/h with it, {scores[best] * 3600.0:.2f} deg/h without'))
        current = options[best]
        current_errors = field(current)
    runs: list[dict[str, FieldErrors]] = []
    for i in range(len(logs)):
        run = {'art': art[i], 'extended': extended[i]}
        if dropped:
            run['validated'] = current_errors[i]
        runs.append(run)
    return Validation(current, tuple(runs), tuple(dropped))


def _refit(result: LoopResult, terms: Sequence[Term]) -> Calibration:
    """The polynomial and ``terms``' shapes refitted jointly on the loop's log."""
    # A term's shape is its fields less the coefficients: whatever a TermSpec holds.
    specs = [TermSpec(**{f.name: getattr(t, f.name) for f in fields(TermSpec)}) for t in terms]
    polynomial = result.art.polynomial
    fit = fit_model(result.signals, result.error, polynomial.rows, polynomial.columns, specs, result.segments.rows())
    return replace(result.art, polynomial=fit.model.polynomial, terms=fit.model.terms)
