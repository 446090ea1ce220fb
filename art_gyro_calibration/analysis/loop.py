"""Close the loop on a rate-table log: fit, trace the residual, extend the model, repeat.

:func:`close_loop` fits the ART polynomial, screens the residual against every signal
(:mod:`art_gyro_calibration.analysis.trace`), adds the most significant effect as an extended term,
refits everything jointly and screens again, until nothing significant remains. It
returns the report's polynomial alone (``art``) and the extended calibration, both
loadable by the node and by ``calibrate apply``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import DEFAULT_RATE_SCALE_FACTOR, TEMP_SCALE_FACTOR, Calibration
from art_gyro_calibration.compensation import RunStart
from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.analysis.metrics import (DEFAULT_SETTLE_S, Segments, correlation_time_s, noise_floor,
                                                   steady_segments)
from art_gyro_calibration.signals import FIRST_ORDER_TAU_S, SIGNALS, SignalFilters, Signals, compute_signals
from art_gyro_calibration.temperature_rate import FIRST_ORDER
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS
from art_gyro_calibration.analysis.allan import allan_deviation
from art_gyro_calibration.analysis.noise import allan_floor_dps
from art_gyro_calibration.analysis.detection import DetectionLimit, detection_limits
from art_gyro_calibration.analysis.runs import Run, run_starts
from art_gyro_calibration.analysis import trace

DEFAULT_MAX_EFFECTS = 4
# Signals computed from the measured rate alone, and the screen's forms on the rate.
RATE_SIGNALS = (*(name for name, s in SIGNALS.items() if s.from_rate), 'rate_x_temperature', 'rate_x_temperature_rate')
# Effects of the heading (a signal the node does not track): found and reported, never written into a calibration.
HEADING_SIGNALS = tuple(name for name, s in SIGNALS.items() if not s.per_sample)
# What the node computes at run time: an effect on any other signal (the heading, an extra log column such as a
# supply voltage) is a finding, never written, so calibrate fit never writes a file the node refuses; a log column
# the robot feeds the node by topic (LoopOptions.node_signals, calibrate fit --node-signal) is written.
NODE_SIGNALS = tuple(name for name, s in SIGNALS.items() if s.per_sample)


def not_written_reason(signal: str) -> str:
    """Why an effect on ``signal`` is reported but not written into the calibration."""
    if signal in HEADING_SIGNALS:
        return 'the node has no absolute heading to apply it with'
    return (f'the node has no {signal} at run time (a column of the log, not a signal the node tracks): a file with '
            'it would be refused, so the error it explains stays uncorrected on the robot; if the robot can give '
            f'the node {signal} by topic, fit with --node-signal {signal} to write it; else log the robot\'s '
            f'{signal} to judge its size there, or fit with --exclude {signal} to say it is known')


DEFAULT_SERIAL = 'UNSPECIFIED'
# Signals whose linear term may grow a square when the held-out error says so; the others
# would duplicate the polynomial (rate_abs**2 = rate**2) or a constant (rate_sign**2).
_SQUARABLE = tuple(name for name, s in SIGNALS.items() if s.squarable)


@dataclass(frozen=True)
class LoopOptions(trace.ScreenOptions):
    """How :func:`close_loop` runs: each round's screen (:class:`trace.ScreenOptions`) and the loop's own settings.

    ``serial_number``, ``rate_scale_factor`` and ``temp_scale_factor`` only go into the
    calibrations returned (the log is already in deg/s and degC). The fit uses the steady rows of
    ``settle_s`` after each change of table rate. Signals in ``exclude`` are never
    candidates (e.g. a log column the node will not have at run time). ``block_s`` is the
    shortest held-out block of time; each round lengthens it to the correlation time of
    what the model leaves (a real gyro's bias wanders for hours). An effect must reach
    ``materiality_dph`` over the logged envelope; None: the bias instability of what
    the ART polynomial leaves (:func:`noise_levels`). ``from_power_on``: the log
    starts at the gyro's power-on (a warm-up is a candidate only then; several runs: each says its own).
    ``still_instability_dps``: the bias instability measured on a record at rest
    (``calibrate fit --still``), for the materiality and the noise budget instead of the residual's.
    ``node_signals``: log columns the robot will feed the node by topic (a supply voltage): an
    effect on one is written, not a finding.
    """

    serial_number: str = DEFAULT_SERIAL
    rate_scale_factor: float = DEFAULT_RATE_SCALE_FACTOR
    temp_scale_factor: float = TEMP_SCALE_FACTOR
    filters: SignalFilters = field(default_factory=SignalFilters)
    settle_s: float = DEFAULT_SETTLE_S
    max_effects: int = DEFAULT_MAX_EFFECTS
    materiality_dph: float | None = None
    exclude: tuple[str, ...] = ()
    block_s: float = trace.DEFAULT_BLOCK_S
    from_power_on: bool = True
    still_instability_dps: float | None = None
    node_signals: tuple[str, ...] = ()


@dataclass(frozen=True)
class Effect:
    """One traced effect, as added to the model."""

    term: Term
    score: trace.CandidateScore
    held_out_rms_without_dps: float
    held_out_rms_with_dps: float

    @property
    def signal(self) -> str:
        """The signal the effect depends on."""
        return self.term.signal


@dataclass(frozen=True)
class SignalShape:
    """What the held-out residual does against one signal, with no form assumed (binned means).

    ``shape_dph``: half the peak-to-peak of the residual's means in groups of the signal
    (:func:`signal_groups`; heading: 30-degree sectors of the heading modulo 360); ``score`` how
    far those means stand out against phase-randomised residuals (:func:`shape_scores`),
    ``chance_score`` the level chance reaches for the strongest of all signals. ``found``:
    beyond both chance and the materiality.
    """

    signal: str
    shape_dph: float
    score: float
    chance_score: float
    found: bool


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
    signals: tuple[SignalShape, ...] = ()


@dataclass(frozen=True)
class LoopResult:
    """Everything :func:`close_loop` found; :mod:`art_gyro_calibration.analysis.report` serialises it."""

    art: Calibration
    extended: Calibration
    effects: tuple[Effect, ...]
    rounds: tuple[trace.TraceResult, ...]
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
    findings: tuple[Effect, ...] = ()   # effects found, not written: not_written_reason (heading, extra column)
    start: RunStart = RunStart(powered_on_at_start=True)   # how the fitted log began, for replaying it
    # The materiality of what the written model leaves (materiality_dph is of what the polynomial alone leaves,
    # effects included): the chance against which the start-up check weighs term sets (replay.startup_check).
    residual_materiality_dph: float = 0.0
    detection: tuple[DetectionLimit, ...] = ()   # per candidate of the last screen: what the log could not see
    # The runs whose rows ``signals`` and ``error`` hold, one after another (one run covering the log: a
    # single-log fit), and each one's fitted turn-on bias less the first's (deg/s; () for one run).
    runs: tuple[Run, ...] = ()
    run_offsets_dps: tuple[float, ...] = ()


def _one_blas_thread(function: Callable[..., LoopResult]) -> Callable[..., LoopResult]:
    """Run ``function`` with BLAS on one thread.

    The loop's products are small (bins x a few columns): a multi-threaded BLAS spends
    its time spin-waiting, 20 times slower on a loaded machine (measured: 85 ms against
    3.6 ms for one screen's per-fold sums at load average 9).
    """
    @functools.wraps(function)
    def wrapped(*args: Any, **kwargs: Any) -> LoopResult:
        # The analysis extra: imported when the loop runs (untyped).
        from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]
        with threadpool_limits(limits=1, user_api='blas'):
            return function(*args, **kwargs)
    return wrapped


@_one_blas_thread
def close_loop(log: GyroLog, rows: int, columns: int, options: LoopOptions = LoopOptions(),
               runs: Sequence[Run] = ()) -> LoopResult:
    """Fit -> trace -> extend -> repeat on a rate-table ``log`` (it needs ``ref_rate``), as ``options`` say.

    ``rows`` x ``columns``: the ART polynomial's powers of temperature and rate. A heading
    effect is fitted against the angle of the rate the ART polynomial corrects, and reported in
    ``findings``, never written: the node has no absolute heading. ``runs``: the log is several
    runs of the gyro one after another (:func:`.runs.joined`), each with its own turn-on bias and
    start; none: one run, from power-on as ``options.from_power_on`` says.
    """
    filters, settle_s, bin_s, block_s = options.filters, options.settle_s, options.bin_s, options.block_s
    if log.ref_rate is None:
        raise LogError('the log has no ref_rate column: fitting needs the rate table\'s true rate')
    for name, values in log.extras.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogError(f'column {name} is not a finite number at row {bad[0] + 1}')
    runnable = NODE_SIGNALS + node_signals(options, tuple(log.extras))
    runs = tuple(runs) or (Run('log', 0, len(log), options.from_power_on),)
    if [r.first_row for r in runs] != [0, *(r.stop for r in runs[:-1])] or runs[-1].stop != len(log):
        raise ValueError(f'the runs ({", ".join(f"{r.name}: rows {r.first_row}..{r.stop}" for r in runs)}) '
                         f'do not cover the log\'s {len(log)} rows one after another')
    # The held-out blocks, bins and segments follow the fit's one clock: each run after the one before.
    behind = [r.name for r in runs[1:] if log.t[r.first_row] <= log.t[r.first_row - 1]]
    if behind:
        raise ValueError(f'run {behind[0]} begins before the run before it ended: lay the runs end to end '
                         '(analysis.runs.joined)')
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, filters,
                              powered_on_at_start=any(r.powered_on_at_start for r in runs),
                              run_starts=run_starts(runs), refined_start=True)
    error = log.rate_dps - log.ref_rate
    segments = steady_segments(log.t, log.ref_rate, settle_s, breaks=[r.first_row for r in runs])
    index = segments.rows()
    if index.size == 0:
        raise LogError('the log has no steady segments of constant ref_rate to fit')
    art_fit = fit_model(signals, error, rows, columns, (), index)
    # The heading is the integral of what the gyro reads once corrected (one more pass), not of the raw
    # reading, whose polynomial error and turn-on bias add hundreds of degrees in hours.
    signals = replace(signals, angle_correction=art_fit.model)
    residual = np.zeros(len(error))
    residual[index] = art_fit.residual
    art_model = art_fit.model
    del art_fit   # its residual is in ``residual``: one array as long as the log is enough
    floor = noise_floor(residual, segments)
    # A still gyro (one reference rate throughout) reads nothing but its error: a signal derived
    # from its rate would explain the error with itself, so none is a candidate.
    still = bool(np.ptp(log.ref_rate) == 0.0)
    binned = trace.Binned(signals, error, segments, rows, columns, options.folds, bin_s, block_s)
    noise = noise_levels(binned, trace.Screen(binned).residual() / binned.sqrt_counts, bin_s)
    if options.still_instability_dps is not None:
        noise = replace(noise, instability_dps=options.still_instability_dps)
    signals.forget()   # the rest of the loop takes its signals chunk by chunk
    instability_dph = noise.instability_dps * DEG_PER_H_PER_DPS
    materiality = noise.materiality_dph if options.materiality_dph is None else options.materiality_dph
    excluded = [*options.exclude, *(RATE_SIGNALS if still else ())]
    specs: list[TermSpec] = []
    rounds: list[trace.TraceResult] = []
    scores: list[trace.CandidateScore] = []
    strong: list[bool] = []   # per spec: its round's score beat the threshold by STRONG_FACTOR
    while len(rounds) < options.max_effects:
        # Held-out blocks at least as long as what the current model leaves stays correlated:
        # shorter ones share a slow residual with their neighbours, and any slow signal seems to predict it.
        if specs:
            residual[index] = fit_model(signals, error, rows, columns, specs, index, ranges=binned.ranges).residual
        binned.refold(max(block_s, correlation_time_s(signals.t, residual, segments)))
        found = trace.trace_residual(signals, error, segments, rows, columns, specs, options,
                                     materiality_dph=materiality, noise_floor_dps=floor,
                                     exclude=excluded + [s.signal for s in scores], binned=binned, still=still)
        rounds.append(found)
        best = found.best
        if best is None:
            break
        same = [i for i, spec in enumerate(specs) if spec.signal == best.spec.signal]
        if same:   # one term per signal in a calibration file: a second form on it joins the first
            merged = trace.joined(specs[same[0]], best.spec)
            assert merged is not None   # the screen offers a signal the model has only in a form that joins it
            specs[same[0]] = merged
            scores[same[0]] = best
            strong[same[0]] = strong[same[0]] and _strong(found)
        else:
            specs.append(best.spec)
            scores.append(best)
            strong.append(_strong(found))
        specs = retuned(binned, specs)
    # A square is judged once every effect is in the model, so it cannot stand in for one not yet found.
    specs = [_maybe_square(spec, binned, specs[:i] + specs[i + 1:], materiality, options)
             for i, spec in enumerate(specs)]
    # Every effect must lower the held-out error of the final model, every row counted (on the blocks
    # of the last round): one that passed its screen only given candidates that did not make it is dropped.
    # Not one that beat its round's chance by far: over one chamber cycle the held-out error of a temperature
    # term is how the polynomial extrapolates into a held-out block's temperatures.
    every_row = binned.row_folds(specs)
    while True:
        held_out_all = every_row.held_out_rms(specs)
        without = [every_row.held_out_rms(specs[:i] + specs[i + 1:]) for i in range(len(specs))]
        weak = [i for i in range(len(specs)) if not strong[i]]
        if not weak or min(without[i] for i in weak) > held_out_all:
            break
        weakest = min(weak, key=lambda i: without[i])
        del specs[weakest], scores[weakest], strong[weakest]
    final = fit_model(signals, error, rows, columns, specs, index, ranges=binned.ranges)
    effects = [Effect(term, score, rms_without, held_out_all)
               for term, score, rms_without in zip(final.model.terms, scores, without)]
    # A heading (or extra column's) effect helped fit the rest; the file gets the model refitted without it.
    heading = [e for e in effects if e.term.signal not in runnable]
    written = [spec for spec in specs if spec.signal in runnable]
    if heading:
        final = fit_model(signals, error, rows, columns, written, index, ranges=binned.ranges)
    low, high = float(np.floor(log.temp_c[index].min())), float(np.ceil(log.temp_c[index].max()))
    art = Calibration(options.serial_number, options.rate_scale_factor, art_model.polynomial,
                      (low, high if high > low else low + 1.0), options.temp_scale_factor, (), filters)
    # What the written model leaves, judged (in this order: the checks share the binned rows' caches).
    held_out_art = every_row.held_out_rms()
    alarm = adequacy(binned, written, floor, bin_s, materiality, options)
    residual_materiality = residual_materiality_dph(binned, written, materiality, bin_s, options)
    detection = detection_limits(binned, specs, rounds[-1], rows, columns, materiality, still,
                                 seed=options.seed) if rounds else ()
    return LoopResult(
        art=art, extended=replace(art, polynomial=final.model.polynomial, terms=final.model.terms),
        effects=tuple(e for e in effects if e not in heading), rounds=tuple(rounds), noise_floor_dps=floor,
        held_out_rms_art_dps=held_out_art, held_out_rms_extended_dps=held_out_all,
        held_out_block_s=every_row.block_s, signals=signals, error=error, segments=segments,
        materiality_dph=materiality, bias_instability_dph=instability_dph, adequacy=alarm, findings=tuple(heading),
        start=RunStart(powered_on_at_start=runs[0].powered_on_at_start),
        residual_materiality_dph=residual_materiality, detection=detection, runs=runs,
        run_offsets_dps=final.run_offsets_dps)


def node_signals(options: LoopOptions, columns: tuple[str, ...]) -> tuple[str, ...]:
    """``options.node_signals``, each checked: a column of the log (``columns``), not excluded, not derived."""
    for name in options.node_signals:
        if name in SIGNALS:
            raise ValueError(f'--node-signal {name}: {name} is derived from the gyro, not a log column fed by topic')
        if name not in columns:
            raise LogError(f'--node-signal {name}: the log has no column {name} '
                           f'(its extra columns: {", ".join(columns) or "none"})')
        if name in options.exclude:
            raise ValueError(f'--node-signal {name} and --exclude {name} contradict each other')
    return options.node_signals


# A term whose round score is this many times the round's threshold (standardised chance scores: an
# exponential tail, so by chance about exp(-threshold) times as rare as the threshold itself) is kept
# whatever the final held-out check says.
STRONG_FACTOR = 2.0


def _strong(found: trace.TraceResult) -> bool:
    """Whether the round's pick beat its threshold by :data:`STRONG_FACTOR`."""
    return found.best is not None and found.best.score >= STRONG_FACTOR * max(found.threshold_score, 1.0)


# A time constant found in an earlier round is sought again within this factor of it.
RETUNE_FACTOR = 2.0


def retuned(binned: trace.Binned, specs: list[TermSpec]) -> list[TermSpec]:
    """``specs`` with each time constant (or lag) fitted again given every other term.

    A time constant chosen while another effect was still in the residual is biased by it
    (a warm-up's, by a Shupe effect not yet modelled); left so, the next round finds a
    richer form that mends the bias, not an effect. Five time constants within
    :data:`RETUNE_FACTOR` (one pass over the log), then the vertex of the parabola in
    log(tau) through the best and its neighbours (one more); only the one kept stays cached.
    """
    out = list(specs)
    duration = trace.duration_s(binned.signals)
    for i, spec in enumerate(out):
        if spec.time_constant_s <= 0.0:
            continue
        screen = trace.Screen(binned, out[:i] + out[i + 1:])
        own = np.log(spec.time_constant_s)
        logs = np.unique(np.clip(own + np.log(RETUNE_FACTOR) * np.linspace(-1.0, 1.0, 5),
                                 *np.log(trace.time_constant_bounds(spec, duration))))
        # The spec itself where it is tried (exp(log(tau)) may differ in the last bit): cached.
        tried = [spec if x == own else replace(spec, time_constant_s=float(np.exp(x))) for x in logs]
        binned.candidate_means(tried)
        sse = np.array([screen.training_sse(v) for v in tried])
        k = int(np.clip(np.argmin(sse), 1, len(sse) - 2))
        curve = np.polyfit(logs[k - 1:k + 2], sse[k - 1:k + 2], 2) if len(sse) >= 3 else np.zeros(3)
        if curve[0] > 0.0:
            vertex = float(np.clip(-curve[1] / (2.0 * curve[0]), logs[0], logs[-1]))
            tried.append(replace(spec, time_constant_s=float(np.exp(vertex))))
            sse = np.append(sse, screen.training_sse(tried[-1]))
        out[i] = tried[int(np.argmin(sse))]
        binned.forget_means([v for v in tried if v not in (out[i], spec)])
    return out


# Stretches where the temperature holds (|dT/dt| below this, degC/s) for at least THERMAL_STILL_S: there
# no thermal effect, modelled or not, moves the bias, and what is left is the gyro's own wander.
THERMAL_STILL_RATE = 3e-3
THERMAL_STILL_S = 180.0
# Whether the temperature holds is read over minutes, whatever estimator the calibration's terms use (the node's
# fast one follows each count): the first-order derivative over 2 min, by which the threshold was chosen.
THERMAL_STILL_FILTERS = SignalFilters(FIRST_ORDER_TAU_S, temperature_rate_form=FIRST_ORDER)


def thermally_still_runs(binned: trace.Binned) -> NDArray[np.int64] | None:
    """Per bin, a label of its stretch of steady temperature (-1 for none); None if under 10 minutes in all."""
    s = binned.signals
    rate = compute_signals(s.t, s.rate, s.temperature, filters=THERMAL_STILL_FILTERS,
                           run_starts=s.run_starts).temperature_rate[binned.index[binned.starts]]
    still = np.abs(rate) <= THERMAL_STILL_RATE
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(np.int8), [0]))))
    labels = np.full(len(still), -1)
    t = binned.bin_times()
    total = 0.0
    # A stretch ends where a run of several does: the next begins at another time and temperature.
    new_run = np.flatnonzero(np.diff(binned.bin_runs)) + 1
    stretches = [(int(a), int(b)) for a0, b0 in zip(edges[::2], edges[1::2])
                 for a, b in zip([a0, *new_run[(new_run > a0) & (new_run < b0)]],
                                 [*new_run[(new_run > a0) & (new_run < b0)], b0])]
    for k, (a, b) in enumerate(stretches):
        if t[b - 1] - t[a] >= THERMAL_STILL_S:
            labels[a:b] = k
            total += t[b - 1] - t[a]
    return labels if total >= 2 * THERMAL_STILL_S else None


