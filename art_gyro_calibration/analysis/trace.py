"""Trace what a fitted model leaves: screen every signal of a log against the residual, held out.

Each candidate signal (every derived signal and every extra column of the log) gets
the term form that fits its physics (:func:`candidate_specs`). It is scored by how
much it lowers the *held-out* mean squared error of the model: the steady rows are cut
into blocks of time (15 minutes, which :func:`loop.close_loop` lengthens to the residual's
correlation time), dealt in turn to ``folds`` folds; for each fold the base model plus the
candidate is fitted on the other folds and predicts this one.

Chance is measured on the data itself, keeping the candidate and randomising the
residual: ``draws`` phase-randomised copies of what the base model leaves keep its
spectrum (a bias that wanders for hours stays slow) but lose any alignment with a
candidate; the spectrum is taken without the strongest candidate's effect, so an effect
does not hide in its own chance (:func:`null_spectrum`). Every candidate scores every
copy; the best chance score of the round, over all candidates, is one draw of the null
of "nothing here", so one quantile of it tests the whole round at level ``alpha``
however many candidates there are (a maximum statistic). A candidate is an effect only
if it beats that quantile and if its fitted size over the logged envelope (half its
range, deg/h) reaches the materiality, by default the data's own bias instability: an
effect smaller than the gyro's wander does not matter to a robot, whatever the log's
length or sample rate. Candidates are scored against the base alone, never conditioned
on each other, so two columns carrying the same information cannot explain each other
away; a log column that stands for a derived signal (one the node computes itself) gives
way to it.

Speed: the screen works on bin means (``bin_s`` of one steady segment per bin, weighted
by the square root of their row count, so a bin mean's noise is that of one sample)
and on per-fold Gram matrices: the held-out error of every fold, every chance draw and
every time constant then follows from small matrices and one product with the bins.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.analysis.chunks import Chunk, chunks
from art_gyro_calibration.analysis.fit import Design, Ranges, TermSpec, centring, fit_model, solve_normal
from art_gyro_calibration.analysis.metrics import Segments, noise_floor
from art_gyro_calibration.signals import DERIVED_SIGNALS, LAGGED_SIGNAL, POWER_ON_SIGNAL, Signals
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

DEFAULT_FOLDS = 6
# Fewer folds than this leave too little to fit on; a short log gets this many, not shorter blocks.
MIN_FOLDS = 3
DEFAULT_DRAWS = 200
# The level of each round's test. A false term costs a robot as much as a missed one (a warm-up fitted to noise
# is a bias for the whole mission), and a null without the effect's own power can afford a strict level.
DEFAULT_ALPHA = 0.01
# The chance residuals' slowest frequencies, below index 8 of the mirrored spectrum (periods over a quarter of
# the log), are kept at least at a random walk's level (:func:`null_spectrum`).
SLOW_INDEX = 8
# Chance draws scored at once: bounds the memory of the target matrices (bins x batch, twice: as drawn and in
# fold order), 55 MB each for 96 h of 1 s bins.
SURROGATE_BATCH = 20
DEFAULT_BIN_S = 1.0
# Held-out blocks of time: several times the bias instability's correlation time.
DEFAULT_BLOCK_S = 900.0
# A log column stands for a derived signal when each spans the other's columns to this R^2 beyond the base.
STANDS_FOR_CORRELATION = 0.9
# A richer form goes after a simpler significant one that explains this share of its effect (R^2).
SIMPLER_FIRST = 0.5
# A form richer only by a time constant must also lose this share of its held-out improvement to the
# simpler one: a decay whose curvature the log shows (a 20-minute warm-up in 2 hours) is no drift,
# though a line explains much of it. (Not for a form with more columns: those fit other effects too.)
SIMPLER_SHARE = 0.9
TIME_CONSTANT_GRID_SIZE = 8
MAX_TIME_CONSTANT_RUNS = 4.0
MIN_TIME_CONSTANT_S = 30.0
# Golden-section steps refining a time constant between grid neighbours: 0.618**8 = 5 % of the bracket.
GOLDEN_STEPS = 8


# The physical forms the screen tries, by candidate name (one family of shapes each). A name is
# what the report calls the effect; the spec's signal is what the term is evaluated on.
FORMS_TRIED = {
    'temperature': 'the polynomial\'s next temperature row\'s bias, T**rows',
    'temperature_x_rate<k>': 'the same row\'s rate terms, T**rows x rate**k for k = 1..columns-1 (scale factor, '
                             'non-linearity), each a candidate of its own',
    'rate': 'the polynomial\'s next rate column, rate**columns (scale-factor non-linearity)',
    'rate_x_temperature': 'the next rate column\'s temperature terms, T**1..rows-1 x rate**columns',
    'temperature_rate': 'c dT/dt, the Shupe effect of a temperature gradient across the coil',
    'rate_x_temperature_rate': 'c rate dT/dt, a scale factor that follows the temperature gradient',
    'temperature_lag': 'the polynomial\'s temperature terms on a coil temperature lagging the sensor, '
                       'T_lag**1..rows-1 x rate**0..columns-1, lag from 1 minute to 2 hours or a quarter of '
                       'the log',
    'time': 'c t, a linear drift (IEEE 952 ramp) from the run\'s start',
    'time_since_power_on': 'c exp(-t/tau), a warm-up from power-on that decays within the log, tau from 30 s to '
                           'half the log',
    'time_since_power_on_slow': 'c exp(-t/tau), a long exponential from power-on, tau from half the log to four '
                                'logs (a trend: it fits a slow wander as a drift does, and is judged apart)',
    'rate_abs': 'c |rate|, scale-factor asymmetry',
    'rate_sign': 'c sign(rate), a bias that depends on the turning direction (dead band, lock-in)',
    'rate_change': 'c d(rate)/dt, angular-acceleration sensitivity',
    'angle': 'c0 sin(heading) + c1 cos(heading), a once-per-turn (magnetic, tilt) coupling: reported, not '
             'written (the node has no absolute heading)',
    'extra columns': 'c x for every further numeric column of the log (a supply voltage, ...)',
}
LAG_GRID_S = (60.0, 2 * SECONDS_PER_HOUR)
# A lag is tried up to this share of the log: the lagged temperature must follow the chamber over the log to be
# told from it. (A 4 h lag fitted on 2 h moved little; its polynomial, extrapolated on a warm restart, read
# 650 deg/h.)
MAX_LAG_SHARE = 0.25


def duration_s(signals: Signals) -> float:
    """The log's length of time, s; of the longest run of several (a time constant is seen within one)."""
    return max(float(run.t[-1] - run.t[0]) if len(run) else 0.0 for _, run in signals.runs())


