"""``calibrate fit`` as one pipeline: the loop, the start-up check, the validation runs, the report.

:func:`fit_log` reads a rate-table log (or several runs of the gyro, :mod:`.runs`), closes the
loop on it (:func:`loop.close_loop`), judges the terms found on every run's start and on warm
restarts of the runs themselves (:func:`replay.startup_check`; asked again without a term that check
dropped, :func:`_retraced`) and, when asked, on other runs of the gyro (:func:`replay.validate`), and returns all of it
in one :class:`FitResult`: the report, the calibration to write and the comment it is
written with. The command (:mod:`.cli`) parses its arguments into :class:`FitSettings`,
calls it, and writes and prints what it returns.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from art_gyro_calibration.calibration import (DEFAULT_RATE_SCALE_FACTOR, TEMP_SCALE_FACTOR, Calibration,
                                              CalibrationError, find_calibration_file, load_calibration,
                                              node_parameters_needed, unit_range_dps)
from art_gyro_calibration.compensation import RunStart, usable_rates
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.static_bias import DEFAULT_SAMPLES
from art_gyro_calibration.units import DEG_PER_H_PER_DPS
from art_gyro_calibration.analysis.bags import BagTopics, read_any_log
from art_gyro_calibration.analysis.baseline import REBIASED, REFIT, BaselineCheck, check_baseline, compare_with_baseline
from art_gyro_calibration.analysis.fit import check_coverage
from art_gyro_calibration.analysis.loop import (DEFAULT_SERIAL, HEADING_SIGNALS, LoopOptions, LoopResult, close_loop,
                                                not_written_reason)
from art_gyro_calibration.analysis.metrics import steady_segments
from art_gyro_calibration.analysis.replay import (OWN_RUNS_NAME, RESTARTS_NAME, Validation, field_score_dps,
                                                  judged_cold, startup_check, unjudged_warm_up, validate)
from art_gyro_calibration.analysis.report import build_report, misfit_reason, validation_section
from art_gyro_calibration.analysis.runs import Run, joined
from art_gyro_calibration.analysis.window_cost import window_cost


@dataclass(frozen=True)
class ScaleFactors:
    """What turns a raw log's counts into deg/s and degC; the calibration file keeps them for the node.

    ``assumed``: neither given nor packaged for the gyro, the usual rate factor is taken.
    """

    rate: float
    temp: float
    assumed: bool = False


def scale_factors(serial: str | None, rate_scale_factor: float | None) -> ScaleFactors:
    """The scale factors given, else the packaged calibration's of ``serial``, else the usual ones.

    A packaged file that exists but is bad is refused (:class:`CalibrationError`).
    """
    if rate_scale_factor is not None:
        return ScaleFactors(rate_scale_factor, TEMP_SCALE_FACTOR)
    if serial:
        try:
            path = find_calibration_file(serial)
        except CalibrationError:
            path = None   # a gyro not calibrated before
        if path is not None:
            packaged = load_calibration(path, expected_serial=serial)
            return ScaleFactors(packaged.rate_scale_factor, packaged.temp_scale_factor)
    return ScaleFactors(DEFAULT_RATE_SCALE_FACTOR, TEMP_SCALE_FACTOR, assumed=True)


@dataclass(frozen=True)
class FitSettings:
    """What ``calibrate fit`` is asked: the polynomial's size, the loop's options, the checks' runs.

    The log is read with the scale factors of ``loop``. ``bias_samples``: rows at rest at the
    start of a run for the node's static bias. ``validate``: other runs of the gyro to judge
    the terms on; ``validate_powered_on_at_start``: they began at its power-on. ``warm_start``:
    the logs fitted (of several) that began with the gyro already warm (the others began at its
    power-on, unless ``loop.from_power_on`` is False).
    """

    rows: int
    columns: int
    loop: LoopOptions
    bias_samples: int = DEFAULT_SAMPLES
    validate: tuple[str, ...] = ()
    validate_powered_on_at_start: bool = False
    topics: BagTopics = BagTopics()   # which topics of a rosbag2 log (and validation run) make its columns
    still: str | None = None          # a record at rest: its bias instability for the materiality and budget
    baseline: str | None = None       # the gyro's current calibration (default: the packaged file of the serial)
    operating_range_c: tuple[float, float] | None = None   # where the robot will run (default: the log's envelope)
    warm_start: tuple[str, ...] = ()


@dataclass(frozen=True)
class FitResult:
    """Everything ``calibrate fit`` found and what it writes.

    ``loop`` is the loop's result as found (the report's effects and the figures are its);
    ``startup`` the start-up check (None: nothing to check) and ``validation`` the
    ``--validate`` runs' replay (None: none given), each of which may drop terms from
    ``calibration``, the one written with ``comment``. ``report`` is REPORT.json.
    """

    log: GyroLog
    loop: LoopResult
    startup: Validation | None
    validation: Validation | None
    calibration: Calibration
    comment: str
    report: dict[str, Any]
    baseline: BaselineCheck | None = None


def fit_log(log_path: str | Sequence[str], settings: FitSettings, calibration_path: str,
            warn: Callable[[str], None] = lambda message: None) -> FitResult:
    """``calibrate fit`` on the log at ``log_path`` (or several runs of the gyro, one calibration for all of them).

    The calibration is to be written to ``calibration_path``.

    In steps: the log as the loop takes it, the loop, the start-up check, the ``--validate``
    runs, the baseline; then the calibration to write, chosen once (:func:`_choose`), and
    the report, assembled once. ``warn`` is told, as each is found, what a person must look
    at: a model that does not fit, a warm-up no cold run judged (that one is in the report too).
    """
    still = None if settings.still is None else still_noise(settings.still, settings.loop, settings.topics)
    loop_options = settings.loop if still is None else replace(
        settings.loop, still_instability_dps=still['bias_instability_dps'])
    paths = (log_path,) if isinstance(log_path, str) else tuple(log_path)
    log, runs, rows = _logs_to_fit(paths, settings, loop_options, warn)
    loop = close_loop(log, settings.rows, settings.columns, loop_options, runs)
    result, startup, restarts = startup_check(loop, log, settings.bias_samples, loop_options.settle_s)
    retrace = _retraced(log, runs, settings, loop_options, (loop, result, startup, restarts))
    if retrace is not None:
        (loop, result, startup, restarts), retraced = retrace
        warn(retraced['message'])
    # The report and figures are the loop's; what the checks drop is in their sections.
    loop_report = build_report(log, loop, settings.bias_samples, source=', '.join(paths))
    # The window terms' cost: a term whose implied mission bias exceeds what it removes is not written.
    window = window_cost(result, loop.runs, settings.bias_samples)
    result = window.result
    for cost in window.costs:
        if not cost.written:
            warn(cost.not_written())
    _warn_loop(loop, warn)
    validation, validation_dropped = _validate(result, settings, warn) if settings.validate else (None, {})
    refit = result.extended if validation is None else validation.calibration
    baseline = _baseline(log, result, refit, settings)
    check = baseline if isinstance(baseline, BaselineCheck) else None
    if check is not None and check.verdict != REFIT:
        warn(check.message)
    if check is not None and check.unknown is not None:
        warn(check.unknown.describe())
    choice = _choose(result, startup, restarts, validation, refit, check, settings)
    calibration = _with_fitted_ranges(choice.calibration, log)
    # A warm-up fitted on two power-ons or more, or judged on another cold run, is not this log's alone.
    judged = (settings.validate and settings.validate_powered_on_at_start) or \
        sum(run.powered_on_at_start for run in loop.runs) > 1
    warning = '' if judged else unjudged_warm_up(calibration, result.bias_instability_dph)
    if warning:
        warn(warning)
    needed = node_parameters_needed(calibration)   # a term on a --node-signal column: the node must be fed it
    comment = (f'Fitted by calibrate fit from {" and ".join(paths)}: {choice.polynomial}, '
               f'effects beyond it: {choice.found}.')
    if needed:
        warn(f'{calibration_path} has terms on signals the gyro does not measure: gyro_node refuses it unless '
             + '; '.join(f'{name} is set ({what})' for name, what in needed.items()))
        comment += f' gyro_node needs {" and ".join(needed)} set.'
    report = {
        **loop_report,
        **rows,   # rows_read and rows_dropped per reason; 'rows' (the loop's) are those fitted
        'runs': runs_section(log, loop),
        # Per candidate of the last screen, the smallest effect this log would have found (DetectionLimit.to_dict).
        'detection_limit_dph': {d.signal: d.to_dict() for d in loop.detection},
        **({} if still is None else {'still': still}),
        **({} if startup is None else {'startup_check': validation_section(startup, restarts)}),
        **({'window_terms': window.section()} if window.costs else {}),
        **({'retraced': retraced} if retrace is not None else {}),
        **({} if validation is None else {'validation': validation_section(validation, list(settings.validate)),
                                          'validation_rows_dropped': validation_dropped}),
        'baseline': baseline.to_dict() if isinstance(baseline, BaselineCheck) else
        {'source': None, 'verdict': 'none', 'message': baseline},
        **({'warnings': [warning]} if warning else {}),
        # The effects above are the loop's; the checks may have dropped some: what the file holds.
        'written': {'calibration': calibration_path, 'terms': [t.signal for t in calibration.terms],
                    **({} if calibration.temperature_range_c is None else
                       {'temperature_range_c': list(calibration.temperature_range_c),
                        'beyond_range': calibration.beyond_range}),
                    **({'node_parameters': needed} if needed else {})},
    }
    return FitResult(log, loop, startup, validation, calibration, comment, report,
                     baseline if isinstance(baseline, BaselineCheck) else None)


_Pass = tuple[LoopResult, LoopResult, 'Validation | None', list[str]]   # loop, its result checked, check, run names


def _startup_score_dph(check: Validation, stage: str | None = None) -> float:
    """A calibration's score on the start-up check's runs (deg/h): ``stage``, or the one to write."""
    stage = stage or ('validated' if check.dropped else 'extended')
    return field_score_dps([run[stage] for run in check.runs]) * DEG_PER_H_PER_DPS


def _found(loop: LoopResult) -> str:
    """What the loop found, for a person: its effects' signals, or "nothing"."""
    return ', '.join(e.signal for e in loop.effects) or 'nothing'


