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
:func:`startup_check` does the same on the fitted log itself, which every fit has: from
its power-on, as a node started cold sees it, and on warm restarts. A term fitted to the
slow noise of one run (a long coil lag, say) can fit it well from power-on and still shift
the static bias of a node started later; a short warm-up that stands in for what the
causal temperature-rate filter misses after power-on fits the log, yet the node's static
bias refinement puts that back too, and a cold start carries it twice for the whole mission.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.fit import TermSpec, fit_model
from art_gyro_calibration.analysis.loop import LoopResult
from art_gyro_calibration.analysis.metrics import DEFAULT_SETTLE_S, FieldErrors, field_errors, steady_segments
from art_gyro_calibration.calibration import Calibration
from art_gyro_calibration.compensation import Applied, RunStart, apply_calibration
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.signals import POWER_ON_SIGNAL, Signals
from art_gyro_calibration.static_bias import DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, DEFAULT_SAMPLES, MotionError
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS


@dataclass(frozen=True)
class Replay:
    """One calibration on one run: the node's output, its error against the table (per kept row), field errors."""

    applied: Applied
    error_dps: NDArray[np.float64]
    field: FieldErrors


def replay(log: GyroLog, calibration: Calibration, bias_samples: int = DEFAULT_SAMPLES,
           settle_s: float = DEFAULT_SETTLE_S, start: RunStart = RunStart(),
           max_mean_dps: float = DEFAULT_MAX_MEAN_DPS, max_std_dps: float = DEFAULT_MAX_STD_DPS,
           signals: Signals | None = None) -> Replay:
    """Apply ``calibration`` to ``log`` as the node does and measure it from the end of the static bias.

    ``start``: how the run began, as the node is told (a warm-up applies only from a declared
    power-on). The rows the node would drop (:func:`compensation.plausible`) are left out.
    ``signals``: the run's, made once for several calibrations (:func:`compensation.run_signals`).
    Raises :class:`static_bias.MotionError` when the run's first ``bias_samples`` rows show motion.
    """
    if log.ref_rate is None:
        raise LogError('the log has no ref_rate column: a replay measures against the rate table\'s true rate')
    applied = apply_calibration(log, calibration, bias_samples, max_mean_dps, max_std_dps, start=start,
                                signals=signals)
    seen = log if applied.kept.all() else log.slice(applied.kept)
    assert seen.ref_rate is not None   # the log's, sliced with it
    error = applied.corrected_dps - seen.ref_rate
    return Replay(applied, error, field_errors(seen.t, error, steady_segments(seen.t, seen.ref_rate, settle_s),
                                               bias_samples))


def replay_anyway(log: GyroLog, calibration: Calibration, bias_samples: int = DEFAULT_SAMPLES,
                  settle_s: float = DEFAULT_SETTLE_S, start: RunStart = RunStart(),
                  checked: bool = True, signals: Signals | None = None) -> tuple[Replay, bool]:
    """:func:`replay`, also where the node would refuse the static bias, and whether it would have.

    Such a run is measured with the bias taken anyway; not ``checked``, the node's motion
    checks are off and nothing is refused.
    """
    if checked:
        try:
            return replay(log, calibration, bias_samples, settle_s, start, signals=signals), False
        except MotionError:
            pass
    anyway = replay(log, calibration, bias_samples, settle_s, start, max_mean_dps=math.inf, max_std_dps=math.inf,
                    signals=signals)
    return anyway, checked


def replay_field(log: GyroLog, calibration: Calibration, bias_samples: int = DEFAULT_SAMPLES,
                 settle_s: float = DEFAULT_SETTLE_S, start: RunStart = RunStart(), checked: bool = True) -> FieldErrors:
    """:func:`replay_anyway`'s field errors; a run whose static bias the node would refuse: ``bias_refused``."""
    done, refused = replay_anyway(log, calibration, bias_samples, settle_s, start, checked)
    return replace(done.field, bias_refused=refused) if refused else done.field


def restart(log: GyroLog, start_s: float) -> GyroLog:
    """The run as a node started ``start_s`` after its first sample sees it (a warm restart)."""
    if not 0.0 <= start_s < log.t[-1] - log.t[0]:
        raise ValueError(f'start {start_s} s is not within the log\'s {log.t[-1] - log.t[0]:.1f} s')
    return log.slice(slice(int(np.searchsorted(log.t, log.t[0] + start_s)), None))