@dataclass(frozen=True)
class NoiseLevels:
    """What the gyro's own noise leaves in a residual's bin means, deg/s."""

    instability_dps: float   # bias instability: the floor of the Allan deviation / 0.664
    wander_dps: float        # spread of the means of the stretches where the temperature holds (0 if too few)

    @property
    def materiality_dph(self) -> float:
        """The smallest effect worth a term by default: the bias instability, deg/h.

        (Not the wander: every effect not yet modelled that is not thermal, a supply voltage
        say, wanders in the still stretches too, and would raise the bar against itself.)
        """
        return self.instability_dps * DEG_PER_H_PER_DPS


def noise_levels(binned: trace.Binned, bin_means: NDArray[np.float64], bin_s: float) -> NoiseLevels:
    """Bias instability and slow wander of a residual's bin means.

    Over the stretches where the temperature holds, if the log has 10 minutes of them (an
    unmodelled thermal effect would otherwise pass for noise); else over all the bins as
    one series (the rests between steady segments are short). The Allan floor is sought
    from one minute on, where the white noise has averaged down, as ``calibrate allan``
    reads it (:func:`.noise.allan_floor_dps`); the wander is the spread of the stretches'
    means (a gyro's bias wanders there too; a thermal effect does not).
    """
    runs = thermally_still_runs(binned)
    wander = 0.0
    values = bin_means
    if runs is not None:
        keep = runs >= 0
        weights = binned.sqrt_counts ** 2
        labels = np.unique(runs[keep])
        means = np.array([np.average(bin_means[runs == k], weights=weights[runs == k]) for k in labels])
        wander = float(np.std(means)) if len(means) > 1 else 0.0
        values, runs = bin_means[keep], runs[keep]
    rate_hz = 1.0 / max(bin_s, 1e-9)
    # The floor as ``calibrate allan`` reads it: of the IEEE 952 terms fitted to the deviation.
    return NoiseLevels(allan_floor_dps(allan_deviation(values, rate_hz, runs), rate_hz, 60.0), wander)