def _retraced(log: GyroLog, runs: Sequence[Run], settings: FitSettings, options: LoopOptions,
              first: _Pass) -> tuple[_Pass, dict[str, Any]] | None:
    """The loop asked again without the terms the start-up check dropped, if that does better on the log's starts.

    A stand-in dropped (a lagged temperature's eight columns fitted beside a warm-up) leaves what it stood in
    for unmodelled, though the screen had found a simpler form of it that the stand-in outscored. Asked again
    without it, the loop may find that form; it is kept if its written terms score lower on the start-up
    check's runs (:func:`replay.field_score_dps`, the same runs) by more than the noise the first pass's model
    leaves. The dropped term may instead be the true one, spoilt by a companion of several coefficients that
    took its part at the starts (a lag's eight beside a warm-up it pushed to a time constant longer than the
    restarts): the loop is asked again without each such companion too, and the best pass on the log's
    starts is the second. None when nothing was dropped, or only terms on a column the node is fed
    (``--node-signal``: not the loop's to exclude).
    """
    startup = first[2]
    dropped = tuple(d.term.signal for d in startup.dropped if d.term.signal not in options.node_signals) \
        if startup is not None else ()
    if startup is None or not dropped:
        return None
    companions = [t.signal for t in first[0].extended.terms
                  if t.signal not in dropped and t.signal not in options.node_signals and len(t.coefficients) > 1]
    tried = []
    for without in (dropped, *((c,) for c in companions)):
        loop2 = close_loop(log, settings.rows, settings.columns,
                           replace(options, exclude=(*options.exclude, *without)), runs)
        result2, startup2, restarts2 = startup_check(loop2, log, settings.bias_samples, options.settle_s)
        # Without a term the second pass writes the polynomial alone, as the first check replayed it.
        after = _startup_score_dph(startup, 'art') if startup2 is None else _startup_score_dph(startup2)
        tried.append((after, without, (loop2, result2, startup2, restarts2)))
    after, without, second = min(tried, key=lambda pass_: pass_[0])
    before = _startup_score_dph(startup)
    # Better by more than the noise the written model leaves (the start-up check weighs term sets the same way).
    chance = first[1].residual_materiality_dph or first[1].materiality_dph
    kept = after + chance < before
    others = ''.join(f'; without {", ".join(w)}, {_found(p[0])} ({dph:.2f} deg/h)'
                     for dph, w, p in tried if w != without)
    message = (f'the start-up check dropped {", ".join(dropped)}: asked again without '
               f'{"it" if without == dropped else ", ".join(without)}, the loop found {_found(second[0])} '
               f'({after:.2f} against {before:.2f} deg/h on the log\'s starts{others}): the '
               f'{"second" if kept else "first"} pass is written')
    section = {'without': list(without), 'found': [e.signal for e in second[0].effects], 'first_dph': before,
               'second_dph': after, 'kept': 'second' if kept else 'first', 'message': message,
               'tried': [{'without': list(w), 'found': [e.signal for e in p[0].effects], 'dph': dph}
                         for dph, w, p in tried]}
    return (second if kept else first), section