# Where the start-up check restarts the fitted log: late enough for the warm-up to have passed and the
# restart's static bias to sit elsewhere in the chamber cycle, early enough to leave an hour of a 2 h log.
RESTART_FRACTIONS = (0.25, 0.5)
# How the drops of the start-up check name the runs they were judged on.
RESTARTS_NAME = 'the fitted log\'s restarts'
OWN_RUNS_NAME = 'the fitted log\'s cold start and restarts'
# How the start-up check names the fitted log replayed from its own power-on.
COLD_START_NAME = 'from the log\'s power-on'


def own_restarts(log: GyroLog, bias_samples: int = DEFAULT_SAMPLES,
                 fractions: Sequence[float] = RESTART_FRACTIONS) -> list[tuple[float, GyroLog]]:
    """Warm restarts of ``log`` itself, as (start in s, run): one from each fraction of its duration on.

    Each begins at the first ``bias_samples`` rows from there on over which the table stands
    still, as a node's static bias needs; a fraction after which the table never stands
    still that long gives none.
    """
    if log.ref_rate is None:
        raise LogError('the log has no ref_rate column: a restart needs the table standing still')
    still = (log.ref_rate == 0.0).astype(float)
    # Row i starts a still stretch when rows i .. i + bias_samples - 1 all stand still.
    starts = np.flatnonzero(np.convolve(still, np.ones(bias_samples), 'valid') >= bias_samples - 0.5)
    duration = log.t[-1] - log.t[0]
    out: list[tuple[float, GyroLog]] = []
    for fraction in fractions:
        later = starts[starts >= np.searchsorted(log.t, log.t[0] + fraction * duration)]
        if later.size:
            out.append((float(log.t[later[0]] - log.t[0]), log.slice(slice(int(later[0]), None))))
    return out


def _warm_up(calibration: Calibration) -> tuple[Term | None, float]:
    """``calibration``'s warm-up term (None without one) and its size at power-on, deg/h."""
    warm_up = next((t for t in calibration.terms if t.signal == POWER_ON_SIGNAL), None)
    return warm_up, 0.0 if warm_up is None else abs(warm_up.evaluate_one(0.0)) * DEG_PER_H_PER_DPS


def unapplied_warm_up(calibration: Calibration, start: RunStart) -> str:
    """Why ``calibration``'s warm-up term is not applied on a run begun as ``start`` ('' when it is, or has none)."""
    warm_up, amplitude_dph = _warm_up(calibration)
    if warm_up is None or start.powered_on_at_start:
        return ''
    return (f'the warm-up term ({amplitude_dph:.1f} deg/h at power-on) is not applied: the log is not known to start '
            'at the gyro\'s power-on, so the term counts as decayed, as the node does by default; '
            '--powered-on-at-start applies it from the first row')


def unjudged_warm_up(calibration: Calibration, bias_instability_dph: float) -> str:
    """Why ``calibration``'s warm-up term needs a cold run to judge it ('' without one).

    Neither the fitted log (one power-on) nor its restarts (power-on unknown) can tell a
    warm-up from a wander of the bias that happens to start high: on every cold start the
    node applies the term, and one fitted to noise is then a bias of about its amplitude
    (several times the bias instability). The amplitude is given beside the log's bias
    instability: a person can tell a large warm-up from a small wander, where a fixed ratio
    would be tuned to one simulator.
    """
    warm_up, amplitude_dph = _warm_up(calibration)
    if warm_up is None:
        return ''
    return (f'the warm-up term ({amplitude_dph:.1f} deg/h at power-on; the log\'s bias instability is '
            f'{bias_instability_dph:.2f} deg/h) was judged on this log alone: if it is the bias wandering at the '
            'start of this run, a node told powered_on_at_start is off by about that much on every cold start; '
            'judge it on another cold run (--validate COLD_LOG --validate-powered-on-at-start)')


def without_terms(calibration: Calibration) -> Calibration:
    """The report's calibration: the same polynomial and scale factors, no extended terms."""
    return replace(calibration, terms=())


@dataclass(frozen=True)
class Dropped:
    """A term dropped because the replayed runs were better without it."""

    term: Term
    reason: str


@dataclass(frozen=True)
class Validation:
    """Field errors per validation run and calibration, and the calibration to write."""

    calibration: Calibration
    runs: tuple[dict[str, FieldErrors], ...]
    dropped: tuple[Dropped, ...]


def field_score_dps(errors: Sequence[FieldErrors]) -> float:
    """One number to compare calibrations on runs: rms of their systematic rms (bias included).

    Infinite when the node would refuse a run's static bias.
    """
    if any(e.bias_refused for e in errors):
        return math.inf
    return float(np.sqrt(np.mean([e.systematic_rms_dps ** 2 for e in errors])))