def residual_materiality_dph(binned: trace.Binned, specs: Sequence[TermSpec], materiality_dph: float, bin_s: float,
                             options: LoopOptions) -> float:
    """The materiality of what the polynomial + ``specs`` leave: the start-up check weighs term sets against it.

    ``materiality_dph`` (of what the polynomial alone leaves, effects included) if it is lower, or if
    the bias instability was measured on a still record (``options.still_instability_dps``).
    """
    if options.still_instability_dps is not None:
        return materiality_dph
    leaves = trace.Screen(binned, specs).residual() / binned.sqrt_counts
    return min(materiality_dph, noise_levels(binned, leaves, bin_s).materiality_dph)


# The residual's block means may exceed their noise budget by this factor before the alarm:
# the budget's bias instability is itself estimated from the same residual.
ADEQUACY_RATIO = 3.0
ADEQUACY_BLOCK_S = 600.0


def adequacy(binned: trace.Binned, specs: Sequence[TermSpec], floor_dps: float, bin_s: float,
             materiality_dph: float, options: LoopOptions = LoopOptions()) -> Adequacy:
    """The lack-of-fit alarm: whether the held-out residual's 10-minute means stay within the noise budget.

    The budget of a 10-minute mean: the white noise over its rows, the bias instability and
    the slow wander of :func:`noise_levels`. The model is inadequate when the residual is
    beyond :data:`ADEQUACY_RATIO` times its budget by more than the materiality, or when it
    has a shape against a signal beyond chance and the materiality (:func:`signal_shapes`):
    an effect that averages out over a block escapes the budget. The bias instability is the
    one of a still record where one was measured (``options.still_instability_dps``).
    """
    # A bin the other folds' fit predicts poorly (a rare rate: its leverage) weighs by its held-out variance.
    residual, inflation = trace.held_out_residual(binned, specs)
    residual /= binned.sqrt_counts   # held-out bin means, deg/s
    weights = binned.sqrt_counts ** 2 / inflation
    t = binned.bin_times()
    block = np.floor((t - t[0]) / ADEQUACY_BLOCK_S).astype(np.int64)
    counts = np.bincount(block, weights=weights)
    sums = np.bincount(block, weights=residual * weights)
    full = counts >= 0.5 * counts.max()
    means = sums[full] / counts[full]
    rms = float(np.sqrt(np.mean((means - means.mean()) ** 2)))
    noise = noise_levels(binned, residual, bin_s)
    if options.still_instability_dps is not None:
        noise = replace(noise, instability_dps=options.still_instability_dps)
    budget = float(np.sqrt(floor_dps ** 2 / np.mean(counts[full]) + (0.664 * noise.instability_dps) ** 2
                           + noise.wander_dps ** 2))
    excess = float(np.sqrt(max(rms ** 2 - budget ** 2, 0.0)))
    adequate = not (rms > ADEQUACY_RATIO * budget and excess * DEG_PER_H_PER_DPS > materiality_dph)
    shapes = signal_shapes(binned, residual, inflation, materiality_dph, bin_s, options)
    adequate = adequate and not any(shape.found for shape in shapes)
    return Adequacy(adequate, ADEQUACY_BLOCK_S, rms * DEG_PER_H_PER_DPS, budget * DEG_PER_H_PER_DPS,
                    excess * DEG_PER_H_PER_DPS, noise.instability_dps * DEG_PER_H_PER_DPS, shapes)