def runs_section(log: GyroLog, loop: LoopResult) -> list[dict[str, Any]]:
    """REPORT.json's ``runs``: per run fitted, its rows, how it began, its turn-on bias and temperatures.

    ``turn_on_offset_dph``: its fitted turn-on bias less the first run's (0 for the first; the
    static bias removes each run's own, none is written).
    """
    offsets = loop.run_offsets_dps or (0.0,) * len(loop.runs)
    return [{'name': run.name, 'rows': run.rows, 'powered_on_at_start': run.powered_on_at_start,
             'turn_on_offset_dph': offset * DEG_PER_H_PER_DPS,
             'temperature_c': [float(np.min(log.temp_c[run.first_row:run.stop])),
                               float(np.max(log.temp_c[run.first_row:run.stop]))]}
            for run, offset in zip(loop.runs, offsets)]


def _logs_to_fit(paths: Sequence[str], settings: FitSettings, options: LoopOptions,
                 warn: Callable[[str], None]) -> tuple[GyroLog, tuple[Run, ...], dict[str, int | dict[str, int]]]:
    """The logs as :func:`_log_to_fit` reads each, one after another (:func:`.runs.joined`), and their runs.

    Each run began at power-on (``options.from_power_on``) unless ``settings.warm_start`` names
    it; a name there that is not one of ``paths``, or a log given twice, is refused. Rows read and
    dropped are summed over the logs; the coverage of the polynomial is checked on all of them
    together (a run alone may span too few degrees: the others complete it).
    """
    unknown = [name for name in settings.warm_start if name not in paths]
    if unknown:
        raise ValueError(f'--warm-start {unknown[0]}: not one of the logs fitted ({", ".join(paths)})')
    twice = [name for i, name in enumerate(paths) if name in paths[:i]]
    if twice:
        raise ValueError(f'{twice[0]}: given twice; each run of the gyro is one log')
    if len(paths) == 1:
        log, rows = _log_to_fit(paths[0], settings, options, warn)
        return log, (Run(paths[0], 0, len(log), options.from_power_on and not settings.warm_start),), rows
    logs = []
    read = 0
    dropped: dict[str, int] = {}
    for path in paths:
        log, rows = _log_to_fit(path, settings, options, warn, coverage=False)
        logs.append((path, log, options.from_power_on and path not in settings.warm_start))
        count, lost = rows['rows_read'], rows['rows_dropped']
        assert isinstance(count, int) and isinstance(lost, dict)   # as _log_to_fit makes them
        read += count
        for reason, n in lost.items():
            dropped[reason] = dropped.get(reason, 0) + n
    log, runs = joined(logs)
    _check_coverage(log, ', '.join(paths), settings, options)
    return log, runs, {'rows_read': read, 'rows_dropped': dropped}


