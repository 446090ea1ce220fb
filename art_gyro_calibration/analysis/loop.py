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
from art_gyro_calibration.analysis.allan import allan_deviation
from art_gyro_calibration.analysis.trace import (DEFAULT_ALPHA, DEFAULT_BIN_S, DEFAULT_BLOCK_S, DEFAULT_DRAWS,
                                                 DEFAULT_FOLDS, DEG_PER_H_PER_DPS, Binned, CandidateScore, Screen,
                                                 TraceResult, held_out_residual, trace_residual)

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
class Adequacy:
    """Whether the final model leaves only noise, held out: the lack-of-fit alarm.

    The budget of a block mean of ``block_s`` is the white noise averaged over the block
    plus the bias instability (the floor of the held-out residual's Allan deviation);
    the residual's block means are compared with it.
    """

    model_adequate: bool
    block_s: float
    residual_rms_dph: float
    budget_dph: float
    excess_dph: float
    bias_instability_dph: float


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
    materiality_dph: float = 0.0
    bias_instability_dph: float = 0.0
    adequacy: Adequacy | None = None


def close_loop(log: GyroLog, rows: int, columns: int, *, serial_number: str = DEFAULT_SERIAL,
               rate_scale_factor: float = DEFAULT_RATE_SCALE_FACTOR, temp_scale_factor: float = TEMP_SCALE_FACTOR,
               filters: SignalFilters = SignalFilters(), settle_s: float = DEFAULT_SETTLE_S,
               max_effects: int = DEFAULT_MAX_EFFECTS, folds: int = DEFAULT_FOLDS,
               draws: int = DEFAULT_DRAWS, alpha: float = DEFAULT_ALPHA, bin_s: float = DEFAULT_BIN_S,
               materiality_dph: float | None = None, seed: int = 0,
               exclude: Sequence[str] = (), block_s: float = DEFAULT_BLOCK_S) -> LoopResult:
    """Fit -> trace -> extend -> repeat on a rate-table ``log`` (it needs ``ref_rate``).

    ``rate_scale_factor`` and ``temp_scale_factor`` only go into the calibrations
    returned (the log is already in deg/s and degC). The fit uses the steady rows of
    ``settle_s`` after each change of table rate. Signals in ``exclude`` are never
    candidates (e.g. a log column the node will not have at run time). ``block_s`` is the
    shortest held-out block of time; each round lengthens it to the correlation time of
    what the model leaves (a real gyro's bias wanders for hours). An effect must reach
    ``materiality_dph`` over the logged envelope; by default the bias instability of what
    the ART polynomial leaves (the floor of its Allan deviation).
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
    instability_dph = bias_instability_dph(Screen(binned).residual() / binned.sqrt_counts, bin_s)
    materiality = instability_dph if materiality_dph is None else materiality_dph
    options = dict(draws=draws, alpha=alpha, bin_s=bin_s, materiality_dph=materiality, seed=seed,
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
    specs = [_maybe_square(spec, binned, specs[:i] + specs[i + 1:], materiality)
             for i, spec in enumerate(specs)]
    every_row.refold(binned.block_s, binned.n_folds)  # held-out errors on the blocks of the last round
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
        error=error, segments=segments, materiality_dph=materiality, bias_instability_dph=instability_dph,
        adequacy=adequacy(binned, specs, floor, bin_s, materiality))


def held_out_rms(rows: Binned, specs: Sequence[TermSpec] = ()) -> float:
    """Held-out RMS error (deg/s) of the polynomial + ``specs``; ``rows`` binned with ``bin_s=0``: every steady row."""
    r = held_out_residual(rows, specs)
    return float(np.sqrt(r @ r / rows.rows_total))


def bias_instability_dph(bin_means: NDArray[np.float64], bin_s: float) -> float:
    """Bias instability (deg/h) of a residual's bin means: the floor of their Allan deviation / 0.664.

    The bins of steady segments are taken as one series (the rests between them are short);
    the floor is sought from one minute on, where the white noise has averaged down.
    """
    adev = allan_deviation(bin_means, 1.0 / max(bin_s, 1e-9))
    usable = adev.adev[adev.tau_s >= min(60.0, adev.tau_s[-1])]
    return float(usable.min() / 0.664 * DEG_PER_H_PER_DPS)


# The residual's block means may exceed their noise budget by this factor before the alarm:
# the budget's bias instability is itself estimated from the same residual.
ADEQUACY_RATIO = 5.0
ADEQUACY_BLOCK_S = 600.0


def adequacy(binned: Binned, specs: Sequence[TermSpec], floor_dps: float, bin_s: float,
             materiality_dph: float) -> Adequacy:
    """The lack-of-fit alarm: do the held-out residual's 10-minute means stay within the noise budget?"""
    residual = held_out_residual(binned, specs) / binned.sqrt_counts   # held-out bin means, deg/s
    t = binned.bin_times()
    block = np.floor((t - t[0]) / ADEQUACY_BLOCK_S).astype(np.int64)
    counts = np.bincount(block, weights=binned.sqrt_counts ** 2)
    sums = np.bincount(block, weights=residual * binned.sqrt_counts ** 2)
    full = counts >= 0.5 * counts.max()
    means = sums[full] / counts[full]
    rms = float(np.sqrt(np.mean((means - means.mean()) ** 2)))
    instability = bias_instability_dph(residual, bin_s) / DEG_PER_H_PER_DPS
    budget = float(np.sqrt(floor_dps ** 2 / np.mean(counts[full]) + (0.664 * instability) ** 2))
    excess = float(np.sqrt(max(rms ** 2 - (ADEQUACY_RATIO * budget) ** 2, 0.0)))
    adequate = not (rms > ADEQUACY_RATIO * budget and excess * DEG_PER_H_PER_DPS > materiality_dph)
    return Adequacy(adequate, ADEQUACY_BLOCK_S, rms * DEG_PER_H_PER_DPS, budget * DEG_PER_H_PER_DPS,
                    excess * DEG_PER_H_PER_DPS, instability * DEG_PER_H_PER_DPS)


def _maybe_square(spec: TermSpec, binned: Binned, specs: list[TermSpec], materiality_dph: float) -> TermSpec:
    """``spec`` with powers [1, 2] if the square lowers the held-out error and its curvature is material.

    The curvature is the square's part that a straight line in the signal cannot give,
    half its range over the logged envelope.
    """
    if spec.form != 'power' or spec.powers != (1,) or spec.signal not in _SQUARABLE + tuple(binned.signals.extras):
        return spec
    squared = replace(spec, powers=(1, 2))
    both = Screen(binned, specs + [squared])
    if both.base_sse() >= Screen(binned, specs + [spec]).base_sse():
        return spec
    _, beta = Screen(binned, specs).fit_with(squared)
    means = binned.candidate_means([squared])[:, 0, :]
    line = np.column_stack([np.ones(len(means)), means[:, 0]])
    bend = means[:, 1] - line @ np.linalg.lstsq(line, means[:, 1], rcond=None)[0]
    return squared if 0.5 * np.ptp(bend * beta[1]) * DEG_PER_H_PER_DPS >= materiality_dph else spec