def validate(result: LoopResult, logs: Sequence[GyroLog], bias_samples: int = DEFAULT_SAMPLES,
             settle_s: float = DEFAULT_SETTLE_S, start: RunStart | Sequence[RunStart] = RunStart(),
             kept_signals: Sequence[str] = (), margin_dps: float = 0.0, strict: bool = True,
             runs_name: str = 'the validation runs', simplest_margin_dps: float | None = None) -> Validation:
    """Replay ``result``'s calibrations on ``logs``; drop each term the runs are better without.

    Terms are dropped one at a time, the one whose removal helps most first; the rest are
    refitted jointly with the polynomial on the fitted log (the loop's signals, error and
    steady rows) before the next comparison. Calibrations per run: ``art``, ``extended``
    and, when terms were dropped, ``validated`` (the one to write). ``start``: how the runs started
    (one for all, or one per run).
    Terms on ``kept_signals`` are never dropped (the runs cannot judge them); a term is dropped
    only when the runs are better without it by more than ``margin_dps`` (:func:`field_score_dps`):
    all of them, or the cold starts among them with the others not worse by more (:func:`_gain_without`).
    A run whose static bias the node refuses with the report's calibration raises
    :class:`static_bias.MotionError` if ``strict``; else (a noisy gyro the node's default checks
    refuse) it is measured with the checks off for every calibration: the refusal is not the terms'.
    ``runs_name`` names the runs in the reasons of the drops. With ``simplest_margin_dps``, the terms
    left are then judged against each term alone (:func:`_simplest`): the set with the fewest
    coefficients within that margin of the best on every run is written.
    """
    if not logs:
        raise ValueError('validation needs at least one run')
    starts = [start] * len(logs) if isinstance(start, RunStart) else list(start)
    if len(starts) != len(logs):
        raise ValueError(f'{len(starts)} run starts for {len(logs)} runs')
    art: list[FieldErrors] = []
    checked: list[bool] = []
    for i, (log, how) in enumerate(zip(logs, starts)):
        try:
            art.append(replay(log, result.art, bias_samples, settle_s, how).field)
            checked.append(True)
        except MotionError as e:
            if strict:
                raise MotionError(f'run {i + 1} of {len(logs)}: with the report\'s calibration alone: {e}') from None
            art.append(replay_field(log, result.art, bias_samples, settle_s, how, checked=False))
            checked.append(False)

    def field(calibration: Calibration) -> list[FieldErrors]:
        return [replay_field(log, calibration, bias_samples, settle_s, how, ok)
                for log, how, ok in zip(logs, starts, checked)]

    extended = field(result.extended)
    current, current_errors = result.extended, extended
    dropped: list[Dropped] = []
    cold = [how.powered_on_at_start for how in starts]
    while True:
        judged = [i for i, term in enumerate(current.terms) if term.signal not in kept_signals]
        if not judged:
            break
        options = [_refit(result, current.terms[:i] + current.terms[i + 1:]) for i in judged]
        options_errors = [field(c) for c in options]
        gains = [_gain_without(current_errors, errors, cold, margin_dps) for errors in options_errors]
        best = int(np.argmax([g.dps for g in gains]))
        gain = gains[best]
        if not gain.dps > margin_dps:
            break
        term = current.terms[judged[best]]
        with_it = ('the node refuses a static bias with it (the still gyro reads as turning)'
                   if math.isinf(gain.with_it_dps)
                   else f'systematic rms with the bias {gain.with_it_dps * DEG_PER_H_PER_DPS:.2f} deg/h with it')
        needed = f' (a drop needs more than {margin_dps * DEG_PER_H_PER_DPS:.2f} deg/h)' if margin_dps else ''
        where = ' on their cold starts (the others not worse by more)' if gain.cold_alone else ''
        dropped.append(Dropped(term, f'{runs_name} are better without it{where}: {with_it}, '
                                     f'{gain.without_dps * DEG_PER_H_PER_DPS:.2f} deg/h without{needed}'))
        current, current_errors = options[best], options_errors[best]
    if simplest_margin_dps is not None:
        current, current_errors, dropped = _simplest(result, current, current_errors, dropped, field, kept_signals,
                                                     simplest_margin_dps, runs_name)
    runs: list[dict[str, FieldErrors]] = []
    for i in range(len(logs)):
        run = {'art': art[i], 'extended': extended[i]}
        if dropped:
            run['validated'] = current_errors[i]
        runs.append(run)
    return Validation(current, tuple(runs), tuple(dropped))


class _Gain(NamedTuple):
    """How much better the judged runs are without a term (``dps``, -inf: not), and their scores (deg/s)."""

    dps: float
    cold_alone: bool        # judged on the cold starts alone
    with_it_dps: float
    without_dps: float