# Rows repeating the previous stamp beyond this share of a log: its clock is coarser than its rows (1 s stamps on a
# 10 Hz log), which no dropping mends; fewer are dropped and counted (a logger that wrote a row twice).
MAX_REPEATED_STAMPS = 0.01
# A log whose non-finite values would drop more than this share of its rows is refused: a column not measured.
MAX_NOT_FINITE_ROWS = 0.5


def _log_to_fit(log_path: str, settings: FitSettings, options: LoopOptions, warn: Callable[[str], None],
                coverage: bool = True) -> tuple[GyroLog, dict[str, int | dict[str, int]]]:
    """The log read with ``options``' scale factors, less the rows nothing can fit; refused if it is too narrow.

    Dropped, each counted (REPORT.json's ``rows_dropped``) and told to ``warn``: the rows :func:`_defined_rows`
    drops, and those the node drops (the rate clipped). Refused (:class:`LogError`): what :func:`_defined_rows`
    refuses, and a log whose steady rates and temperatures cannot determine the polynomial; one without
    ``ref_rate`` is left for the loop to say what is missing.
    """
    read = read_any_log(log_path, options.rate_scale_factor, options.temp_scale_factor, settings.topics, warn)
    log, dropped = _defined_rows(read, log_path, warn)
    usable = usable_rates(log.rate_dps, options.rate_scale_factor)
    if not usable.all():   # the node drops these frames: no value to fit (a turn beyond the range reads as slower)
        dropped['rate beyond range'] = log.t.size - int(usable.sum())
        warn(f'{log.t.size - int(usable.sum())} of {log.t.size} rows excluded: the rate clipped (at '
             f'+-{unit_range_dps(options.rate_scale_factor):g} deg/s) or beyond any unit\'s range (the node '
             'drops such frames)')
        log = log.slice(usable)
    if coverage:
        _check_coverage(log, log_path, settings, options)
    return log, {'rows_read': len(read), 'rows_dropped': dropped}