# The heading's sectors are 360 / SHAPE_GROUPS degrees; other signals are grouped by level, else by equal widths,
# else (fewer groups than this) by equal counts (signal_groups).
SHAPE_GROUPS = 12
# A signal that holds at most SHAPE_LEVELS levels (a rate table's steps) is grouped by level: equal counts split
# one step between two groups with its neighbours, and a bump at that step is diluted below chance. Levels are
# split where the sorted values leap by more than LEVEL_GAP of their range: a rate table's steps are 1 deg/s apart
# in 200, its noise a few thousandths; a ramped temperature or a supply voltage leaps nowhere near that.
SHAPE_LEVELS = 32
LEVEL_GAP = 1e-3
LEVEL_WIDTH = 0.5   # and each level spans less than this share of the leaps beside it
SHAPE_BINS = 24     # other signals: groups of equal width over their central values
TAIL_SHARE = 0.01   # the share of the values at either end beyond those
# A group of less than this share of the weight is left out of the statistics and the size: a few bins (a
# restart's turn) are one moment of the wander, not a shape (such a group alone can raise a false alarm).
MIN_LEVEL_SHARE = 0.5 / SHAPE_LEVELS
# Each statistic is scaled by this quantile of its chance copies: by their median, the spread over few groups (a
# long tail) set the level chance reaches for all, and a bump well beyond its own copies went unfound.
SHAPE_SCALE_QUANTILE = 0.9
# Chance copies of the residual grouped at a time, over all signals.
SHAPE_DRAW_BATCH = 25
# A group seen again after this long away is visited again (cross_fitted): a chamber ramp's temperature comes
# back after the hold at the other end (15 min), a clock never.
REVISIT_S = 600.0
# The signals the form-free check looks at beside every extra log column; the heading modulo 360 degrees.
SHAPE_SIGNALS = ('rate', 'temperature', 'temperature_rate', 'time_since_power_on', 'angle', 'rate_change')