def _gain_without(with_it: Sequence[FieldErrors], without: Sequence[FieldErrors], cold: Sequence[bool],
                  margin_dps: float) -> _Gain:
    """How much better the runs are without a term, and whether the cold starts alone say so.

    A term acting at power-on (a warm-up, a fast lag of the self-heating) moves the static bias of
    the cold starts alone; pooled with the restarts, two a run, its harm there is diluted below the
    margin, and a lab's several runs dilute it no less. So the cold starts are judged apart too,
    when the other runs are not worse without the term by more than ``margin_dps``.
    """
    def gain(runs: tuple[bool, ...]) -> _Gain:
        now = field_score_dps([e for e, c in zip(with_it, cold) if c in runs])
        then = field_score_dps([e for e, c in zip(without, cold) if c in runs])
        return _Gain(-math.inf if math.isnan(now - then) else now - then, runs == (True,), now, then)

    pooled = gain((True, False))
    if all(cold) or not any(cold) or -gain((False,)).dps > margin_dps:
        return pooled
    alone = gain((True,))
    return alone if alone.dps > pooled.dps else pooled


def _coefficients(calibration: Calibration) -> int:
    return sum(len(t.coefficients) for t in calibration.terms)


def _simplest(result: LoopResult, current: Calibration, errors: list[FieldErrors], dropped: list[Dropped],
              field: Callable[[Calibration], list[FieldErrors]], kept_signals: Sequence[str], margin_dps: float,
              runs_name: str) -> tuple[Calibration, list[FieldErrors], list[Dropped]]:
    """Among ``current`` and each term the loop found alone (with the kept ones): the fewest coefficients in the margin.

    Correlated terms stand in for one another: a short lag beside a temperature rate of the
    wrong sign, a 30 s warm-up, together mimic the one Shupe term, fit the log as well, and
    can still leave a cold start worse. So a set with fewer coefficients is written if on
    every run it is within ``margin_dps`` of the best set there: a combination is kept only
    if it beats the simpler set by more than chance on some run (a warm-up, say, on the cold
    start, the one run that applies it). (Not the polynomial alone: a term is dropped for
    doing nothing only when the runs are better without it.)
    """
    judged = [t for t in result.extended.terms if t.signal not in kept_signals]
    if len(judged) < 2:
        return current, errors, dropped
    sets = [(current, errors)]
    for term in judged:
        alone = _refit(result, tuple(t for t in result.extended.terms if t is term or t.signal in kept_signals))
        sets.append((alone, field(alone)))
    if any(math.isinf(field_score_dps(e)) for _, e in sets):
        return current, errors, dropped
    per_run = np.array([[e.systematic_rms_dps for e in run_errors] for _, run_errors in sets])
    within = np.all(per_run <= per_run.min(axis=0) + margin_dps, axis=1)
    simpler = [k for k in range(1, len(sets)) if within[k]
               and _coefficients(sets[k][0]) < _coefficients(current)]
    if not simpler:
        return current, errors, dropped
    pick = min(simpler, key=lambda k: (_coefficients(sets[k][0]), field_score_dps(sets[k][1])))
    chosen, chosen_errors = sets[pick]
    chosen_signals = ', '.join(t.signal for t in chosen.terms)
    worst = float(np.max(per_run[pick] - per_run.min(axis=0))) * DEG_PER_H_PER_DPS
    reason = (f'{runs_name} are as good with {chosen_signals} alone: '
              f'{field_score_dps(chosen_errors) * DEG_PER_H_PER_DPS:.2f} deg/h, '
              f'against {field_score_dps(errors) * DEG_PER_H_PER_DPS:.2f} with '
              f'{", ".join(t.signal for t in current.terms)}, and on each run within {worst:.2f} deg/h of the best '
              f'set (chance: {margin_dps * DEG_PER_H_PER_DPS:.2f} deg/h; fewer coefficients win)')
    kept = {t.signal for t in chosen.terms}
    gone = {d.term.signal for d in dropped}
    return chosen, chosen_errors, [d for d in dropped if d.term.signal not in kept] + [
        Dropped(t, reason) for t in result.extended.terms if t.signal not in kept | gone]