def _check_coverage(log: GyroLog, source: str, settings: FitSettings, options: LoopOptions) -> None:
    """:func:`.fit.check_coverage` of ``log`` (from ``source``), refused naming it; one without ``ref_rate`` passes."""
    if log.ref_rate is not None:
        try:
            check_coverage(log.temp_c, steady_segments(log.t, log.ref_rate, options.settle_s).rate,
                           settings.rows, settings.columns)
        except ValueError as e:
            raise LogError(f'{source}: {e}') from None


def _defined_rows(log: GyroLog, log_path: str, warn: Callable[[str], None]) -> tuple[GyroLog, dict[str, int]]:
    """``log`` less the rows whose values do not say what they claim; how many were dropped, per reason.

    Dropped and told to ``warn``: a row with a value that is not finite in any column (``ref_rate``, a signal
    column), one repeating the previous stamp (a logger that wrote it twice). Refused (:class:`LogError`): a
    column mostly not finite, and stamps coarser than the rows (1 s stamps on a 10 Hz log), which no drop mends.
    """
    dropped: dict[str, int] = {}
    columns = {'t': log.t, 'rate': log.rate_dps, 'temperature': log.temp_c,
               **({} if log.ref_rate is None else {'ref_rate': log.ref_rate}), **log.extras}
    finite = np.ones(len(log), dtype=bool)
    not_finite: dict[str, int] = {}
    for name, values in columns.items():
        bad = ~np.isfinite(values)
        if bad.any():
            not_finite[name] = int(bad.sum())
            finite &= ~bad
    if not finite.all():
        dropped.update({f'not finite: {name}': count for name, count in not_finite.items()})
        counts = ', '.join(f'{count} in {name}' for name, count in not_finite.items())
        if finite.sum() < (1.0 - MAX_NOT_FINITE_ROWS) * len(log):
            raise LogError(f'{log_path}: {len(log) - int(finite.sum())} of {len(log)} rows have values that are not '
                           f'finite ({counts}): too few rows left to fit')
        warn(f'{log_path}: {len(log) - int(finite.sum())} of {len(log)} rows excluded: values not finite ({counts})')
        log = log.slice(finite)
    repeated = np.zeros(len(log), dtype=bool)
    repeated[1:] = log.t[1:] == log.t[:-1]
    if repeated.any():
        count = int(repeated.sum())
        if count > MAX_REPEATED_STAMPS * len(log):
            steps = np.diff(log.t[~repeated])
            raise LogError(f'{log_path}: column t: {count} of {len(log)} rows repeat the previous stamp: the stamps '
                           f'step by {float(np.median(steps)) if steps.size else 0.0:g} s while the log has '
                           f'{len(log) / max(float(log.t[-1] - log.t[0]), 1e-300):.3g} rows per second; time too '
                           'coarse to fit (log t finer than the row interval)')
        dropped['repeated stamp'] = count
        warn(f'{log_path}: {count} of {len(log)} rows excluded: they repeat the previous row\'s stamp')
        log = log.slice(~repeated)
    return log, dropped