def signal_groups(x: NDArray[np.float64], circular: bool = False) -> NDArray[np.int64]:
    """The group of each value of a signal, for the form-free check.

    Its level if it holds a few (:data:`SHAPE_LEVELS`: a rate table's steps); else
    :data:`SHAPE_BINS` groups of equal width over its central values, a group of fewer than
    :data:`MIN_LEVEL_SHARE` of the values joined to the next; equal counts if that leaves fewer
    than :data:`SHAPE_GROUPS`. ``circular``: a heading in degrees, in sectors of its value modulo 360.
    """
    if circular:
        return np.floor(np.mod(x, 360.0) / (360.0 / SHAPE_GROUPS)).astype(np.int64) % SHAPE_GROUPS
    order = np.sort(x)
    leaps = np.flatnonzero(np.diff(order) > LEVEL_GAP * (order[-1] - order[0]))
    if 0 < len(leaps) < SHAPE_LEVELS:
        # Levels, if each is narrow beside the leaps to its neighbours (a continuous signal may leap in a few
        # places; the measured rate's levels widen with the rate, by the gyro's scale factor over temperature).
        widths = order[np.append(leaps, -1)] - order[np.insert(leaps + 1, 0, 0)]
        gaps = np.concatenate([[np.inf], order[leaps + 1] - order[leaps], [np.inf]])
        if np.all(widths < LEVEL_WIDTH * np.minimum(gaps[:-1], gaps[1:])):
            return np.searchsorted(0.5 * (order[leaps] + order[leaps + 1]), x).astype(np.int64)
    # Equal widths over the central values (the tails join the end groups), a narrow group joined to the next:
    # equal counts gave the chamber's holds ten groups and a ramp two, and a bump on the ramp was diluted.
    low, high = np.quantile(x, [TAIL_SHARE, 1.0 - TAIL_SHARE])
    g = np.searchsorted(np.linspace(low, high, SHAPE_BINS + 1)[1:-1], x, side='right')
    counts = np.bincount(g, minlength=SHAPE_BINS)
    merged = np.empty(SHAPE_BINS, dtype=np.int64)
    group, held = 0, 0
    for b in range(SHAPE_BINS):
        merged[b] = group
        held += counts[b]
        if held >= MIN_LEVEL_SHARE * len(x) and counts[b + 1:].sum() >= MIN_LEVEL_SHARE * len(x):
            group, held = group + 1, 0
    if group + 1 >= SHAPE_GROUPS:
        return merged[g]
    # A peaked signal (the rate change: most bins at rest) leaves few groups of equal width: a spread over few
    # groups has a long tail by chance, which raised the level chance reaches for every signal.
    edges = np.quantile(x, np.linspace(0.0, 1.0, SHAPE_GROUPS + 1)[1:-1])
    return np.searchsorted(edges, x, side='right').astype(np.int64)


