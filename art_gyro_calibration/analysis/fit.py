"""Least-squares fit of the ART polynomial (and extended terms) to a rate-table log.

The measured error ``e = rate_dps - ref_rate`` is fitted against ``T**a * r**b``
(a < rows, b < columns) plus the bases of the extended terms. The raw monomials span
1e-9 to 1e-2 in coefficient and their columns are nearly collinear (T in [10, 50] degC),
so the solve runs on a scaled basis: ``u = (T - Tc) / Ts`` and ``v = r / Rs`` with u, v in
[-1, 1], term columns divided by their largest magnitude. The coefficients are then
mapped back exactly (binomial expansion of ``(Tc + Ts u)**a``) into the report's form.

A term on the temperature rate is fitted on the node's own causal estimate of it, whose noise
(0.05 degC counts through a filter of tens of seconds) would bias a least-squares coefficient
toward zero (errors in variables: the fitted Shupe coefficient about 6 % low, a mission-long
error of several deg/h after a cold start). Those columns are instrumented
by their own means over :data:`INSTRUMENT_BIN_S` of contiguous fitted rows: with ``X`` the
design and ``Z`` the same with those columns so averaged, ``beta = (Z'X)^-1 Z'y``
(instrumental variables; R. J. Bowden and D. A. Turkington, *Instrumental Variables*, 1984,
ch. 2). The estimate's noise averages out of the means while the temperature's slow rate
does not, and what the coefficient multiplies is the rate itself.

Note on the constant: the log's error holds the run's turn-on bias and the Earth's
rate, so the fitted constant (``T**0 r**0``) absorbs them; the static bias collection
before every mission removes that constant again (``CalcStaticBiasDrift``), so only the
shape of the surface matters, not its offset. A fit of several runs (:attr:`Signals.run_starts`)
gives every run after the first a constant of its own, its turn-on bias beside the first's:
fitted with the rest, never written.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from math import comb

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.analysis.chunks import Chunk, chunks
from art_gyro_calibration.analysis.metrics import PIECE_ROWS
from art_gyro_calibration.model import ArtPolynomial, ErrorModel
from art_gyro_calibration.signals import Signals
from art_gyro_calibration.terms import Term, term_basis


# A polynomial of R rows (powers of temperature 0..R-1) needs the log's temperature to span (R - 1) times this:
# over less, its temperature powers fit the noise (0.05 degC per count) and the turn-on bias, not a slope.
MIN_TEMP_SPAN_PER_POWER_C = 1.0
# Table rates closer than this (deg/s) are one rate.
RATE_LEVEL_DPS = 1e-6
# Signals whose term columns are instrumented by their means (see the module's docstring), and the span of those
# means: the local quadratic estimate's noise stays correlated for about its 20 s; over 60 s means a coefficient
# fitted on it over 0.1 degC/min chamber ramps and a self-heating came out 0.6 % low, against 6 % on every row.
INSTRUMENTED_SIGNALS = ('temperature_rate',)
INSTRUMENT_BIN_S = 60.0


def check_coverage(temp_c: ArrayLike, table_rates: ArrayLike, rows: int, columns: int) -> None:
    """Refuse a log that cannot determine a ``rows`` x ``columns`` polynomial, naming what it lacks.

    ``table_rates``: the reference rate of each steady segment. A polynomial of C columns needs
    C distinct table rates (a log at rest leaves every power of the rate free: a least-squares
    minimum-norm answer read a true 30 deg/s as 5.9); one of R rows a temperature span of
    (R - 1) x MIN_TEMP_SPAN_PER_POWER_C.
    """
    levels = np.unique(np.round(np.asarray(table_rates, dtype=float) / RATE_LEVEL_DPS)) * RATE_LEVEL_DPS
    if levels.size < columns:
        shown = ', '.join(f'{r:g}' for r in levels[:5]) + (' ...' if levels.size > 5 else '')
        raise ValueError(f'not enough motion for {columns} columns: the table held {levels.size} distinct rate(s) '
                         f'({shown} deg/s); a polynomial with powers of the rate 0..{columns - 1} needs at least '
                         f'{columns}: log more table rates, or fit --columns {max(levels.size, 1)}')
    temp = np.asarray(temp_c, dtype=float)
    low, high = float(np.min(temp)), float(np.max(temp))
    need = (rows - 1) * MIN_TEMP_SPAN_PER_POWER_C
    if high - low < need:
        fits = int((high - low) // MIN_TEMP_SPAN_PER_POWER_C) + 1
        raise ValueError(f'not enough temperature range for {rows} rows: the log spans {high - low:.2f} degC '
                         f'({low:.2f}..{high:.2f}); a polynomial with powers of the temperature 0..{rows - 1} needs '
                         f'at least {need:g} degC ({MIN_TEMP_SPAN_PER_POWER_C:g} per power): log a wider '
                         f'temperature range, or fit --rows {fits}')


@dataclass(frozen=True)
class TermSpec:
    """The shape of an extended term before its coefficients are fitted."""

    signal: str
    form: str
    powers: tuple[int, ...] = ()
    time_constant_s: float = 0.0
    rate_powers: tuple[int, ...] = (0,)

    @property
    def width(self) -> int:
        """Number of coefficients."""
        return Term.width(self.form, self.powers, self.rate_powers)

    def basis(self, signals: Signals, rows: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """Unscaled basis columns over every sample of ``signals``, or over its ``rows``.

        The signal is made over every sample (a lag's recursion runs through all), the basis of it only where asked
        (every form's is sample by sample).
        """
        x, rate = signals.for_term(self), signals.rate
        if rows is not None:
            x, rate = x[rows], rate[rows]
        return term_basis(self.form, x, self.powers, self.time_constant_s, self.rate_powers, rate)

    def term(self, coefficients: Sequence[float] | NDArray[np.float64]) -> Term:
        """The term with fitted ``coefficients``."""
        return Term(self.signal, self.form, tuple(float(c) for c in coefficients), self.powers,
                    self.time_constant_s, self.rate_powers)


@dataclass(frozen=True)
class Scaling:
    """Maps temperature and rate into [-1, 1]: ``u = (T - temp_center) / temp_half_range``, ``v = r / rate_scale``."""

    temp_center: float
    temp_half_range: float
    rate_scale: float

    @classmethod
    def of(cls, temp_c: ArrayLike, rate_dps: ArrayLike) -> Scaling:
        """Scaling that spans the data given."""
        temp = np.asarray(temp_c, dtype=float)
        rate = np.asarray(rate_dps, dtype=float)
        low, high = float(temp.min()), float(temp.max())
        return cls(0.5 * (low + high), max(0.5 * (high - low), 1.0), max(float(np.abs(rate).max()), 1.0))


def polynomial_basis(rate_dps: ArrayLike, temp_c: ArrayLike, rows: int, columns: int,
                     scaling: Scaling) -> NDArray[np.float64]:
    """Columns ``u**a * v**b`` (column ``a * columns + b``) of the scaled polynomial."""
    u = (np.asarray(temp_c, dtype=float) - scaling.temp_center) / scaling.temp_half_range
    v = np.asarray(rate_dps, dtype=float) / scaling.rate_scale
    out = np.empty((len(u), rows * columns))
    u_power = np.ones_like(u)
    for a in range(rows):
        uv = u_power.copy()
        for b in range(columns):
            out[:, a * columns + b] = uv
            uv *= v
        u_power *= u
    return out


def polynomial_from_scaled(beta: ArrayLike, rows: int, columns: int, scaling: Scaling) -> ArtPolynomial:
    """Report-form polynomial of the scaled coefficients ``beta`` (as ordered by :func:`polynomial_basis`)."""
    b = np.asarray(beta, dtype=float).reshape(rows, columns)
    tc, ts, rs = scaling.temp_center, scaling.temp_half_range, scaling.rate_scale
    raw = np.zeros((rows, columns))  # raw[k, j] multiplies T**k r**j
    for a in range(rows):
        for k in range(a + 1):
            raw[k] += b[a] * comb(a, k) * (-tc) ** (a - k) / ts ** a
    raw /= rs ** np.arange(columns)
    return ArtPolynomial(raw[::-1, ::-1])


def centring(low: NDArray[np.float64], high: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Offsets and scales that map columns spanning ``low`` to ``high`` into [-1, 1] (a constant one: scale 1).

    A term's signal may sit far from zero (a 24 V supply, an air pressure in Pa); centring
    keeps its column from nearly repeating the polynomial's constant.
    """
    offset = 0.5 * (high + low)
    scale = 0.5 * (high - low)
    scale[scale == 0.0] = 1.0
    return offset, scale


Ranges = dict[TermSpec, tuple[NDArray[np.float64], NDArray[np.float64]]]


def term_ranges(signals: Signals, specs: Sequence[TermSpec], index: NDArray[np.int64],
                chunk_rows: int | None = None) -> Ranges:
    """The :func:`centring` of each spec's basis over the rows ``index``, in one pass over the log's chunks."""
    low: dict[TermSpec, NDArray[np.float64]] = {}
    high: dict[TermSpec, NDArray[np.float64]] = {}
    for chunk in chunks(signals, index, chunk_rows):
        for spec in specs:
            basis = spec.basis(chunk.signals, chunk.rows)   # every chunk: a lag's recursion runs through all
            if len(basis):
                low[spec] = np.minimum(low[spec], basis.min(axis=0)) if spec in low else basis.min(axis=0)
                high[spec] = np.maximum(high[spec], basis.max(axis=0)) if spec in high else basis.max(axis=0)
    if len(low) < len(set(specs)):
        raise ValueError('no rows to centre the terms\' columns on')
    return {spec: centring(low[spec], high[spec]) for spec in specs}


def _spans(index: NDArray[np.int64], *columns: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Each column's lowest and highest value over the rows ``index``, a piece of the rows at a time."""
    pieces = range(0, len(index), PIECE_ROWS)
    return [np.array([min(float(c[index[i:i + PIECE_ROWS]].min()) for i in pieces),
                      max(float(c[index[i:i + PIECE_ROWS]].max()) for i in pieces)]) for c in columns]


class Design:
    """Scaled design of the polynomial and the terms ``specs`` over the rows ``index``, built chunk by chunk.

    Polynomial columns are scaled monomials, then one column per run after the first of
    several (1 on its rows: its turn-on bias beside the first run's); term columns are
    centred and scaled (:func:`centring` over the rows ``index``). ``ranges`` caches the terms' centring
    across designs of the same rows (it is filled with what is missing).
    """

    def __init__(self, signals: Signals, rows: int, columns: int, specs: Sequence[TermSpec] = (),
                 index: NDArray[np.int64] | None = None, ranges: Ranges | None = None,
                 chunk_rows: int | None = None) -> None:
        if rows < 1 or columns < 1:
            raise ValueError(f'the polynomial needs rows and columns >= 1, got {rows} x {columns}')
        self.signals, self.chunk_rows = signals, chunk_rows
        self.index = np.arange(len(signals)) if index is None else np.asarray(index)
        self.rows, self.columns, self.specs = rows, columns, tuple(specs)
        self.run_firsts = np.array([first for first, _ in signals.run_starts], dtype=np.int64)
        self.offsets = max(len(self.run_firsts) - 1, 0)   # the runs' own constants
        self.scaling = Scaling.of(*_spans(self.index, signals.temperature, signals.rate))
        ranges = {} if ranges is None else ranges
        missing = [spec for spec in dict.fromkeys(self.specs) if spec not in ranges]
        if missing:
            ranges.update(term_ranges(signals, missing, self.index, chunk_rows))
        base = rows * columns + self.offsets
        self.column_offset = np.concatenate([np.zeros(base)] + [ranges[s][0] for s in self.specs])
        self.column_scale = np.concatenate([np.ones(base)] + [ranges[s][1] for s in self.specs])

    @property
    def width(self) -> int:
        """Number of columns."""
        return self.rows * self.columns + self.offsets + sum(spec.width for spec in self.specs)

    def matrix(self, chunk: Chunk) -> NDArray[np.float64]:
        """The scaled columns over the chunk's selected rows."""
        signals, rows = chunk.signals, chunk.rows
        out = np.empty((len(rows), self.width))
        p = self.rows * self.columns
        out[:, :p] = polynomial_basis(signals.rate[rows], signals.temperature[rows], self.rows, self.columns,
                                      self.scaling)
        if self.offsets:   # a chunk lies within one run
            out[:, p:p + self.offsets] = 0.0
            run = int(np.searchsorted(self.run_firsts, chunk.start, side='right')) - 1
            if run:
                out[:, p + run - 1] = 1.0
            p += self.offsets
        for spec in self.specs:   # every chunk: a lag's recursion runs through all
            out[:, p:p + spec.width] = (spec.basis(signals, rows) - self.column_offset[p:p + spec.width]) \
                / self.column_scale[p:p + spec.width]
            p += spec.width
        return out

    @property
    def instrumented(self) -> NDArray[np.int64]:
        """The columns of the terms on :data:`INSTRUMENTED_SIGNALS`."""
        p = self.rows * self.columns + self.offsets
        out: list[int] = []
        for spec in self.specs:
            if spec.signal in INSTRUMENTED_SIGNALS:
                out.extend(range(p, p + spec.width))
            p += spec.width
        return np.asarray(out, dtype=np.int64)

    def instrument_bins(self) -> NDArray[np.int64]:
        """Each selected row's bin: :data:`INSTRUMENT_BIN_S` of the clock within contiguous selected rows."""
        if not len(self.index):
            return np.zeros(0, dtype=np.int64)
        cell = np.floor(self.signals.t[self.index] / INSTRUMENT_BIN_S)
        change = (np.diff(self.index) != 1) | (np.diff(cell) != 0)
        return np.concatenate(([0], np.cumsum(change))).astype(np.int64)

    def chunks(self) -> Iterator[tuple[Chunk, NDArray[np.float64]]]:
        """Each chunk of the log with its :meth:`matrix`."""
        for chunk in chunks(self.signals, self.index, self.chunk_rows):
            yield chunk, self.matrix(chunk)

    def model(self, beta: ArrayLike) -> ErrorModel:
        """The error model of scaled coefficients ``beta``."""
        coef = np.asarray(beta, dtype=float) / self.column_scale
        # Term columns were centred: the polynomial's constant (column 0, u**0 v**0) takes their means back.
        coef[0] -= coef @ self.column_offset
        p = self.rows * self.columns
        polynomial = polynomial_from_scaled(coef[:p], self.rows, self.columns, self.scaling)
        p += self.offsets
        terms = []
        for spec in self.specs:
            terms.append(spec.term(coef[p:p + spec.width]))
            p += spec.width
        return ErrorModel(polynomial, tuple(terms))

    def run_offsets(self, beta: ArrayLike) -> tuple[float, ...]:
        """Each run's turn-on bias less the first's (deg/s; the first's 0.0): one per run of several, else ()."""
        if not len(self.run_firsts):
            return ()
        p = self.rows * self.columns
        return (0.0, *(float(c) for c in np.asarray(beta, dtype=float)[p:p + self.offsets]))


class Instruments:
    """The instrumented rows of ``Z'X`` and ``Z'y`` (the module's docstring), summed per bin over a design's chunks.

    Per bin of :meth:`Design.instrument_bins` (a bin may span two chunks), the sums of the columns
    and the error; then a bin's rows of ``Z'X`` are its instrumented columns' sums times its
    columns' sums over its row count. Least squares keeps ``X'X`` on the other rows.
    """

    def __init__(self, design: Design) -> None:
        self.columns = design.instrumented
        self.bins = design.instrument_bins() if self.columns.size else np.zeros(0, dtype=np.int64)
        self.sums = np.zeros((int(self.bins[-1]) + 1 if self.bins.size else 0, design.width + 1))
        self.counts = np.bincount(self.bins, minlength=len(self.sums)).astype(float)

    def add(self, chunk: Chunk, x: NDArray[np.float64], y: NDArray[np.float64]) -> None:
        """Add a chunk's design rows ``x`` and error ``y`` (its selected rows) into their bins."""
        if self.columns.size and len(y):
            mine = self.bins[chunk.positions]
            first = np.flatnonzero(np.diff(mine, prepend=-1))   # bins increase along the rows
            self.sums[mine[first]] += np.add.reduceat(np.column_stack([x, y]), first, axis=0)

    def rows(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per bin, its instrumented rows of ``Z'X`` (bins, instrumented, width) and of ``Z'y`` (bins, instrumented)."""
        means = self.sums[:, self.columns] / np.maximum(self.counts, 1.0)[:, None]
        return means[:, :, None] * self.sums[:, None, :-1], means * self.sums[:, -1:]

    def first_rows(self) -> NDArray[np.int64]:
        """Each bin's first row among the selected rows (a position in the design's ``index``)."""
        return np.flatnonzero(np.diff(self.bins, prepend=-1))


def solve_normal(gram: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least-squares solution of normal equations on a scaled basis (minimum norm if rank-deficient)."""
    return np.asarray(np.linalg.lstsq(gram, rhs, rcond=1e-13)[0], dtype=np.float64)


@dataclass(frozen=True)
class Fit:
    """A fitted model and its residual over the rows it was fitted on."""

    model: ErrorModel
    index: NDArray[np.int64]
    residual: NDArray[np.float64]
    run_offsets_dps: tuple[float, ...] = ()   # Design.run_offsets: each run's turn-on bias less the first's


def fit_model(signals: Signals, error: ArrayLike, rows: int, columns: int,
              specs: Sequence[TermSpec] = (), index: NDArray[np.int64] | None = None, *,
              ranges: Ranges | None = None, chunk_rows: int | None = None) -> Fit:
    """Fit the rows x columns polynomial and the terms ``specs`` jointly to ``error`` (deg/s, one per sample).

    ``index`` selects the rows to fit (increasing, e.g. the steady rows of a rate-table
    log); the residual returned is over those rows. Terms on the temperature rate are
    instrumented (the module's docstring). The normal equations are summed chunk
    by chunk (:mod:`art_gyro_calibration.analysis.chunks`, ``chunk_rows`` rows each), so
    memory holds no matrix with a row per log row; ``ranges`` is :class:`Design`'s cache.
    """
    e = np.asarray(error, dtype=float)
    idx = np.arange(len(e)) if index is None else np.asarray(index)
    if idx.size < rows * columns + max(len(signals.run_starts) - 1, 0) + sum(s.width for s in specs):
        raise ValueError(f'{idx.size} samples cannot determine a {rows} x {columns} polynomial '
                         f'and {len(specs)} extended terms')
    design = Design(signals, rows, columns, specs, idx, ranges, chunk_rows)
    instruments = Instruments(design)
    gram = np.zeros((design.width, design.width))
    cross = np.zeros(design.width)
    for chunk, x in design.chunks():
        y = e[chunk.start + chunk.rows]
        gram += x.T @ x
        cross += x.T @ y
        instruments.add(chunk, x, y)
    if instruments.columns.size:
        iv_gram, iv_cross = instruments.rows()
        gram[instruments.columns] = iv_gram.sum(axis=0)
        cross[instruments.columns] = iv_cross.sum(axis=0)
    beta = solve_normal(gram, cross)
    residual = np.empty(idx.size)
    for chunk, x in design.chunks():
        residual[chunk.positions] = e[chunk.start + chunk.rows] - x @ beta
    return Fit(design.model(beta), idx, residual, design.run_offsets(beta))