def time_constant_bounds(spec: TermSpec, duration: float) -> tuple[float, float]:
    """The shortest and longest time constant (or lag) of ``spec``'s kind a log of ``duration`` s can identify."""
    if spec.signal == LAGGED_SIGNAL:
        return LAG_GRID_S[0], max(min(LAG_GRID_S[1], MAX_LAG_SHARE * duration), 2 * LAG_GRID_S[0])
    return MIN_TIME_CONSTANT_S, max(MAX_TIME_CONSTANT_RUNS * duration, 2 * MIN_TIME_CONSTANT_S)


def candidate_specs(signals: Signals, rows: int, columns: int, exclude: Sequence[str] = (),
                    still: bool = False) -> dict[str, list[TermSpec]]:
    """Per candidate (by name, :data:`FORMS_TRIED`), the term shapes to try: several for a time constant.

    The polynomial's next orders are cross terms with the rate as the report's matrix has
    them (not on a ``still`` log, whose rate is only its error); a warm-up is tried only on a
    log that starts at power-on.
    """
    duration = duration_s(signals)
    taus = np.geomspace(*time_constant_bounds(TermSpec(POWER_ON_SIGNAL, 'exp_decay'), duration),
                        TIME_CONSTANT_GRID_SIZE)
    lags = np.geomspace(*time_constant_bounds(TermSpec(LAGGED_SIGNAL, 'power'), duration), TIME_CONSTANT_GRID_SIZE)
    temperature_powers = tuple(range(1, rows))
    rate_powers = (0,) if still else tuple(range(columns))
    out: dict[str, list[TermSpec]] = {
        # The next row one rate power at a time: a scale factor in T**3 is one column, not four.
        'temperature': [TermSpec('temperature', 'power', (rows,))],
        **{f'temperature_x_rate{k}': [TermSpec('temperature', 'power', (rows,), rate_powers=(k,))]
           for k in rate_powers[1:]},
        'rate': [TermSpec('rate', 'power', (columns,))],
        'rate_x_temperature': [TermSpec('temperature', 'power', temperature_powers, rate_powers=(columns,))],
        'temperature_rate': [TermSpec('temperature_rate', 'power', (1,))],
        'rate_x_temperature_rate': [TermSpec('temperature_rate', 'power', (1,), rate_powers=(1,))],
        'temperature_lag': [TermSpec(LAGGED_SIGNAL, 'power', temperature_powers, float(tau), rate_powers)
                            for tau in lags],
        'time': [TermSpec('time', 'power', (1,))],
        'time_since_power_on': [TermSpec(POWER_ON_SIGNAL, 'exp_decay', (), float(tau))
                                for tau in taus if tau <= duration / 2],
        'time_since_power_on_slow': [TermSpec(POWER_ON_SIGNAL, 'exp_decay', (), float(tau))
                                     for tau in taus if tau > duration / 2],
        'rate_abs': [TermSpec('rate_abs', 'power', (1,))],
        'rate_sign': [TermSpec('rate_sign', 'power', (1,))],
        'rate_change': [TermSpec('rate_change', 'power', (1,))],
        'angle': [TermSpec('angle', 'harmonic')],
    }
    if rows < 2:
        del out['rate_x_temperature'], out['temperature_lag']   # no temperature terms to lag
    if not signals.powered_on_at_start:   # nothing counts from a power-on the log did not start with
        out = {name: specs for name, specs in out.items() if all(s.signal != POWER_ON_SIGNAL for s in specs)}
    out.update({name: [TermSpec(name, 'power', (1,))] for name in signals.extras})
    return {name: specs for name, specs in out.items() if name not in exclude and specs}


def joined(have: TermSpec, new: TermSpec) -> TermSpec | None:
    """One power term on a signal with both terms' columns, if they share their powers or their rate powers."""
    if not (have.form == new.form == 'power' and have.time_constant_s == new.time_constant_s
            and (have.powers == new.powers or have.rate_powers == new.rate_powers)):
        return None
    return replace(have, powers=tuple(sorted(set(have.powers) | set(new.powers))),
                   rate_powers=tuple(sorted(set(have.rate_powers) | set(new.rate_powers))))