def cross_fitted(groups: NDArray[np.int64], t: NDArray[np.float64], weights: NDArray[np.float64],
                 residual: NDArray[np.float64]) -> NDArray[np.float64]:
    """``residual`` less its shape against a signal, each visit's part taken from the group's other visits.

    A visit: a group's bins with no :data:`REVISIT_S` away between them. Each visit loses its
    group's weighted mean over the other visits: a shape repeated at every visit goes; a
    wander, different at each, is not fitted away but added to (chance errs towards too much,
    not too little); a group visited once (a clock's) keeps all.
    """
    order = np.lexsort((t, groups))
    g = groups[order]
    new_visit = np.concatenate([[True], (g[1:] != g[:-1]) | (np.diff(t[order]) > REVISIT_S)])
    visit = np.empty(len(groups), dtype=np.int64)
    visit[order] = np.cumsum(new_visit) - 1
    group_sum = np.bincount(groups, weights=weights * residual)[groups]
    group_weight = np.bincount(groups, weights=weights)[groups]
    others = group_weight - np.bincount(visit, weights=weights)[visit]
    seen = others > 1e-9 * group_weight
    out = residual.copy()
    out[seen] -= (group_sum - np.bincount(visit, weights=weights * residual)[visit])[seen] / others[seen]
    return out


