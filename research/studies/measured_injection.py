"""Known effects added to the real CATS record, and whether the package's loop finds them blind.

Each effect is added to a gyro axis's real readings (its real noise, temperature
history and bias wander stay), scaled to a given rms over the still record in units of
that axis's bias instability; then every held-out-day fold is run again exactly as on
the record itself (:func:`measured_folds.run_fold`), and compared with the fold without
injection: did the loop name the effect's signal, how much of the effect its terms took
up, and what the held-out day's error became.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import SignalFilters, compute_signals
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

from measured_folds import Fold, run_fold
from measured_record import ACCELERATION_CHANNELS, AXES, DAY

EFFECTS = ('shupe', 'warmup', 'drift', 'step')
EFFECT_TITLES = {'shupe': 'Shupe-like k dT/dt', 'warmup': 'warm-up exp(-t/3 h)', 'drift': 'linear drift',
                 'step': 'step at the first orientation change'}
ORIENTATION_SIGNALS = ACCELERATION_CHANNELS + tuple(f'mag_{a}' for a in AXES)
# The signals that name each effect right: its own, or for a step at an orientation change, any channel
# that changes with the orientation.
EXPECTED_SIGNALS = {'shupe': ('temperature_rate',), 'warmup': ('time_since_power_on',), 'drift': ('time',),
                    'step': ORIENTATION_SIGNALS}
# Sizes: rms over the still record, in units of the axis's bias instability.
SIZES = (10.0, 3.0, 1.0)
WARMUP_TAU_S = 3.0 * SECONDS_PER_HOUR


def effect_shape(effect: str, log: GyroLog, days: NDArray[np.int_]) -> NDArray[np.float64]:
    """The shape of ``effect`` over the log's samples, before scaling (signals since the record's start)."""
    since: NDArray[np.float64] = log.t - log.t[0]
    if effect == 'shupe':
        return compute_signals(log.t, log.rate_dps, log.temp_c, {}, SignalFilters()).temperature_rate
    if effect == 'warmup':
        return np.exp(-since / WARMUP_TAU_S)
    if effect == 'drift':
        return since / DAY
    if effect == 'step':
        return (days >= 1).astype(float)
    raise ValueError(f'unknown effect {effect!r}; one of {", ".join(EFFECTS)}')


def scaled(shape: NDArray[np.float64], rms_dps: float) -> tuple[NDArray[np.float64], float]:
    """``shape`` scaled to ``rms_dps`` about its mean, and the scale (the effect's coefficient)."""
    scale = rms_dps / float(np.std(shape))
    return shape * scale, scale


@dataclass(frozen=True)
class Trial:
    """One effect at one size added to one axis, one day held out, against the same fold without it."""

    effect: str
    factor: float  # rms in units of the bias instability
    rms_dps: float
    coefficient: float  # deg/s per unit of the effect's shape (deg/s per degC/s, deg/s, deg/s per day)
    fold: Fold
    base: Fold
    detected: bool
    named: tuple[str, ...]
    recovered: float  # fraction of the injected effect the named terms took up beyond the fold without it

    @property
    def new_claims(self) -> tuple[str, ...]:
        """Signals of effects kept that neither name this effect nor were kept without injection."""
        before = {t.signal for t in self.base.kept_effects}
        return tuple(s for s in self.named if s not in EXPECTED_SIGNALS[self.effect] and s not in before)


def run_trial(base: Fold, days: NDArray[np.int_], effect: str, factor: float, floor_dps: float,
              max_effects: int, seed: int = 0) -> Trial:
    """Add ``effect`` at ``factor`` times ``floor_dps`` rms to the base fold's log and run the fold again, blind."""
    log = base.log
    values, coefficient = scaled(effect_shape(effect, log, days), factor * floor_dps)
    injected = replace(log, rate_dps=log.rate_dps + values)
    fold = run_fold(injected, days, base.day, base.held_name, base.axis, max_effects, seed)
    expected = EXPECTED_SIGNALS[effect]
    named = tuple(t.signal for t in fold.kept_effects)
    detected = any(s in expected for s in named)
    train = ~fold.held

    def taken_up(f: Fold) -> NDArray[np.float64]:
        terms = [t for t in f.kept_effects if t.signal in expected]
        return sum((t.evaluate(f.signals.get(t.signal)) for t in terms), np.zeros(len(log)))[train]

    delta = taken_up(fold) - taken_up(base)
    v = values[train] - np.mean(values[train])
    recovered = float((delta - np.mean(delta)) @ v / (v @ v)) if detected else float('nan')
    return Trial(effect, factor, factor * floor_dps, coefficient, fold, base, detected, named, recovered)


def run_injections(bases: Sequence[Fold], days_of: dict[str, NDArray[np.int_]], floors: dict[str, float],
                   effects: Sequence[str] = EFFECTS, sizes: Sequence[float] = SIZES,
                   max_effects: int = 4,
                   progress: Callable[[Trial], None] | None = None) -> list[Trial]:
    """Every effect at every size on every base fold (axis and held-out day)."""
    trials = []
    for effect in effects:
        for factor in sizes:
            for base in bases:
                trials.append(run_trial(base, days_of[base.axis], effect, factor, floors[base.axis], max_effects))
                if progress:
                    progress(trials[-1])
    return trials


@dataclass(frozen=True)
class Cell:
    """The trials of one effect at one size, summed up."""

    effect: str
    factor: float
    trials: tuple[Trial, ...]

    @property
    def detected(self) -> int:
        """Trials whose loop kept a term on the effect's signal."""
        return sum(t.detected for t in self.trials)

    def named(self) -> str:
        """The signals the loop kept, most frequent first, with counts."""
        counts = Counter(s for t in self.trials for s in t.named)
        return ', '.join(f'{s} ({n})' for s, n in counts.most_common()) or 'nothing'

    def new_claims(self) -> int:
        """Trials that kept an effect on a signal that neither names this effect nor was kept without it."""
        return sum(bool(t.new_claims) for t in self.trials)

    def recovered(self) -> NDArray[np.float64]:
        """Fraction of the injected effect taken up, over the trials that detected it."""
        return np.array([t.recovered for t in self.trials if t.detected])

    def held_out(self, stage: str, way: str) -> NDArray[np.float64]:
        """Held-out 10-minute rms (deg/h) of ``stage`` measured ``way``, one per trial."""
        return np.array([t.fold.field[stage, way].systematic_rms_dps * DEG_PER_H_PER_DPS for t in self.trials])


def cells(trials: Sequence[Trial]) -> list[Cell]:
    """Trials grouped by effect and size, in the order run."""
    keys = list(dict.fromkeys((t.effect, t.factor) for t in trials))
    return [Cell(e, f, tuple(t for t in trials if (t.effect, t.factor) == (e, f))) for e, f in keys]