def startup_check(result: LoopResult, log: GyroLog, bias_samples: int = DEFAULT_SAMPLES,
                  settle_s: float = DEFAULT_SETTLE_S) -> tuple[LoopResult, Validation | None, list[str]]:
    """Judge ``result``'s terms on the log it was fitted on, as the node would run on it.

    The runs: the log from its own start as a cold start, when it began at the gyro's power-on
    (``result.start``) at rest, and its warm restarts (:func:`own_restarts`). A fit of several
    runs (``result.runs``): every run's start, cold (from its power-on) or warm (a restart, as
    the node started on a warm gyro sees it), and every run's own restarts. Returns the result
    with the terms dropped that the runs are better without by more than the loop's
    materiality (the rest refitted, its effects those kept), the check (None when there was
    nothing to check: no term, or no run the node could start) and a name per run. Without a
    cold start a warm-up is kept: a restart, power-on unknown, cannot judge it. A set with fewer
    coefficients (one term alone) is then written if on every run it is as good as the best within
    the noise the written model leaves (:func:`_simplest`).
    """
    if not result.extended.terms:
        return result, None, []
    runs = _node_starts(result, log, bias_samples)
    cold = any(how.powered_on_at_start for _, _, how in runs)
    if not runs:
        return result, None, []
    names = [name for name, _, _ in runs]
    # The restarts are an hour or two of one run: a true term that matters little can score a few tenths of
    # a deg/h worse on them by chance, where a term fitted to noise that shifts the static bias scores worse by
    # several deg/h. Term sets are weighed against the noise the written model leaves: the loop's materiality
    # also holds what the polynomial alone left of the effects.
    chance = result.residual_materiality_dph or result.materiality_dph
    check = validate(result, [run for _, run, _ in runs], bias_samples, settle_s, [how for _, _, how in runs],
                     kept_signals=() if cold else (POWER_ON_SIGNAL,),
                     margin_dps=result.materiality_dph / DEG_PER_H_PER_DPS,
                     strict=False, runs_name=OWN_RUNS_NAME if cold else RESTARTS_NAME,
                     simplest_margin_dps=chance / DEG_PER_H_PER_DPS)
    if not check.dropped:
        return result, check, names
    kept = {term.signal: term for term in check.calibration.terms}
    effects = tuple(replace(e, term=kept[e.signal]) for e in result.effects if e.signal in kept)
    return replace(result, extended=check.calibration, effects=effects), check, names


def _node_starts(result: LoopResult, log: GyroLog, bias_samples: int) -> list[tuple[str, GyroLog, RunStart]]:
    """The runs :func:`startup_check` replays, (name, run, how it began) each: cold starts first.

    Per run of the fit: its start, if the table rests over its first ``bias_samples`` rows (a
    cold start if it began at power-on; a warm one only among several runs: one log's
    restarts are its warm starts), then its own restarts (:func:`own_restarts`).
    """
    several = len(result.runs) > 1
    cold: list[tuple[str, GyroLog, RunStart]] = []
    warm: list[tuple[str, GyroLog, RunStart]] = []
    for run in result.runs if several else ():
        part = log.slice(slice(run.first_row, run.stop))
        assert part.ref_rate is not None   # the loop fitted it
        if len(part) > 2 * bias_samples and not np.any(part.ref_rate[:bias_samples]):
            if run.powered_on_at_start:
                cold.append((f'{run.name}: {COLD_START_NAME}', part, RunStart(powered_on_at_start=True)))
            else:
                warm.append((f'{run.name}: from its start (warm)', part, RunStart()))
        warm += [(f'{run.name}: restarted at {start_s / 60.0:.0f} min', later, RunStart())
                 for start_s, later in own_restarts(part, bias_samples)]
    if several:
        return cold + warm
    warm = [(f'restarted at {start_s / 60.0:.0f} min', run, RunStart())
            for start_s, run in own_restarts(log, bias_samples)]
    assert log.ref_rate is not None   # own_restarts refuses a log without it
    if result.start.powered_on_at_start and len(log) > 2 * bias_samples and not np.any(log.ref_rate[:bias_samples]):
        cold = [(COLD_START_NAME, log, result.start)]
    return cold + warm


def judged_cold(names: Sequence[str]) -> bool:
    """Whether the runs :func:`startup_check` named ``names`` hold a cold start (a run from its power-on)."""
    return any(name.endswith(COLD_START_NAME) for name in names)


def _refit(result: LoopResult, terms: Sequence[Term]) -> Calibration:
    """The polynomial and ``terms``' shapes refitted jointly on the loop's log."""
    # A term's shape is its fields less the coefficients: whatever a TermSpec holds.
    specs = [TermSpec(**{f.name: getattr(t, f.name) for f in fields(TermSpec)}) for t in terms]
    polynomial = result.art.polynomial
    fit = fit_model(result.signals, result.error, polynomial.rows, polynomial.columns, specs, result.segments.rows())
    return replace(result.art, polynomial=fit.model.polynomial, terms=fit.model.terms)