def _with_fitted_ranges(calibration: Calibration, log: GyroLog) -> Calibration:
    """``calibration`` with the range over which each of its terms on a log column (a supply voltage) was fitted.

    The node and ``calibrate apply`` take a value far beyond it as wrong (:meth:`Calibration.signal_limits`).
    """
    ranges = {}
    for term in calibration.terms:
        values = log.extras.get(term.signal)
        if values is not None and values.size and float(np.min(values)) < float(np.max(values)):
            ranges[term.signal] = (float(np.min(values)), float(np.max(values)))
    return replace(calibration, signal_ranges=ranges)


def _warn_loop(loop: LoopResult, warn: Callable[[str], None]) -> None:
    """Tell ``warn`` what the loop found and does not write, and whether its model leaves more than noise."""
    for finding in loop.findings:
        if finding.signal not in HEADING_SIGNALS:
            warn(f'an effect on {finding.signal} ({finding.score.effect_dph:.2f} deg/h) was found and not written: '
                 f'{not_written_reason(finding.signal)}')
    adequacy = loop.adequacy
    if adequacy is not None and not adequacy.model_adequate:
        reason = misfit_reason(adequacy.residual_rms_dph, adequacy.budget_dph, adequacy.excess_dph,
                               [(x.signal, x.shape_dph) for x in adequacy.signals if x.found])
        warn(f'the model does not fit: {reason}; see REPORT.md and the residual against each signal (--plots)')


@dataclass(frozen=True)
class _Choice:
    """The calibration to write and what its comment says of it.

    ``polynomial``: whose polynomial it holds; ``found``: the effects beyond it, and what the checks dropped.
    """

    calibration: Calibration
    polynomial: str
    found: str


def _choose(result: LoopResult, startup: Validation | None, restarts: list[str], validation: Validation | None,
            refit: Calibration, check: BaselineCheck | None, settings: FitSettings) -> _Choice:
    """The calibration to write: ``refit`` (the loop's after the start-up check and the ``--validate`` runs).

    Or, judged against a baseline, ``check``'s: the refit continued beyond the log by the
    baseline, or the baseline whose polynomial the refit did not beat held out (its bias
    column refitted when that was better), with the terms fitted on top of it that made it better.
    """
    found = _found(result)
    if startup is not None:
        found += _dropped(startup, OWN_RUNS_NAME if judged_cold(restarts) else RESTARTS_NAME)
    if validation is not None and validation.dropped:
        found = (', '.join(t.signal for t in refit.terms) or 'nothing') + _dropped(validation, 'the validation runs')
    if check is None or check.verdict == REFIT:
        written = refit if check is None else check.calibration
        return _Choice(written, f'ART polynomial {settings.rows} x {settings.columns}', found)
    if len(check.calibration.terms) < len(refit.terms):
        found += ' (not written: they made the baseline worse)'
    bias = ', its bias column refitted' if check.verdict == REBIASED else ''
    return _Choice(check.calibration, f'the baseline\'s polynomial ({check.source}{bias}; the refit was not better '
                   'held out)', found)


