"""Trace what a fitted model leaves: screen every signal of a log against the residual, held out.

Each candidate signal (every derived signal and every extra column of the log) gets
the term form that fits its physics (:func:`candidate_specs`). It is scored by how
much it lowers the *held-out* mean squared error of the model: the steady rows are cut
into blocks of time (15 minutes, which :func:`loop.close_loop` lengthens to the residual's
correlation time), dealt in turn to ``folds`` folds; for each fold the base model plus the
candidate is fitted on the other folds and predicts this one.

Chance is measured on the data itself: the same score with the candidate circularly
shifted by ``shifts`` large random offsets, which keeps the candidate's own slowness and
the residual's (bias instability) but breaks their alignment; offsets where the shifted
candidate still correlates with itself (a periodic temperature cycle shifted by a
period, or by half of one, which flips its sign) are not drawn. A candidate is an
effect only if its score beats every shifted score (chance below 1 / (shifts + 1)) and
if it removes at least ``materiality`` of the white-noise variance estimated from the
data: below that, an effect is not told apart from the gyro's own bias instability.
Several unmodelled effects inflate each other's chance level, so material candidates
are scored again with the other material ones (and, if still nothing beats chance,
with every other candidate) in the base.

Speed: the screen works on bin means (``bin_s`` of one steady segment per bin, weighted
by the square root of their row count, so a bin mean's noise is that of one sample)
and on per-fold Gram matrices: the held-out error of every fold, every shift and every
time constant then follows from small matrices without touching the rows again.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.analysis.fit import Design, TermSpec, centred, fit_model, solve_normal
from art_gyro_calibration.analysis.metrics import Segments, noise_floor
from art_gyro_calibration.signals import Signals

DEFAULT_FOLDS = 6
DEFAULT_SHIFTS = 39
DEFAULT_BIN_S = 1.0
# Held-out blocks of time: several times the bias instability's correlation time.
DEFAULT_BLOCK_S = 900.0
DEFAULT_MATERIALITY = 0.03
# A shift is a fair draw of chance only if the shifted candidate does not resemble the
# candidate itself (or its negative): a periodic chamber cycle would otherwise shift onto itself.
MAX_SELF_CORRELATION = 0.3
TIME_CONSTANT_GRID_SIZE = 8
MAX_TIME_CONSTANT_RUNS = 4.0
# Self-correlation of a candidate is judged on at most this many block means (cheap FFTs).
SELF_CORRELATION_POINTS = 4096
MIN_TIME_CONSTANT_S = 30.0


def candidate_specs(signals: Signals, rows: int, columns: int,
                    exclude: Sequence[str] = ()) -> dict[str, list[TermSpec]]:
    """Per candidate signal, the term shapes to try (several only for a warm-up's time constant).

    temperature: the next power ``T**rows``; rate: the next power ``r**columns``;
    time: a linear drift ``t``, or ``exp(-t/tau)`` over a log grid of tau from 30 s to four runs;
    angle: once-per-turn harmonic;
    everything else (temperature_rate, rate_abs, rate_sign, rate_change, extra columns): linear.
    """
    duration = float(signals.t[-1] - signals.t[0]) if len(signals) else 0.0
    out: dict[str, list[TermSpec]] = {}
    for name in signals.names():
        if name in exclude:
            continue
        if name == 'temperature':
            out[name] = [TermSpec(name, 'power', (rows,))]
        elif name == 'rate':
            out[name] = [TermSpec(name, 'power', (columns,))]
        elif name == 'time':
            # A linear drift, or a warm-up decaying from 30 s to several times the run (a long one
            # is a slow drift that levels off); each fold picks the shape its training blocks prefer.
            taus = np.geomspace(MIN_TIME_CONSTANT_S, max(MAX_TIME_CONSTANT_RUNS * duration, 2 * MIN_TIME_CONSTANT_S),
                                TIME_CONSTANT_GRID_SIZE)
            out[name] = [TermSpec(name, 'power', (1,))] + [TermSpec(name, 'exp_decay', (), float(tau)) for tau in taus]
        elif name == 'angle':
            out[name] = [TermSpec(name, 'harmonic')]
        else:
            out[name] = [TermSpec(name, 'power', (1,))]
    return out


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


def _held_out(gram: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Held-out and training SSE per fold from per-fold Grams ``(..., K, q, q)`` of ``[X, e]``."""
    train = gram.sum(axis=-3, keepdims=True) - gram
    a = train[..., :-1, :-1]
    b = train[..., :-1, -1]
    diag = np.einsum('...ii->...i', a)
    ridge = 1e-12 * diag.mean(axis=-1)[..., None, None] * np.eye(a.shape[-1])
    beta = np.linalg.solve(a + ridge, b[..., None])[..., 0]
    held = (gram[..., -1, -1] - 2 * np.einsum('...i,...i->...', beta, gram[..., :-1, -1])
            + np.einsum('...i,...ij,...j->...', beta, gram[..., :-1, :-1], beta))
    trained = train[..., -1, -1] - np.einsum('...i,...i->...', beta, b)
    return held, trained


class Binned:
    """Steady rows of a log in bins, with the polynomial's columns and the error binned once.

    Folds: the bins are grouped into blocks of ``block_s`` of time, dealt to the
    ``folds`` in turn, so every fold holds whole blocks of time from the whole run (a
    warm-up in the first hour or a temperature extreme is then in several folds).
    """

    def __init__(self, signals: Signals, error: ArrayLike, segments: Segments, rows: int, columns: int,
                 folds: int = DEFAULT_FOLDS, bin_s: float = DEFAULT_BIN_S, block_s: float = DEFAULT_BLOCK_S) -> None:
        self.signals = signals
        self.index = segments.rows()
        self.starts, counts = _bins(segments, signals.t, bin_s)
        if len(counts) < 4 * folds:
            raise ValueError(f'{len(counts)} bins of steady data are too few for {folds} folds')
        self.sqrt_counts = np.sqrt(counts)
        self.rows_total = int(counts.sum())
        poly = Design(signals, rows, columns, (), self.index).matrix
        self.base = self._bin(np.column_stack([poly, np.asarray(error, dtype=float)[self.index]]))
        self._t_bin = signals.t[self.index[self.starts]]
        self.n_folds = folds
        self.block_s = 0.0
        self.folds: list[NDArray[np.int64]] = []
        self.refold(block_s)
        self._means: dict[TermSpec, NDArray[np.float64]] = {}

    def refold(self, block_s: float) -> None:
        """Deal blocks of ``block_s`` (at most a ``2 * folds``-th of the run) to the folds in turn."""
        t_bin = self._t_bin
        duration = float(t_bin[-1] - t_bin[0])
        self.block_s = min(block_s, max(duration / (2 * self.n_folds), 1e-9))
        fold = np.floor((t_bin - t_bin[0]) / self.block_s).astype(np.int64) % self.n_folds
        self.folds = [np.flatnonzero(fold == k) for k in range(self.n_folds)]

    def _bin(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bin sums of steady-row ``values`` divided by sqrt(count): a mean weighted to unit noise."""
        return np.add.reduceat(values, self.starts, axis=0) / self.sqrt_counts.reshape(-1, *([1] * (values.ndim - 1)))

    def candidate_means(self, variants: Sequence[TermSpec]) -> NDArray[np.float64]:
        """Bin means of the scaled candidate bases, shape (bins, variants, width); each computed once."""
        cols = []
        for spec in variants:
            if spec not in self._means:
                _, _, basis = centred(spec.basis(self.signals)[self.index])
                self._means[spec] = self._bin(basis) / self.sqrt_counts[:, None]
            cols.append(self._means[spec])
        return np.stack(cols, axis=1)


class Screen:
    """The base model (polynomial + ``specs``) on binned rows, with per-fold Grams, ready to score candidates."""

    def __init__(self, binned: Binned, specs: Sequence[TermSpec] = ()) -> None:
        self.binned = binned
        self.sqrt_counts = binned.sqrt_counts
        self.rows_total = binned.rows_total
        parts = [binned.base[:, :-1]]
        parts += [binned.candidate_means([spec])[:, 0, :] * self.sqrt_counts[:, None] for spec in specs]
        self.xe = np.column_stack([*parts, binned.base[:, -1]])
        self.width = self.xe.shape[1] - 1
        self.gram = np.stack([self.xe[k].T @ self.xe[k] for k in binned.folds])
        self._base_sse: float | None = None

    def candidate_means(self, variants: Sequence[TermSpec]) -> NDArray[np.float64]:
        """Bin means of the scaled candidate bases, shape (bins, variants, width)."""
        return self.binned.candidate_means(variants)

    def base_sse(self) -> float:
        """Held-out SSE of the base model over all folds."""
        if self._base_sse is None:
            self._base_sse = float(_held_out(self.gram)[0].sum())
        return self._base_sse

    def scores(self, means: NDArray[np.float64], shifts: NDArray[np.int64]) -> NDArray[np.float64]:
        """Held-out SSE with the candidate for each circular shift (0 = as logged).

        With several variants (time constants), each fold picks the variant that fits its
        training blocks best, so the choice itself is held out.
        """
        n, n_var, w = means.shape
        p = self.width
        n_ver = len(shifts) * n_var
        q = p + w + 1
        gram = np.zeros((n_ver, len(self.binned.folds), q, q))
        for k, rows in enumerate(self.binned.folds):
            # Shifted copies fold by fold: memory stays at one fold's worth.
            rolled = means[(rows[:, None] - shifts[None, :]) % n]  # (rows, shifts, variants, w)
            ck = (rolled * self.sqrt_counts[rows, None, None, None]).reshape(len(rows), n_ver, w)
            cx = (ck.reshape(len(rows), n_ver * w).T @ self.xe[rows]).reshape(n_ver, w, p + 1)
            gram[:, k, :p, :p] = self.gram[k, :p, :p]
            gram[:, k, :p, -1] = gram[:, k, -1, :p] = self.gram[k, :p, -1]
            gram[:, k, -1, -1] = self.gram[k, -1, -1]
            gram[:, k, p:p + w, :p] = cx[:, :, :p]
            gram[:, k, :p, p:p + w] = np.swapaxes(cx[:, :, :p], 1, 2)
            gram[:, k, p:p + w, -1] = gram[:, k, -1, p:p + w] = cx[:, :, p]
            gram[:, k, p:p + w, p:p + w] = np.einsum('njw,njv->jwv', ck, ck)
        held, trained = _held_out(gram)
        held = held.reshape(len(shifts), n_var, -1)
        trained = trained.reshape(len(shifts), n_var, -1)
        pick = np.argmin(trained, axis=1)[:, None, :]
        return np.take_along_axis(held, pick, axis=1)[:, 0, :].sum(axis=-1)

    def training_sse(self, spec: TermSpec) -> float:
        """SSE of the base model plus ``spec`` fitted to all folds (for choosing a time constant)."""
        c = self.candidate_means([spec])[:, 0, :] * self.sqrt_counts[:, None]
        base = self.gram.sum(axis=0)
        cx = c.T @ self.xe
        p = self.width
        g = np.block([[base[:p, :p], cx[:, :p].T, base[:p, p:]],
                      [cx[:, :p], c.T @ c, cx[:, p:]],
                      [base[p:, :p], cx[:, p:].T, base[p:, p:]]])
        beta = solve_normal(g[:-1, :-1], g[:-1, -1])
        return float(g[-1, -1] - beta @ g[:-1, -1])


@dataclass(frozen=True)
class CandidateScore:
    """One candidate signal's held-out score against its chance level (per-sample deg^2/s^2)."""

    signal: str
    spec: TermSpec
    improvement_dps2: float
    null_mean_dps2: float
    null_std_dps2: float
    null_max_dps2: float
    fraction_of_floor: float
    significant: bool


@dataclass(frozen=True)
class TraceResult:
    """What one screen found: every candidate's score, best first."""

    noise_floor_dps: float
    base_held_out_mse_dps2: float
    candidates: tuple[CandidateScore, ...]

    @property
    def best(self) -> CandidateScore | None:
        """The significant candidate that removes most error, or None: nothing found."""
        found = [c for c in self.candidates if c.significant]
        return found[0] if found else None


def trace_residual(signals: Signals, error: ArrayLike, segments: Segments, rows: int, columns: int,
                   specs: Sequence[TermSpec] = (), *, folds: int = DEFAULT_FOLDS, shifts: int = DEFAULT_SHIFTS,
                   bin_s: float = DEFAULT_BIN_S, materiality: float = DEFAULT_MATERIALITY,
                   seed: int = 0, noise_floor_dps: float | None = None,
                   exclude: Sequence[str] = (), binned: Binned | None = None) -> TraceResult:
    """Screen every signal not yet modelled (nor in ``exclude``) against what the model (polynomial + ``specs``) leaves.

    ``error`` is ``rate_dps - ref_rate`` per log row; only the steady rows of ``segments``
    are used. The noise floor is estimated from the base fit's residual unless given;
    ``binned`` (the same log, rows and columns) saves binning it again in a loop.
    """
    if noise_floor_dps is None:
        base = fit_model(signals, error, rows, columns, specs, segments.rows())
        residual = np.zeros(len(signals))
        residual[base.index] = base.residual
        noise_floor_dps = noise_floor(residual, segments)
    if binned is None:
        binned = Binned(signals, error, segments, rows, columns, folds, bin_s)
    screen = Screen(binned, specs)
    rng = np.random.default_rng(seed)
    floor_var = noise_floor_dps ** 2
    families = candidate_specs(signals, rows, columns, [*exclude, *(s.signal for s in specs)])
    scores = [score for signal, variants in families.items()
              if (score := _score(screen, signal, variants, shifts, rng, floor_var, materiality)) is not None]
    # Several unmodelled effects inflate each other's chance level (a slow residual makes any
    # slow candidate look useful). Score each material candidate again with the other
    # material ones in the base, so that its chance level is measured on what they leave.
    material = [c for c in scores if c.fraction_of_floor > materiality]
    if len(material) > 1:
        scores = _rescore(scores, material, material, binned, specs, families, shifts, rng, floor_var, materiality)
    # Still nothing beats chance although something matters: the unmodelled rest may hide in
    # candidates whose own score the others spoil; condition on every other candidate.
    if not any(c.significant for c in scores):
        material = [c for c in scores if c.fraction_of_floor > materiality]
        scores = _rescore(scores, material, scores, binned, specs, families, shifts, rng, floor_var, materiality)
    scores.sort(key=lambda c: c.improvement_dps2, reverse=True)
    return TraceResult(noise_floor_dps, screen.base_sse() / screen.rows_total, tuple(scores))


def _rescore(scores: list[CandidateScore], material: list[CandidateScore], given: list[CandidateScore],
             binned: Binned, specs: Sequence[TermSpec], families: dict[str, list[TermSpec]], shifts: int,
             rng: np.random.Generator, floor_var: float, materiality: float) -> list[CandidateScore]:
    """Scores with each ``material`` candidate scored again with the other ``given`` ones in the base."""
    rescored = []
    for c in material:
        others = [o.spec for o in given if o.signal != c.signal]
        conditional = Screen(binned, [*specs, *others])
        rescored.append(_score(conditional, c.signal, families[c.signal], shifts, rng, floor_var, materiality))
    return [c for c in scores if c not in material] + [c for c in rescored if c is not None]


def _score(screen: Screen, signal: str, variants: Sequence[TermSpec], shifts: int, rng: np.random.Generator,
           floor_var: float, materiality: float) -> CandidateScore | None:
    """Held-out improvement of one candidate over the screen's base, against its shifted copies."""
    means = screen.candidate_means(variants)
    if np.ptp(means, axis=0).max() == 0.0:
        return None  # constant over the steady rows: nothing to tell apart from the polynomial's constant
    offsets = np.concatenate([[0], _fair_shifts(means, shifts, rng)])
    improvement = (screen.base_sse() - screen.scores(means, offsets)) / screen.rows_total
    real, null = improvement[0], improvement[1:]
    if null.size < min(shifts, 9):
        null = np.array([np.inf])  # too few fair shifts: chance cannot be measured, so nothing is claimed
    spec = variants[0] if len(variants) == 1 else _best_variant(screen, variants)
    significant = bool(real > null.max() and real > materiality * floor_var)
    return CandidateScore(signal, spec, float(real), float(null.mean()), float(null.std()),
                          float(null.max()), float(real / floor_var), significant)


def _fair_shifts(means: NDArray[np.float64], count: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Up to ``count`` circular shifts (in bins, within the middle 80 %) that decorrelate the candidate from itself.

    The circular self-correlation of each variant (and across its columns) is computed
    by FFT on block means of the bins, which is ample for the slow shapes that matter.
    """
    n, n_var, w = means.shape
    step = max(1, -(-n // SELF_CORRELATION_POINTS))
    m = n // step
    x = means[:m * step].reshape(m, step, n_var, w).mean(axis=1)
    x = x - x.mean(axis=0)
    spectrum = np.fft.rfft(x, axis=0)
    power = np.sum(x * x, axis=0)
    power[power == 0.0] = 1.0
    worst = np.zeros(m)
    for v in range(n_var):
        for i in range(w):
            for j in range(w):
                cross = np.fft.irfft(np.conj(spectrum[:, v, i]) * spectrum[:, v, j], m)
                worst = np.maximum(worst, np.abs(cross) / np.sqrt(power[v, i] * power[v, j]))
    lags = np.arange(m // 10, m - m // 10)
    fair = lags[worst[lags] <= MAX_SELF_CORRELATION]
    chosen = rng.choice(fair, size=min(count, fair.size), replace=False) if fair.size else fair
    return chosen * step


def held_out_rms(rows: Binned, specs: Sequence[TermSpec] = ()) -> float:
    """Held-out RMS error (deg/s) of the polynomial + ``specs``; ``rows`` binned with ``bin_s=0``: every steady row."""
    screen = Screen(rows, specs)
    return float(np.sqrt(screen.base_sse() / screen.rows_total))


def _best_variant(screen: Screen, variants: Sequence[TermSpec]) -> TermSpec:
    """The best variant on all the data; a time constant is refined by golden-section search in log(tau)."""
    sse = [screen.training_sse(v) for v in variants]
    best = int(np.argmin(sse))
    if variants[best].form != 'exp_decay':
        return variants[best]
    decays = [(s, v) for s, v in zip(sse, variants) if v.form == 'exp_decay']
    sse = [s for s, _ in decays]
    variants = [v for _, v in decays]
    i = int(np.argmin(sse))
    taus = [v.time_constant_s for v in variants]
    lo, hi = np.log(taus[max(i - 1, 0)]), np.log(taus[min(i + 1, len(taus) - 1)])
    template = variants[i]

    def cost(log_tau: float) -> float:
        return screen.training_sse(TermSpec(template.signal, template.form, (), float(np.exp(log_tau))))

    golden = (np.sqrt(5.0) - 1) / 2
    a, b = lo + (1 - golden) * (hi - lo), lo + golden * (hi - lo)
    fa, fb = cost(a), cost(b)
    for _ in range(20):
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
    return TermSpec(template.signal, template.form, (), best)