def shape_scores(means: NDArray[np.float64], shares: NDArray[np.float64]) -> NDArray[np.float64]:
    """A signal's score for the residual and each chance copy (columns of ``means``, group means, residual first).

    ``means`` and ``shares``: of the groups :func:`signal_shapes` keeps (:data:`MIN_LEVEL_SHARE`).
    The larger of two statistics, each over its :data:`SHAPE_SCALE_QUANTILE` among the copies:
    the weighted spread of the group means (a shape across the signal's range) and the largest
    group mean over its own spread among the copies (a shape in one group, a bump at some
    temperatures, can stand out by this one alone).
    """
    spread = shares @ means ** 2
    own_spread = np.sqrt(np.mean(means[:, 1:] ** 2, axis=1))
    peak = np.max(np.abs(means) / np.maximum(own_spread, 1e-300)[:, None], axis=0)
    return np.asarray(np.maximum(spread / max(float(np.quantile(spread[1:], SHAPE_SCALE_QUANTILE)), 1e-300),
                                 peak / max(float(np.quantile(peak[1:], SHAPE_SCALE_QUANTILE)), 1e-300)),
                      dtype=np.float64)


def _group_means(groups: NDArray[np.int64], weights: NDArray[np.float64],
                 values: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weighted means of ``values`` (columns) per group, less the overall mean, shape (groups, columns)."""
    total = np.asarray(np.bincount(groups, weights=weights), dtype=np.float64)
    out = np.stack([np.asarray(np.bincount(groups, weights=weights * v, minlength=len(total)), dtype=np.float64)
                    for v in values.T], axis=1)
    out /= np.maximum(total, 1e-300)[:, None]
    overall = (weights @ values) / weights.sum()
    out -= overall
    out[total == 0.0] = 0.0
    return out


def signal_shapes(binned: trace.Binned, residual: NDArray[np.float64], inflation: NDArray[np.float64],
                  materiality_dph: float, bin_s: float,
                  options: LoopOptions = LoopOptions()) -> tuple[SignalShape, ...]:
    """The held-out residual (bin means, deg/s) against each signal the loop knows, with no form assumed.

    Per signal, the residual's weighted means in groups of the signal's value at each bin
    (:func:`signal_groups`; weighted by the inverse of its held-out variance: ``inflation``, see
    :func:`trace.held_out_residual`); the score is :func:`shape_scores`. Chance: ``options.draws``
    phase-randomised copies of the residual (its own memory, as the loop's screen draws them)
    less the signal's shape (:func:`cross_fitted`, as the screen takes out its strongest
    candidate), scored alike, and the ``1 - options.alpha`` quantile of the largest score over
    the signals: one level for all.
    A shape beyond chance is weighed against the materiality read from the residual without it
    (unless the materiality was given, or measured on a still record): the shape is in the
    residual the loop read its bias instability from, and would raise it against itself.
    """
    signals = binned.signals
    rows = binned.index[binned.starts]
    # A signal computed from the measured rate holds that row's noise, which is in the bin's residual too:
    # it is read one row before the bin (the rate change's filter forgets in half a second, a bin is longer).
    before = np.maximum(rows - 1, 0)
    names = [n for n in SHAPE_SIGNALS if n != 'time_since_power_on' or signals.powered_on_at_start]
    names += list(signals.extras)
    # A held-out bin's residual carries the error of the fit made without it, as wide as its leverage
    # (``inflation``): a rate step met once in a short log, held out, leaves a large residual in a log with no
    # effect at all, a false alarm against the rate. Weighted by the inverse of their variance, and the
    # chance copies drawn from the residual standardised by it and given it back, such bins weigh as they should.
    spread_of = np.sqrt(inflation)
    weights = binned.sqrt_counts ** 2 / spread_of ** 2
    if not names or len(residual) < 4 * SHAPE_GROUPS:
        return ()
    groups = [signal_groups(_finite(np.asarray(signals.get(name))[before if name in RATE_SIGNALS else rows]),
                            name == 'angle') for name in names]
    share = weights / weights.sum()
    shares = [np.asarray(np.bincount(g, weights=share), dtype=np.float64) for g in groups]
    own = [_group_means(g, weights, residual[:, None])[:, 0] for g in groups]
    # Chance copies keep the residual's memory but not the shape under test: a function of the temperature over
    # a chamber's repeated cycles is periodic, and copies with its spectrum repeat a shape as large as it on every
    # cycle, and the shape would hide below the chance it sets. The shape is taken out cross-fitted: the group
    # means themselves would take out the wander they hold too, and a slow signal (the time since power-on, a
    # supply voltage) would then score high by chance.
    t = np.asarray(signals.t)[rows]
    spectra = [trace.mirrored_spectrum(cross_fitted(g, t, weights, residual) / spread_of) for g in groups]
    means = [np.empty((len(w), options.draws + 1)) for w in shares]   # per signal: group means, residual first
    for m, own_means in zip(means, own):
        m[:, 0] = own_means
    # The copies a few at a time (a 24 h log's 200 copies would hold 140 MiB a signal), every signal's with the
    # same phases: they are drawn together, as their largest score is.
    rng = np.random.default_rng(options.seed)
    batch = max(1, SHAPE_DRAW_BATCH // len(groups))
    for done in range(0, options.draws, batch):
        count = min(batch, options.draws - done)
        for g, m, values in zip(groups, means, trace.phase_surrogates_alike(spectra, count, rng)):
            m[:, 1 + done:1 + done + count] = _group_means(g, weights, values[:len(residual)] * spread_of[:, None])
    kept = [w >= MIN_LEVEL_SHARE for w in shares]   # a level of a few bins (a restart's turn) is one moment
    scores = np.stack([shape_scores(m[k], w[k]) for m, w, k in zip(means, shares, kept)])
    shape_dph = np.array([0.5 * np.ptp(m[k]) for m, k in zip(own, kept)]) * DEG_PER_H_PER_DPS
    chance = float(np.quantile(scores[:, 1:].max(axis=0), 1.0 - options.alpha))
    signals.forget()   # the derived signals read here are as long as the log
    measured = options.materiality_dph is None and options.still_instability_dps is None
    found = []
    for i in range(len(names)):
        bar = materiality_dph
        if measured and scores[i, 0] > chance and shape_dph[i] <= bar:
            bar = min(bar, noise_levels(binned, residual - own[i][groups[i]], bin_s).materiality_dph)
        found.append(bool(scores[i, 0] > chance and shape_dph[i] > bar))
    return tuple(SignalShape(name, float(shape_dph[i]), float(scores[i, 0]), chance, found[i])
                 for i, name in enumerate(names))


def _finite(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x`` with an infinite value held at the largest finite one.

    A warm run's time since power-on (infinite: its warm-up has decayed) joins the latest times of
    the cold runs beside it in a several-run fit.
    """
    infinite = np.isposinf(x)
    if not infinite.any() or infinite.all():
        return x
    return np.where(infinite, np.max(x[~infinite]), x)


def _maybe_square(spec: TermSpec, binned: trace.Binned, specs: list[TermSpec], materiality_dph: float,
                  options: trace.ScreenOptions) -> TermSpec:
    """``spec`` with powers [1, 2] if the square beats chance, lowers the held-out error and its curvature is material.

    Chance as the screen judges a candidate (:func:`trace.trace_residual`): what the square explains
    beyond the model with the line, against ``options.draws`` phase-randomised copies of what that
    model leaves, at level ``options.alpha``. On a heating's one decay the line and the square are
    alike, and a wander took the square in (a Shupe gyro's linear term written as 0.04 + 10 r^2).
    The curvature is the square's part that a straight line in the signal cannot give, half its
    range over the logged envelope.
    """
    if spec.form != 'power' or spec.powers != (1,) or spec.signal not in _SQUARABLE + tuple(binned.signals.extras):
        return spec
    squared = replace(spec, powers=(1, 2))
    line = trace.Screen(binned, specs + [spec])
    if trace.Screen(binned, specs + [squared]).base_sse() >= line.base_sse():
        return spec
    family = {'square': [replace(spec, powers=(2,))]}
    residual = line.residual()
    held_out = {'square': float(line.held_out_improvements(family, residual[:, None])['square'][0])}
    spectrum = trace.null_spectrum(line, family, residual, held_out)
    rng = np.random.default_rng(options.seed)
    chance = np.concatenate([line.explained(family, trace.phase_surrogates(
        spectrum, min(trace.SURROGATE_BATCH, options.draws - start), rng)[:len(residual)])['square'][0]
        for start in range(0, options.draws, trace.SURROGATE_BATCH)])
    if line.explained(family, residual[:, None])['square'][0, 0] <= np.quantile(chance, 1.0 - options.alpha):
        return spec
    _, beta = trace.Screen(binned, specs).fit_with(squared)
    means = binned.candidate_means([squared])[:, 0, :]
    line_fit = np.column_stack([np.ones(len(means)), means[:, 0]])
    bend = means[:, 1] - line_fit @ np.linalg.lstsq(line_fit, means[:, 1], rcond=None)[0]
    return squared if 0.5 * np.ptp(bend * beta[1]) * DEG_PER_H_PER_DPS >= materiality_dph else spec