def _baseline(log: GyroLog, result: LoopResult, calibration: Calibration,
              settings: FitSettings) -> BaselineCheck | str:
    """The refit judged against the gyro's current calibration, or why there is none to judge it against.

    The baseline: ``settings.baseline``, else the packaged file of the loop's serial.
    """
    serial = settings.loop.serial_number
    path = settings.baseline
    if path is None:
        try:
            path = str(find_calibration_file(serial)) if serial != DEFAULT_SERIAL else None
        except CalibrationError:
            path = None
        if path is None:
            return (f'no baseline: no calibration of {serial} is packaged and --baseline was not given'
                    if serial != DEFAULT_SERIAL else 'no baseline: neither --serial nor --baseline was given')
    baseline = load_calibration(path, expected_serial=None if serial == DEFAULT_SERIAL else serial)
    check_baseline(baseline, path, settings.loop.rate_scale_factor, settings.loop.temp_scale_factor)
    check = compare_with_baseline(log, result, calibration, baseline, path, settings.bias_samples,
                                  settings.loop.settle_s, settings.operating_range_c)
    if check is None:
        return (f'not judged against the baseline {path}: the log has no run the node could start '
                f'({settings.bias_samples} rows at rest) or fewer than two held-out blocks')
    return check


def still_noise(path: str, options: LoopOptions, topics: BagTopics) -> dict[str, Any]:
    """``calibrate allan`` on a record at rest (read with ``options``' scale factors): its IEEE 952 terms.

    ``bias_instability_dps`` is the floor as the loop reads it on a residual
    (:func:`.noise.allan_floor_dps` from one minute on), so the two are the same measure.
    """
    from art_gyro_calibration.analysis.bags import csv_rate_chunks, is_bag, rate_chunks
    from art_gyro_calibration.analysis.noise import allan_floor_dps, allan_of_record
    total: float   # a bag's messages, or the rows a CSV's size gives
    if is_bag(path):
        total, chunks = rate_chunks(path, topics.rate)
    else:
        total, chunks = csv_rate_chunks(path, options.rate_scale_factor, options.temp_scale_factor)
    measured = allan_of_record(chunks, path, progress_total=total)
    floor = allan_floor_dps(measured.allan, measured.stats.sample_rate_hz, 60.0)
    return {'source': path, 'samples': measured.stats.samples, 'sample_rate_hz': measured.stats.sample_rate_hz,
            **measured.terms.to_dict(), 'bias_instability_dps': floor,
            'materiality_bias_instability_dph': floor * DEG_PER_H_PER_DPS}


def _validate(result: LoopResult, settings: FitSettings,
              warn: Callable[[str], None]) -> tuple[Validation, dict[str, dict[str, int]]]:
    """Replay ``result``'s calibrations on the ``validate`` runs, read as the fitted log was; rows dropped per run."""
    logs, dropped = [], {}
    for path in settings.validate:
        log, dropped[path] = _defined_rows(
            read_any_log(path, result.art.rate_scale_factor, result.art.temp_scale_factor, settings.topics), path,
            warn)
        logs.append(log)
    return validate(result, logs, settings.bias_samples, settings.loop.settle_s,
                    RunStart(powered_on_at_start=settings.validate_powered_on_at_start)), dropped


def _dropped(validation: Validation, runs: str) -> str:
    """What a replay dropped, for the calibration file's comment ('' when nothing)."""
    if not validation.dropped:
        return ''
    return f' ({", ".join(d.term.signal for d in validation.dropped)} dropped: {runs} were better without)'