def _bins(segments: Segments, t: NDArray[np.float64], bin_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Starts (positions among the steady rows) and row counts of bins of ``bin_s`` within segments."""
    if bin_s <= 0.0:
        n = int(segments.counts.sum())
        return np.arange(n), np.ones(n, dtype=np.int64)
    starts, counts = [], []
    position = 0
    for a, b in zip(segments.starts, segments.stops):
        edges = np.searchsorted(t[a:b], np.arange(t[a], t[b - 1] + bin_s, bin_s), side='left')
        edges = np.unique(np.append(edges, b - a))
        starts.append(position + edges[:-1])
        counts.append(np.diff(edges))
        position += b - a
    return np.concatenate(starts), np.concatenate(counts)


def _cv_sse(gram: NDArray[np.float64], cross: NDArray[np.float64],
            yy: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Held-out and training SSE, shape (K, T), of a least-squares fit per fold and target.

    ``gram`` (K, q, q) holds each fold's ``X'X``, ``cross`` (K, q, T) its ``X'y`` for T
    targets and ``yy`` (K, T) its ``y'y``: fold k is predicted from the fit to the others.
    """
    train = gram.sum(axis=0) - gram
    train_cross = cross.sum(axis=0) - cross
    diag = np.einsum('kii->ki', train)
    ridge = 1e-12 * diag.mean(axis=-1)[:, None, None] * np.eye(gram.shape[-1])
    beta = np.linalg.solve(train + ridge, train_cross)
    held = yy - 2 * np.einsum('kqt,kqt->kt', beta, cross) + np.einsum('kqt,kqt->kt', beta, gram @ beta)
    trained = yy.sum(axis=0) - yy - np.einsum('kqt,kqt->kt', beta, train_cross)
    return held, trained


class Binned:
    """Steady rows of a log in bins, with the polynomial's columns and the error binned once.

    Folds: the bins are grouped into blocks of ``block_s`` of time, dealt to the folds in
    turn, so every fold holds whole blocks of time from the whole run (a warm-up in the
    first hour or a temperature extreme is then in several folds). Several runs
    (:attr:`Signals.run_starts`): each run's blocks count from its own first bin, none spans two. A short log gets fewer
    folds (down to :data:`MIN_FOLDS`) rather than blocks shorter than asked for. Every
    per-row quantity is summed into the bins chunk by chunk (``chunk_rows`` rows,
    :mod:`art_gyro_calibration.analysis.chunks`): memory holds the bins, not a matrix per row.
    """

    def __init__(self, signals: Signals, error: ArrayLike, segments: Segments, rows: int, columns: int,
                 folds: int = DEFAULT_FOLDS, bin_s: float = DEFAULT_BIN_S, block_s: float = DEFAULT_BLOCK_S,
                 chunk_rows: int | None = None) -> None:
        self.signals = signals
        self.index = segments.rows()
        self.starts, self._counts = _bins(segments, signals.t, bin_s)
        if len(self._counts) < 4 * MIN_FOLDS:
            raise ValueError(f'{len(self._counts)} bins of steady data are too few for {MIN_FOLDS} folds')
        self.sqrt_counts = np.sqrt(self._counts)
        self.rows_total = int(self._counts.sum())
        self.chunk_rows = chunk_rows
        self.error = np.asarray(error, dtype=float)
        self.ranges: Ranges = {}   # the centring of every term's columns over the steady rows
        self._polynomial = Design(signals, rows, columns, (), self.index, self.ranges, chunk_rows)
        self.base = np.zeros((len(self.starts), self._polynomial.width + 1))
        for chunk in self._chunks():
            values = np.column_stack([self._polynomial.matrix(chunk), self.error[chunk.start + chunk.rows]])
            self._add_to_bins(self.base, chunk, values)
        self.base /= self.sqrt_counts[:, None]
        self._t_bin = signals.t[self.index[self.starts]]
        # Per run: the time its rows begin (runs lie end to end on the fit's clock) and of its first bin.
        firsts = [first for first, _ in signals.runs()]
        self.bin_runs = np.searchsorted(firsts, self.index[self.starts], side='right') - 1
        self._run_t = signals.t[firsts]
        self._run_t0 = np.array([self._t_bin[self.bin_runs == k][0] if np.any(self.bin_runs == k) else self._run_t[k]
                                 for k in range(len(firsts))])
        self._blocks_before = np.zeros(len(firsts), dtype=np.int64)
        self.max_folds = folds
        self.n_folds = folds
        self.block_s = 0.0
        self.folds: list[NDArray[np.int64]] = []
        self.refold(block_s)
        self._means: dict[TermSpec, NDArray[np.float64]] = {}

    def refold(self, block_s: float, n_folds: int | None = None) -> None:
        """Deal blocks of ``block_s`` to the folds in turn, at least two blocks per fold."""
        t_bin = self._t_bin
        last = np.array([t_bin[self.bin_runs == k][-1] if np.any(self.bin_runs == k) else self._run_t0[k]
                         for k in range(len(self._run_t0))])
        duration = max(float(np.sum(last - self._run_t0)), 1e-9)
        if n_folds is None:
            n_folds = int(np.clip(duration // (2 * block_s), MIN_FOLDS, self.max_folds))
        self.n_folds = n_folds
        self.block_s = min(block_s, duration / (2 * n_folds))
        blocks = np.floor((last - self._run_t0) / self.block_s).astype(np.int64) + 1
        self._blocks_before = np.concatenate([[0], np.cumsum(blocks)[:-1]])
        fold = self._fold_of(t_bin)
        self.folds = [np.flatnonzero(fold == k) for k in range(n_folds)]
        # The bins in fold order, and where each fold ends: per-fold sums then run on slices, not copies.
        self.order = np.concatenate(self.folds)
        self.bounds = np.cumsum([0] + [len(k) for k in self.folds])

    def _fold_of(self, t: NDArray[np.float64]) -> NDArray[np.int64]:
        """The fold of the block of time each of ``t`` (times of steady rows) falls in, blocks counted run by run."""
        run = np.searchsorted(self._run_t, t, side='right') - 1
        block = np.floor((t - self._run_t0[run]) / self.block_s).astype(np.int64) + self._blocks_before[run]
        return np.asarray(block % self.n_folds, dtype=np.int64)

    def _add_to_bins(self, sums: NDArray[np.float64], chunk: Chunk, values: NDArray[np.float64]) -> None:
        """Add ``values`` of the chunk's steady rows into the bin ``sums`` (a bin the chunk's edge cuts adds twice)."""
        if len(chunk.rows):
            a, b = chunk.positions.start, chunk.positions.stop
            first = int(np.searchsorted(self.starts, a, side='right')) - 1
            last = int(np.searchsorted(self.starts, b, side='left'))
            sums[first:last] += np.add.reduceat(values, np.maximum(self.starts[first:last] - a, 0), axis=0)

    def _chunks(self) -> Iterator[Chunk]:
        """The log's chunks, with their steady rows."""
        return chunks(self.signals, self.index, self.chunk_rows)

    def candidate_means(self, variants: Sequence[TermSpec]) -> NDArray[np.float64]:
        """Bin means of the scaled candidate bases, shape (bins, variants, width); each computed once."""
        missing = [spec for spec in dict.fromkeys(variants) if spec not in self._means]
        if missing:
            self._add_means(missing)
        return np.stack([self._means[spec] for spec in variants], axis=1)

    def forget_means(self, specs: Sequence[TermSpec]) -> None:
        """Drop the cached bin means of ``specs`` (variants tried and not kept): the cache grows with the log."""
        for spec in specs:
            self._means.pop(spec, None)
            self.ranges.pop(spec, None)

    def _add_means(self, specs: Sequence[TermSpec]) -> None:
        """Bin means of the centred bases of ``specs``, in one pass over the log, one basis at a time.

        The centring (:func:`centring`, over all steady rows) is known only at the end: each
        basis is summed less a provisional offset (its first rows' midpoint, within its
        range), and the bin sums are moved to the final offset after, with no digits lost.
        """
        sums = {spec: np.zeros((len(self.starts), spec.width)) for spec in specs}
        provisional: dict[TermSpec, NDArray[np.float64]] = {}
        low: dict[TermSpec, NDArray[np.float64]] = {}
        high: dict[TermSpec, NDArray[np.float64]] = {}
        for chunk in self._chunks():
            for spec in specs:   # every chunk, steady rows in it or not: a lag's recursion runs through all
                basis = spec.basis(chunk.signals, chunk.rows)
                if len(basis):
                    lo, hi = basis.min(axis=0), basis.max(axis=0)
                    if spec not in provisional:
                        provisional[spec], low[spec], high[spec] = 0.5 * (hi + lo), lo, hi
                    low[spec], high[spec] = np.minimum(low[spec], lo), np.maximum(high[spec], hi)
                    self._add_to_bins(sums[spec], chunk, basis - provisional[spec])
        for spec in specs:
            offset, scale = centring(low[spec], high[spec])
            self.ranges[spec] = offset, scale
            sums[spec] -= self._counts[:, None] * (offset - provisional[spec])
            sums[spec] /= scale
            self._means[spec] = sums[spec] / self.sqrt_counts[:, None] / self.sqrt_counts[:, None]
            del sums[spec]

    def bin_times(self) -> NDArray[np.float64]:
        """Time (s) of each bin's first row."""
        return self._t_bin

    def fold_sums(self, a: NDArray[np.float64], b: NDArray[np.float64], ordered: bool = False) -> NDArray[np.float64]:
        """Per fold ``a_k' b_k`` over the bins of fold k, shape (K, a columns, b columns).

        ``ordered``: ``a`` and ``b`` are already in fold order (``x[binned.order]``).
        """
        if not ordered:
            a, b = a[self.order], b[self.order]
        edges = self.bounds
        return np.stack([a[i:j].T @ b[i:j] for i, j in zip(edges[:-1], edges[1:])])

    def row_folds(self, specs: Sequence[TermSpec] = ()) -> RowFolds:
        """Per-fold sums over every steady row (not bins) of the polynomial and ``specs``, on these folds' blocks."""
        specs = tuple(dict.fromkeys(specs))
        design = Design(self.signals, self._polynomial.rows, self._polynomial.columns, specs, self.index,
                        self.ranges, self.chunk_rows)
        k, q = self.n_folds, design.width
        gram, cross, yy = np.zeros((k, q, q)), np.zeros((k, q)), np.zeros(k)
        for chunk, x in design.chunks():
            rows = chunk.start + chunk.rows
            y = self.error[rows]
            fold = self._fold_of(self.signals.t[rows])
            for f in np.unique(fold):
                mine = fold == f
                gram[f] += x[mine].T @ x[mine]
                cross[f] += x[mine].T @ y[mine]
                yy[f] += y[mine] @ y[mine]
        return RowFolds(specs, self._polynomial.width, gram, cross, yy, self.rows_total, self.block_s)


@dataclass(frozen=True)
class RowFolds:
    """Per-fold sums over every steady row of the polynomial's and some terms' columns: X'X, X'e and e'e.

    The held-out error of the polynomial with any subset of those terms follows from them
    (:meth:`held_out_rms`), each fold predicted from the fit to the others, with no matrix
    of a row per log row.
    """

    specs: tuple[TermSpec, ...]
    polynomial_width: int
    gram: NDArray[np.float64]    # (K, q, q)
    cross: NDArray[np.float64]   # (K, q)
    yy: NDArray[np.float64]      # (K,)
    rows_total: int
    block_s: float

    def held_out_rms(self, specs: Sequence[TermSpec] = ()) -> float:
        """Held-out RMS error (deg/s) of the polynomial + ``specs`` (among :attr:`specs`), over every steady row."""
        starts = np.cumsum([self.polynomial_width] + [spec.width for spec in self.specs])
        columns = np.concatenate([np.arange(self.polynomial_width)]
                                 + [np.arange(starts[i], starts[i] + spec.width)
                                    for spec in specs for i in [self.specs.index(spec)]]).astype(np.int64)
        gram, cross = self.gram[:, columns][:, :, columns], self.cross[:, columns]
        total_gram, total_cross = gram.sum(axis=0), cross.sum(axis=0)
        sse = 0.0
        for g, c, yy in zip(gram, cross, self.yy):
            beta = solve_normal(total_gram - g, total_cross - c)
            sse += yy - 2.0 * beta @ c + beta @ g @ beta
        return float(np.sqrt(max(sse, 0.0) / self.rows_total))


class Screen:
    """The base model (polynomial + ``specs``) on binned rows, with per-fold Grams, ready to score candidates."""

    def __init__(self, binned: Binned, specs: Sequence[TermSpec] = ()) -> None:
        self.binned = binned
        self.specs = tuple(specs)
        self.sqrt_counts = binned.sqrt_counts
        self.rows_total = binned.rows_total
        parts = [binned.base[:, :-1]]
        parts += [self.weighted(spec) for spec in specs]
        self.x = np.column_stack(parts)
        self.e = binned.base[:, -1]
        self.width = self.x.shape[1]
        self.gram = binned.fold_sums(self.x, self.x)
        self._xe = self.x.T @ self.e
        self._ee = float(self.e @ self.e)
        self._base_sse: float | None = None
        # Per candidate variant, its columns' cross products with the base and what is left of them beyond it.
        self._beyond: dict[TermSpec, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}

    def weighted(self, spec: TermSpec) -> NDArray[np.float64]:
        """The candidate's columns as the screen fits them: bin means weighted to unit noise."""
        return self.binned.candidate_means([spec])[:, 0, :] * self.sqrt_counts[:, None]

    def base_sse(self) -> float:
        """Held-out SSE of the base model over all folds."""
        if self._base_sse is None:
            held, _ = _cv_sse(self.gram, self.binned.fold_sums(self.x, self.e[:, None]),
                              self.binned.fold_sums(self.e[:, None], self.e[:, None])[:, 0])
            self._base_sse = float(held.sum())
        return self._base_sse

    def residual(self) -> NDArray[np.float64]:
        """What the base model fitted to every bin leaves, weighted as the bins are."""
        return self.e - self.x @ solve_normal(self.gram.sum(axis=0), self.x.T @ self.e)

    def fit_with(self, spec: TermSpec) -> tuple[float, NDArray[np.float64]]:
        """SSE over all bins of the base plus ``spec``, and the candidate's coefficients (scaled basis)."""
        c = self.weighted(spec)
        cx = c.T @ self.x
        gram = np.block([[self.gram.sum(axis=0), cx.T], [cx, c.T @ c]])
        rhs = np.concatenate([self._xe, c.T @ self.e])
        beta = solve_normal(gram, rhs)
        return float(self._ee - beta @ rhs), beta[self.width:]

    def training_sse(self, spec: TermSpec) -> float:
        """SSE of the base model plus ``spec`` fitted to all folds (for choosing a time constant)."""
        return self.fit_with(spec)[0]

    def beyond_base(self, means: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bin means of candidate columns less what the base model's columns can give of them."""
        x = self.x / self.sqrt_counts[:, None]
        return means - x @ solve_normal(x.T @ x, x.T @ means)

    def effect_dph(self, spec: TermSpec) -> float:
        """Worst-case size of the fitted candidate over the logged envelope, deg/h.

        Half the range of what it adds beyond the base model (its part the polynomial could
        absorb is no effect), over the bin means.
        """
        _, beta = self.fit_with(spec)
        contribution = self.beyond_base(self.binned.candidate_means([spec])[:, 0, :]) @ beta
        return float(0.5 * np.ptp(contribution) * DEG_PER_H_PER_DPS)

    def explained(self, families: Mapping[str, Sequence[TermSpec]],
                  targets: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
        """Per family, how much each variant lowers the MSE (deg^2/s^2 per row) of each target, fitted to all bins.

        (variants, targets) per family: the squared length of each target's projection on the
        variant's columns beyond the base model, from small matrices and one product with
        the bins per variant.
        """
        gram = self.gram.sum(axis=0)
        beta = solve_normal(gram, self.x.T @ targets)
        out = {}
        for name, variants in families.items():
            rows = []
            for spec in variants:
                c = self.weighted(spec)
                if spec not in self._beyond:   # the same for every batch of targets: once per screen
                    cx = c.T @ self.x
                    self._beyond[spec] = cx, c.T @ c - cx @ solve_normal(gram, cx.T)
                cx, beyond = self._beyond[spec]
                r = c.T @ targets - cx @ beta
                rows.append(np.einsum('wt,wt->t', r, solve_normal(beyond, r)))
            out[name] = np.stack(rows) / self.rows_total
        return out

    def held_out_improvements(self, families: Mapping[str, Sequence[TermSpec]],
                              targets: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
        """Per family, how much it lowers the held-out MSE (deg^2/s^2 per row) of each target column.

        Each fold picks the family's variant (a time constant) that fits its training blocks
        best, for each target apart, so the choice itself is held out.
        """
        order = self.binned.order

        def fold_sums(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
            return self.binned.fold_sums(a, b, ordered=True)

        targets = targets[order]
        x = self.x[order]
        cross_x = fold_sums(x, targets)
        edges = self.binned.bounds
        yy = np.stack([np.einsum('nt,nt->t', targets[i:j], targets[i:j]) for i, j in zip(edges[:-1], edges[1:])])
        base_held, _ = _cv_sse(self.gram, cross_x, yy)
        p = self.width
        out = {}
        for name, variants in families.items():
            held = []
            trained = []
            for spec in variants:
                c = self.weighted(spec)[order]
                w = c.shape[1]
                gram = np.empty((len(self.binned.folds), p + w, p + w))
                gram[:, :p, :p] = self.gram
                gram[:, p:, :p] = fold_sums(c, x)
                gram[:, :p, p:] = np.swapaxes(gram[:, p:, :p], 1, 2)
                gram[:, p:, p:] = fold_sums(c, c)
                h, tr = _cv_sse(gram, np.concatenate([cross_x, fold_sums(c, targets)], axis=1), yy)
                held.append(h)
                trained.append(tr)
            pick = np.argmin(np.stack(trained), axis=0)[None]
            chosen = np.take_along_axis(np.stack(held), pick, axis=0)[0]
            out[name] = (base_held - chosen).sum(axis=0) / self.rows_total
        return out


def mirrored_spectrum(x: NDArray[np.float64]) -> NDArray[np.complex128]:
    """The spectrum :func:`phase_surrogates` randomises: of ``x`` less its mean, followed by its mirror image.

    Mirrored, a wander that ends far from where it began is no jump at the wrap, and the
    surrogates keep its trends. ``x`` is first continued by the mirror image of its end to
    a length whose transform is fast (a few bins in a thousand at most): a bin count with a
    large prime factor made every surrogate ten times dearer.
    """
    fast = _fast_length(len(x))
    x_fast = np.concatenate([x, x[::-1][:fast - len(x)]])
    return np.fft.rfft(np.concatenate([x_fast, x_fast[::-1]]) - x.mean())


def _fast_length(n: int) -> int:
    """The smallest 2**a 3**b 5**c >= ``n``: a length whose transform needs no large prime."""
    best = 1 << max(n - 1, 0).bit_length()
    fives = 1
    while fives < best:
        threes = fives
        while threes < best:
            twos = threes << max(0, (n - 1) // threes).bit_length()   # the smallest threes * 2**a >= n
            best = min(best, twos)
            threes *= 3
        fives *= 5
    return best


def phase_surrogates(spectrum: NDArray[np.complex128], count: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``count`` series with the amplitude ``spectrum`` (:func:`mirrored_spectrum`) and random phases, (n, count).

    A slow bias wander keeps its slowness (its spectrum), but loses any alignment with a
    candidate: the null of "the candidate explains nothing", with the residual's own memory.
    """
    return phase_surrogates_alike([spectrum], count, rng)[0]


def phase_surrogates_alike(spectra: Sequence[NDArray[np.complex128]], count: int,
                           rng: np.random.Generator) -> list[NDArray[np.float64]]:
    """:func:`phase_surrogates` of each of ``spectra`` (one length), all with the same random phases."""
    n2 = 2 * (len(spectra[0]) - 1)
    # A draw a row (written whole), turned to a series a column at the end: a column written a draw at a time
    # strode through the whole array.
    drawn = [np.empty((count, n2 // 2)) for _ in spectra]
    for j in range(count):   # one draw at a time: the complex temporaries are one series long, not ``count``
        phases = rng.uniform(0.0, 2.0 * np.pi, len(spectra[0]))
        phases[0] = 0.0
        phases[-1] = 0.0   # the Nyquist term of the (even) mirrored length stays real
        turn = np.exp(1j * phases)
        for draws, spectrum in zip(drawn, spectra):
            draws[j] = np.fft.irfft(spectrum * turn, n2)[:n2 // 2]
    return [np.ascontiguousarray(draws.T) for draws in drawn]


def null_spectrum(screen: Screen, families: Mapping[str, Sequence[TermSpec]], residual: NDArray[np.float64],
                  held_out: dict[str, float]) -> NDArray[np.complex128]:
    """The amplitude spectrum of the chance residuals: the residual's, without the strongest candidate's effect.

    The residual's own spectrum holds any effect it carries: over one chamber cycle a
    Shupe effect is then as likely by chance as by cause. So the fit of the strongest
    candidate (most ``held_out`` improvement) is taken out first. At the slowest
    frequencies (periods over a quarter of the log, where the log holds only a few
    cycles) that would also take out the part of a bias
    wander the candidate happens to fit, and make chance too small: there the spectrum is
    kept at least at a rate random walk's through its level at periods of a quarter to an
    eighth of the log (power ~ 1/f**2, the steepest noise of a gyro's error model, IEEE
    952; a steeper one is a drift, a candidate), but never above the residual's own.
    """
    full = mirrored_spectrum(residual)
    if not families or len(full) <= 2 * SLOW_INDEX:
        return full
    strongest = families[max(held_out, key=lambda name: held_out[name])]
    spec = strongest[0] if len(strongest) == 1 else _best_variant(screen, strongest, refine=False)
    spectrum = np.abs(mirrored_spectrum(Screen(screen.binned, [*screen.specs, spec]).residual()))
    # Index j of the mirrored spectrum (2n bins) is a period of 2n/j bins: j = SLOW_INDEX is a quarter of the log.
    level = float(np.mean(spectrum[SLOW_INDEX:2 * SLOW_INDEX] ** 2))
    slow = np.arange(1, SLOW_INDEX)
    floor = np.minimum(np.sqrt(level) * SLOW_INDEX * np.sqrt(2.0) / slow, np.abs(full[slow]))
    spectrum[slow] = np.maximum(spectrum[slow], floor)
    return spectrum.astype(np.complex128)


@dataclass(frozen=True)
class CandidateScore:
    """One candidate's test against chance and its size.

    ``explained_dps2``: how much it lowers the MSE fitted to all bins (deg^2/s^2 per row,
    the test's statistic); ``null_*`` the same over the chance draws; ``threshold_dps2`` what
    it had to explain to count; ``score`` its statistic standardised by its own chance
    draws. ``improvement_dps2``: how much it lowers the held-out MSE (which form goes first).
    """

    signal: str
    spec: TermSpec
    improvement_dps2: float
    null_mean_dps2: float
    null_std_dps2: float
    null_max_dps2: float
    fraction_of_floor: float
    significant: bool
    p_value: float = 1.0
    effect_dph: float = 0.0
    stands_for: str = ''
    explained_dps2: float = 0.0
    threshold_dps2: float = math.inf
    score: float = 0.0


@dataclass(frozen=True)
class TraceResult:
    """What one screen found: every candidate's score, best first, and the round's chance level.

    ``threshold_score``: the ``1 - alpha`` quantile of the best standardised chance score of
    any candidate; ``threshold_dps2``: the least any candidate had to explain to beat it.
    """

    noise_floor_dps: float
    base_held_out_mse_dps2: float
    candidates: tuple[CandidateScore, ...]
    threshold_dps2: float = math.inf
    draws: int = 0
    materiality_dph: float = 0.0
    alpha: float = DEFAULT_ALPHA
    threshold_score: float = math.inf

    @property
    def best(self) -> CandidateScore | None:
        """The significant candidate to add next, or None: nothing found.

        The one least likely by chance; among those tied at that (the strongest effects all
        beat every draw), the one that lowers the held-out error most: a weaker candidate may
        owe its score to the part of a stronger effect it can mimic (a drift, of a warm-up).
        A candidate that a simpler significant one stands for gives way to it.
        """
        found = [c for c in self.candidates if c.significant]
        if not found:
            return None
        least = min(c.p_value for c in found)
        pick = max((c for c in found if c.p_value <= least), key=lambda c: c.improvement_dps2)
        named = {c.signal: c for c in found}
        return named.get(pick.stands_for, pick)


# A candidate's chance draws are standardised by their tail: the distance beyond this quantile in units of
# the mean excess over it (an exponential tail's scale). Candidates' chance tails differ in shape (one
# column, eight, a time constant chosen): so standardised, each beats the round's threshold about equally
# often by chance, and a candidate with a light tail is not judged by another's heavy one.
TAIL_QUANTILE = 0.9
# Candidates whose every time constant is judged apart, each in its own chance tail. A warm-up of minutes
# explains by chance what a few minutes of noise hold; one of hours, the wander of hours: judged together by the
# best variant, a short warm-up would be measured against the long ones' chance and missed; the round's
# threshold is still set over all.
JUDGED_PER_VARIANT = ('time_since_power_on',)


@dataclass(frozen=True)
class ScreenOptions:
    """How a screen judges candidates: held-out folds, bins of ``bin_s``, ``draws`` chance copies, level ``alpha``.

    ``seed`` seeds the chance copies. (The loop's options extend these: :class:`loop.LoopOptions`.)
    """

    folds: int = DEFAULT_FOLDS
    draws: int = DEFAULT_DRAWS
    alpha: float = DEFAULT_ALPHA
    bin_s: float = DEFAULT_BIN_S
    seed: int = 0


def trace_residual(signals: Signals, error: ArrayLike, segments: Segments, rows: int, columns: int,
                   specs: Sequence[TermSpec] = (), options: ScreenOptions = ScreenOptions(), *,
                   materiality_dph: float = 0.0, noise_floor_dps: float | None = None,
                   exclude: Sequence[str] = (), binned: Binned | None = None, still: bool = False) -> TraceResult:
    """Screen every signal not yet modelled (nor in ``exclude``) against what the model (polynomial + ``specs``) leaves.

    ``error`` is ``rate_dps - ref_rate`` per log row; only the steady rows of ``segments``
    are used. Each candidate's statistic is how much its best variant (time constant)
    explains of the residual, fitted to all bins (a warm-up's every time constant is judged
    apart, :data:`JUDGED_PER_VARIANT`). Chance: ``options.draws`` phase-randomised copies
    of the residual, each explained by every candidate in the same way (its variant chosen
    again); a candidate's statistic is standardised by its own chance draws (a form of eight
    columns explains more by chance than one of one, a slow signal more than a fast one),
    and it is significant if it beats the ``1 - options.alpha`` quantile of the best standardised
    chance score of any candidate (one test for the whole round, whatever the number and
    kind of candidates: a maximum statistic) and its fitted size reaches
    ``materiality_dph`` over the logged envelope. (Not held out: on one chamber cycle a
    held-out statistic is dominated by the polynomial extrapolated into a held-out block's
    temperatures, and misses small effects a statistic over all bins finds.)
    """
    if noise_floor_dps is None:
        base = fit_model(signals, error, rows, columns, specs, segments.rows())
        residual = np.zeros(len(signals))
        residual[base.index] = base.residual
        noise_floor_dps = noise_floor(residual, segments)
    draws, alpha = options.draws, options.alpha
    if binned is None:
        binned = Binned(signals, error, segments, rows, columns, options.folds, options.bin_s)
    screen = Screen(binned, specs)
    rng = np.random.default_rng(options.seed)
    floor_var = noise_floor_dps ** 2
    families = candidate_specs(signals, rows, columns, exclude, still)
    # One term per signal in a calibration file: a candidate on a signal the model has must join its term.
    taken = {spec.signal: spec for spec in specs}
    families = {name: v for name, v in families.items()
                if v[0].signal not in taken or joined(taken[v[0].signal], v[0]) is not None}
    families = {name: v for name, v in families.items() if np.ptp(binned.candidate_means(v), axis=0).max() > 0.0}
    if not families:
        return TraceResult(noise_floor_dps, screen.base_sse() / screen.rows_total, (), math.inf, draws,
                           materiality_dph, alpha)
    residual = screen.residual()
    held_out = {name: float(v[0]) for name, v in screen.held_out_improvements(families, residual[:, None]).items()}
    spectrum = null_spectrum(screen, families, residual, held_out)
    parts: dict[str, list[NDArray[np.float64]]] = {name: [] for name in families}
    for start in range(0, draws + 1, SURROGATE_BATCH):
        count = min(SURROGATE_BATCH, draws + 1 - start)
        targets = phase_surrogates(spectrum, count, rng)[:len(residual)]
        if start == 0:
            targets[:, 0] = residual   # column 0: the residual as logged
        for name, explained in screen.explained(families, targets).items():
            parts[name].append(explained)
        del targets   # not alive beside the next batch
    table = {name: np.concatenate(v, axis=1) for name, v in parts.items()}   # (variants, 1 + draws)
    # Per candidate, the statistics judged: the best variant's, or every variant's apart (JUDGED_PER_VARIANT).
    judged = {name: v if name in JUDGED_PER_VARIANT else v.max(axis=0, keepdims=True) for name, v in table.items()}
    centre = {name: np.quantile(v[:, 1:], TAIL_QUANTILE, axis=1, keepdims=True) for name, v in judged.items()}
    spread = {name: np.maximum(np.sum(np.maximum(v[:, 1:] - centre[name], 0.0), axis=1, keepdims=True)
                               / np.maximum(np.sum(v[:, 1:] > centre[name], axis=1, keepdims=True), 1), 1e-300)
              for name, v in judged.items()}
    standard = {name: (v - centre[name]) / spread[name] for name, v in judged.items()}
    best_chance = np.max(np.concatenate([v[:, 1:] for v in standard.values()]), axis=0)
    threshold = float(np.quantile(best_chance, 1.0 - alpha, method='higher'))
    candidates = []
    for name, values in judged.items():
        variants = families[name]
        top = int(np.argmax(standard[name][:, 0]))   # the variant judged: the best standardised one
        real, null, score = float(values[top, 0]), values[top, 1:], float(standard[name][top, 0])
        beats = score > threshold
        # The term's shape: the variant that explains most; judged apart, the most among those that beat chance.
        fits = table[name][:, 0]
        if len(values) > 1 and beats:
            fits = np.where(standard[name][:, 0] > threshold, fits, -np.inf)
        spec = variants[int(np.argmax(fits))]
        if len(variants) > 1 and beats:   # a time constant refined only where it may matter
            spec = _best_variant(screen, [v for v, f in zip(variants, fits) if f > -np.inf])
        size = screen.effect_dph(spec)
        candidates.append(CandidateScore(
            name, spec, held_out[name], float(null.mean()), float(null.std()), float(null.max()),
            held_out[name] / floor_var, bool(beats and size >= materiality_dph),
            float((1 + np.sum(best_chance >= score)) / (draws + 1)), size, explained_dps2=real,
            threshold_dps2=float(centre[name][top, 0] + threshold * spread[name][top, 0]), score=score))
    candidates = _stand_ins(screen, candidates)
    candidates.sort(key=lambda c: c.score, reverse=True)
    return TraceResult(noise_floor_dps, screen.base_sse() / screen.rows_total, tuple(candidates),
                       min(c.threshold_dps2 for c in candidates), draws, materiality_dph, alpha, threshold)


def _stand_ins(screen: Screen, candidates: list[CandidateScore]) -> list[CandidateScore]:
    """Mark a significant candidate that a simpler significant one should go before.

    A log column gives way to a derived signal (one the node computes) that carries the same
    information: each spans the other's columns beyond the base (R^2 >=
    :data:`STANDS_FOR_CORRELATION`, both ways; one way, the eight columns of a lagged
    temperature stood for a supply voltage over one chamber cycle); a richer form to a
    simpler one (fewer columns, or no time constant) that explains at least
    :data:`SIMPLER_FIRST` of its fitted effect: a lagged temperature's terms contain the Shupe term, a long
    decay looks like a drift (if the line also does nearly as well held out,
    :data:`SIMPLER_SHARE`). The simpler one is named (:attr:`TraceResult.best`), and the next
    round asks what the richer form adds beyond it.
    """
    found = [c for c in candidates if c.significant]
    out = []
    for c in candidates:
        if c.significant:
            mine = screen.binned.candidate_means([c.spec])[:, 0, :]
            effect = screen.beyond_base(mine) @ screen.fit_with(c.spec)[1]
            alike = []
            for d in found:
                theirs = screen.binned.candidate_means([d.spec])[:, 0, :]
                if c.spec.signal not in DERIVED_SIGNALS and d.spec.signal in DERIVED_SIGNALS:
                    # The same information both ways: a wide derived form (a lagged temperature's eight columns)
                    # spans any slow column over one chamber cycle, and would take a supply voltage's place.
                    if _alike(screen, theirs, mine) < STANDS_FOR_CORRELATION:
                        continue
                    needed, likeness = STANDS_FOR_CORRELATION, _alike(screen, mine, theirs)
                elif d is not c and _complexity(d.spec) < _complexity(c.spec) \
                        and (d.spec.width < c.spec.width or d.improvement_dps2 >= SIMPLER_SHARE * c.improvement_dps2):
                    # What the richer form fitted, not all its columns can span: one column never spans a lagged
                    # temperature's eight, though it gives all of the Shupe effect they fit.
                    needed, likeness = SIMPLER_FIRST, _alike(screen, effect[:, None], theirs)
                else:
                    continue
                if likeness >= needed:
                    alike.append((likeness, d.signal))
            if alike:
                c = replace(c, stands_for=max(alike)[1])
        out.append(c)
    return out


def _complexity(spec: TermSpec) -> float:
    """Columns, and half a column more for a time constant: a drift beats a decay that looks like it."""
    return spec.width + (0.5 if spec.time_constant_s > 0.0 else 0.0)


def _alike(screen: Screen, a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """How much of ``a``'s columns ``b``'s span (R^2), both after removing what the base model spans."""
    ra, rb = screen.beyond_base(a), screen.beyond_base(b)
    explained = rb @ solve_normal(rb.T @ rb, rb.T @ ra)
    total = float(np.sum(ra * ra))
    return float(np.sum(explained * explained)) / total if total > 0.0 else 0.0


def held_out_residual(rows: Binned, specs: Sequence[TermSpec] = ()) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per bin, what the polynomial + ``specs`` fitted on the other folds leaves, and how much that widens its spread.

    The residual is weighted as the bins are; the widening is ``1 + h``, ``h = x' G_k^-1 x``, the
    bin's (weighted) row against the Gram of the folds it was not in: the variance of the held-out
    residual is the noise's times ``1 + h``. Most bins have ``h`` of a few hundredths; a bin of the
    one -100 deg/s step in a fold of a short log, where the rate-cubed terms rest on few rows, far more.
    """
    screen = Screen(rows, specs)
    out = np.empty(len(screen.e))
    inflation = np.empty(len(screen.e))
    gram = screen.gram.sum(axis=0)
    for k in rows.folds:
        x = screen.x[k]
        training = gram - x.T @ x
        beta = solve_normal(training, screen.x.T @ screen.e - x.T @ screen.e[k])
        out[k] = screen.e[k] - x @ beta
        inflation[k] = 1.0 + np.einsum('ij,ji->i', x, solve_normal(training, x.T))
    return out, inflation


def _best_variant(screen: Screen, variants: Sequence[TermSpec], refine: bool = True) -> TermSpec:
    """The best variant on all the data; its time constant, if it has one and ``refine``, by golden-section search."""
    sse = [screen.training_sse(v) for v in variants]
    template = variants[int(np.argmin(sse))]
    if not refine:
        return template
    shape = replace(template, time_constant_s=0.0)
    kin = [(e, v) for e, v in zip(sse, variants) if replace(v, time_constant_s=0.0) == shape]
    if len(kin) < 2:
        return template
    sse = [e for e, _ in kin]
    i = int(np.argmin(sse))
    taus = [v.time_constant_s for _, v in kin]
    lo, hi = np.log(taus[max(i - 1, 0)]), np.log(taus[min(i + 1, len(taus) - 1)])

    tried: list[TermSpec] = []

    def cost(log_tau: float) -> float:
        tried.append(replace(template, time_constant_s=float(np.exp(log_tau))))
        return screen.training_sse(tried[-1])

    golden = (np.sqrt(5.0) - 1) / 2
    a, b = lo + (1 - golden) * (hi - lo), lo + golden * (hi - lo)
    fa, fb = cost(a), cost(b)
    for _ in range(GOLDEN_STEPS):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = lo + (1 - golden) * (hi - lo)
            fa = cost(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + golden * (hi - lo)
            fb = cost(b)
    best = float(np.exp(a if fa < fb else b))
    if min(fa, fb) > sse[i]:
        best = taus[i]
    chosen = replace(template, time_constant_s=best)
    screen.binned.forget_means([v for v in tried if v != chosen])   # the search's steps: one pass each, kept none
    return chosen
