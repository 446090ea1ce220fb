"""Close the loop on a rate-table log: fit, trace the residual, extend the model, repeat.

:func:`close_loop` fits the ART polynomial, screens the residual against every signal
(:mod:`art_gyro_calibration.analysis.trace`), adds the most significant effect as an extended term,
refits everything jointly and screens again, until nothing significant remains. It
returns the report's polynomial alone (``art``) and the extended calibration, both
loadable by the node and by ``calibrate apply``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import TEMP_SCALE_FACTOR, Calibration
from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.analysis.metrics import (DEFAULT_SETTLE_S, Segments, correlation_time_s, noise_floor,
                                                   steady_segments)
from art_gyro_calibration.signals import SignalFilters, Signals, compute_signals
from art_gyro_calibration.terms import Term
from art_gyro_calibration.analysis.trace import (DEFAULT_BIN_S, DEFAULT_BLOCK_S, DEFAULT_FOLDS, DEFAULT_MATERIALITY,
                                                 DEFAULT_SHIFTS, Binned, CandidateScore, Screen, TraceResult,
                                                 held_out_rms,
                                                 trace_residual)

DEFAULT_MAX_EFFECTS = 4
# Most RD2100s read 0.00305 deg/s per count (report, section 1).
DEFAULT_RATE_SCALE_FACTOR = 0.00305
# Signals computed from the measured rate alone.
RATE_SIGNALS = ('rate', 'rate_abs', 'rate_sign', 'rate_change', 'angle')
DEFAULT_SERIAL = 'UNSPECIFIED'
# Signals whose linear term may grow a square when the held-out error says so; the others
# would duplicate the polynomial (rate_abs**2 = rate**2) or a constant (rate_sign**2).
_SQUARABLE = ('temperature_rate', 'rate_change')


@dataclass(frozen=True)
class Effect:
    """One traced effect, as added to the model."""

    term: Term
    score: CandidateScore
    held_out_rms_without_dps: float
    held_out_rms_with_dps: float

    @property
    def signal(self) -> str:
        """The signal the effect depends on."""
        return self.term.signal


@dataclass(frozen=True)
class LoopResult:
    """Everything :func:`close_loop` found; :mod:`art_gyro_calibration.analysis.report` serialises it."""

    art: Calibration
    extended: Calibration
    effects: tuple[Effect, ...]
    rounds: tuple[TraceResult, ...]
    noise_floor_dps: float
    held_out_rms_art_dps: float
    held_out_rms_extended_dps: float
    held_out_block_s: float
    signals: Signals
    error: NDArray[np.float64]
    segments: Segments


def close_loop(log: GyroLog, rows: int, columns: int, *, serial_number: str = DEFAULT_SERIAL,
               rate_scale_factor: float = DEFAULT_RATE_SCALE_FACTOR, temp_scale_factor: float = TEMP_SCALE_FACTOR,
               filters: SignalFilters = SignalFilters(), settle_s: float = DEFAULT_SETTLE_S,
               max_effects: int = DEFAULT_MAX_EFFECTS, folds: int = DEFAULT_FOLDS,
               shifts: int = DEFAULT_SHIFTS, bin_s: float = DEFAULT_BIN_S,
               materiality: float = DEFAULT_MATERIALITY, seed: int = 0,
               exclude: Sequence[str] = (), block_s: float = DEFAULT_BLOCK_S) -> LoopResult:
    """Fit -> trace -> extend -> repeat on a rate-table ``log`` (it needs ``ref_rate``).

    ``rate_scale_factor`` and ``temp_scale_factor`` only go into the calibrations
    returned (the log is already in deg/s and degC). The fit uses the steady rows of
    ``settle_s`` after each change of table rate. Signals in ``exclude`` are never
    candidates (e.g. a log column the node will not have at run time). ``block_s`` is the
    shortest held-out block of time; each round lengthens it to the correlation time of
    what the model leaves (a real gyro's bias wanders for hours).
    """
    if log.ref_rate is None:
        raise LogError('the log has no ref_rate column: fitting needs the rate table\'s true rate')
    for name, values in log.extras.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogError(f'column {name} is not a finite number at row {bad[0] + 1}')
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, filters)
    error = log.rate_dps - log.ref_rate
    segments = steady_segments(log.t, log.ref_rate, settle_s)
    index = segments.rows()
    if index.size == 0:
        raise LogError('the log has no steady segments of constant ref_rate to fit')
    art_fit = fit_model(signals, error, rows, columns, (), index)
    residual = np.zeros(len(error))
    residual[index] = art_fit.residual
    floor = noise_floor(residual, segments)
    # A still gyro (one reference rate throughout) reads nothing but its error: a signal derived
    # from its rate would explain the error with itself, so none is a candidate.
    still = bool(np.ptp(log.ref_rate) == 0.0)
    binned = Binned(signals, error, segments, rows, columns, folds, bin_s, block_s)
    every_row = Binned(signals, error, segments, rows, columns, folds, 0.0, block_s)
    options = dict(folds=folds, shifts=shifts, bin_s=bin_s, materiality=materiality, seed=seed,
                   noise_floor_dps=floor, exclude=[*exclude, *(RATE_SIGNALS if still else ())], binned=binned)
    specs: list[TermSpec] = []
    rounds: list[TraceResult] = []
    scores: list[CandidateScore] = []
    while len(specs) < max_effects:
        # Held-out blocks at least as long as what the current model leaves stays correlated:
        # shorter ones share a slow residual with their neighbours, and any slow signal seems to predict it.
        current = art_fit if not specs else fit_model(signals, error, rows, columns, specs, index)
        residual[index] = current.residual
        binned.refold(max(block_s, correlation_time_s(signals.t, residual, segments)))
        found = trace_residual(signals, error, segments, rows, columns, specs, **options)
        rounds.append(found)
        best = found.best
        if best is None:
            break
        specs.append(best.spec)
        scores.append(best)
    # A square is judged once every effect is in the model, so it cannot stand in for one not yet found.
    specs = [_maybe_square(spec, binned, specs[:i] + specs[i + 1:], materiality * floor ** 2)
             for i, spec in enumerate(specs)]
    every_row.refold(binned.block_s)  # held-out errors on the blocks of the last round
    # Every effect must lower the held-out error of the final model, every row counted: one
    # that passed its screen only given candidates that did not make it is dropped.
    while True:
        held_out_all = held_out_rms(every_row, specs)
        without = [held_out_rms(every_row, specs[:i] + specs[i + 1:]) for i in range(len(specs))]
        if not specs or min(without) > held_out_all:
            break
        weakest = int(np.argmin(without))
        del specs[weakest], scores[weakest]
    final = fit_model(signals, error, rows, columns, specs, index)
    effects = [Effect(term, score, rms_without, held_out_all)
               for term, score, rms_without in zip(final.model.terms, scores, without)]
    low, high = float(np.floor(log.temp_c[index].min())), float(np.ceil(log.temp_c[index].max()))
    art = Calibration(serial_number, rate_scale_factor, art_fit.model.polynomial,
                      (low, high if high > low else low + 1.0), temp_scale_factor, (), filters)
    return LoopResult(
        art=art, extended=replace(art, polynomial=final.model.polynomial, terms=final.model.terms),
        effects=tuple(effects), rounds=tuple(rounds), noise_floor_dps=floor,
        held_out_rms_art_dps=held_out_rms(every_row),
        held_out_rms_extended_dps=held_out_all, held_out_block_s=every_row.block_s, signals=signals,
        error=error, segments=segments)


def _maybe_square(spec: TermSpec, binned: Binned, specs: list[TermSpec], material_dps2: float) -> TermSpec:
    """``spec`` with powers [1, 2] if the square lowers the held-out error materially, else ``spec``."""
    if spec.form != 'power' or spec.powers != (1,) or spec.signal not in _SQUARABLE + tuple(binned.signals.extras):
        return spec
    squared = replace(spec, powers=(1, 2))
    linear = Screen(binned, specs + [spec])
    both = Screen(binned, specs + [squared])
    gain = (linear.base_sse() - both.base_sse()) / linear.rows_total
    return squared if gain > material_dps2 else spec
