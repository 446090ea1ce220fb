"""What a term active in the node's static-bias window will cost a mission, and whether it is written.

The node takes its static bias over a run's first ``bias_samples`` rows with the terms applied
(:func:`compensation.apply_calibration`): a term's value there, as the node takes it, goes into
``CalcStaticBiasDrift`` and is carried for the whole mission, while the term's own value decays
(a warm-up) or swings about zero (a temperature rate). A coefficient error ``d`` of such a term
leaves ``w . d`` in every row after the window: ``w`` the mean of the term's columns over the window
as the node takes them (a temperature rate: the refinement's, :class:`static_bias.Refinement`), less
what the polynomial takes with the term when its coefficient moves (the columns' projection on the
polynomial over the fitted rows: a lagged temperature is mostly the temperature, and its coefficient
trades with the polynomial's; a constant cancels in the node).

The spread of ``w . beta``: the coefficients' covariance under the noise, a white part and a
Gauss-Markov wander (1-minute means) fitted to what the fit leaves as the fit would leave them
(:func:`_kernel`): a bias that wanders for an hour counts as such, not as white noise, and what the
fit took of it is put back. With several runs, at least the spread of leave-one-run-out refits (a
warm-up's amplitude against each run's turn-on bias and start); they alone may agree by chance. Not
a jackknife over blocks of one run: a warm-up's amplitude rests on the first block, and a refit
without it carries the written shape back from hours later (it read several times the error the
written warm-up then made on a second cold run, and dropped warm-ups that helped). A term with a
time constant is spread with it held and free (:func:`_uncertainty`). A wander longer than the
runs, or of another shape, leaves the coefficient further off than it says.

A term whose implied bias exceeds what it removes (the rms over the rows after the window of what
it corrects beyond the polynomial, net of its window value) is not written. Correlated stand-ins:
when several window terms are written and one of them alone, refitted with the polynomial, corrects
what the set corrects within the set's own implied bias, that one is written instead.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls  # type: ignore[import-untyped]  # scipy ships no types

from art_gyro_calibration.analysis.chunks import chunks
from art_gyro_calibration.analysis.fit import Design, Instruments, TermSpec, polynomial_basis, solve_normal
from art_gyro_calibration.analysis.loop import LoopResult
from art_gyro_calibration.analysis.runs import Run, run_of_rows
from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.signals import LAGGED_SIGNAL, POWER_ON_SIGNAL
from art_gyro_calibration.static_bias import refinement_span_s
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS

# The signals whose terms act in the static-bias window: the warm-up, and the filtered signals (their
# filter, or the refinement, gives them a value there that the coefficient carries into the bias).
WINDOW_SIGNALS = (POWER_ON_SIGNAL, 'temperature_rate', LAGGED_SIGNAL, 'rate_change')
# The noise's model is fitted to the residual's autocovariance over lags to this fraction of the longest run (longer
# lags pair too few bins).
MAX_LAG_SHARE = 0.25
# The fit's sums are kept per bin of this many seconds of a run, and grouped into blocks or runs from there.
BIN_S = 60.0
# A term with a time constant (a warm-up, a lag) is spread with a twin of its time constant times exp of this beside
# it: the pair spans the term and its derivative in log(tau), so each refit moves the time constant too (the amplitude
# at power-on trades with it) where the written term's is held.
TWIN_LOG_STEP = 0.1


@dataclass(frozen=True)
class TermCost:
    """One window term: what it puts in the window, its uncertainty there as a mission bias, what it removes (deg/h).

    ``written``: its implied bias is within what it removes. ``settle``: the run that would settle its doubt.
    """

    signal: str
    description: str
    window_dph: float
    implied_bias_dph: float
    removes_dph: float
    written: bool
    settle: str = ''

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's entry."""
        return asdict(self)

    def not_written(self) -> str:
        """Why the term is not written, and what would settle it ('' when it is written)."""
        if self.written:
            return ''
        return (f'the {self.signal} term is not written: its value in the static-bias window is uncertain by '
                f'{self.implied_bias_dph:.2f} deg/h, a bias for the whole mission, more than the '
                f'{self.removes_dph:.2f} deg/h it removes after the window; {self.settle}')


@dataclass(frozen=True)
class WindowCost:
    """The loop's result with the window terms it should not write dropped (the rest refitted), and why.

    ``method``: how the uncertainty was measured; ``runs``: how many runs it was measured on; ``stand_ins``: why one
    term replaced several ('' if none did).
    """

    result: LoopResult
    costs: tuple[TermCost, ...]
    method: str
    runs: int
    stand_ins: str = ''

    def section(self) -> dict[str, Any]:
        """REPORT.json's ``window_terms``."""
        return {'method': self.method, 'runs': self.runs, 'terms': [c.to_dict() for c in self.costs],
                'stand_ins': self.stand_ins or None}


def _spec(term: Term) -> TermSpec:
    """A term's shape: its fields less the coefficients."""
    return TermSpec(**{f.name: getattr(term, f.name) for f in fields(TermSpec)})


def _kernel(bin_k: NDArray[np.int64], run_bins: int, residual: NDArray[np.float64], columns: NDArray[np.float64],
            influence: NDArray[np.float64]) -> tuple[NDArray[np.float64], str]:
    """The noise's covariance per lag (:data:`BIN_S` means, lags below ``run_bins``): white and a Gauss-Markov wander.

    Fitted to what the fit leaves, as the fit would leave it: the residual at the grid places ``bin_k`` is
    ``(I - H) e``, ``H = columns @ influence`` the fit's bins' hat matrix (``columns`` the bins' mean
    design rows), so its autocovariance is that of ``(I - H) S (I - H)'`` for the noise's ``S``. The
    fit and the runs' constants take much of a wander as long as a run out of its residual, and a
    kernel read off the residual itself (tapered where it fell below 1/e) put the spread of a warm-up's
    window value at a half to a third of what it was. For each time constant on a grid up to the
    longest run, the white and the wander variances are a non-negative least-squares fit of the
    expected autocovariance to the residual's over lags to :data:`MAX_LAG_SHARE` of that run, weighted
    by their pairs; the best fit is taken. Runs lie on the grid apart by more than ``run_bins`` (no
    pair spans two). How it was made, for people.
    """
    n = int(bin_k[-1]) + 1
    size = 1 << int(2 * n).bit_length()
    lags = max(int(run_bins * MAX_LAG_SHARE), 1)
    present = np.zeros(n)
    present[bin_k] = 1.0
    x = np.zeros((columns.shape[1], n))
    x[:, bin_k] = columns.T
    b = np.zeros_like(x)
    b[:, bin_k] = influence
    grid = np.zeros(n)
    grid[bin_k] = residual - residual.mean()
    fx, fb, fm = (np.fft.rfft(v, size) for v in (x, b, present))
    pairs = np.rint(np.fft.irfft(np.conj(fm) * fm, size)[:lags + 1])
    observed = np.fft.irfft(np.conj(np.fft.rfft(grid, size)) * np.fft.rfft(grid, size), size)[:lags + 1]

    def expected(lag_kernel: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per lag 0..lags, the sum over pairs of ``(I - H) S (I - H)'`` for ``S``'s covariance per lag."""
        whole = np.zeros(size)
        whole[:len(lag_kernel)] = lag_kernel
        whole[size - len(lag_kernel) + 1:] = lag_kernel[:0:-1]
        fs = np.fft.rfft(whole)
        c = np.fft.irfft(fs * fb, size)[:, :n] * present      # S B' (columns of C), on the bins present
        fc = np.fft.rfft(c, size)
        q = b @ c.T                                            # B S B'
        cross = np.sum(np.conj(fx) * fc + np.conj(fc) * fx, axis=0)
        both = np.sum(np.conj(fx) * (q @ fx), axis=0)
        own = np.zeros(lags + 1)
        own[:min(lags + 1, len(lag_kernel))] = lag_kernel[:lags + 1]
        return np.asarray(np.fft.irfft(both - cross, size)[:lags + 1] + pairs * own, dtype=np.float64)

    white_kernel = np.zeros(run_bins)
    white_kernel[0] = 1.0
    white = expected(white_kernel)
    weight = np.sqrt(pairs) / np.maximum(pairs, 1.0)   # a lag's mean product is as uncertain as 1/sqrt(its pairs)
    fits = []
    for tau in np.geomspace(0.5, run_bins, 24):
        variances, misfit = nnls(np.stack([white, expected(np.exp(-np.arange(run_bins) / tau))], axis=1)
                                 * weight[:, None], observed * weight)
        fits.append((misfit, float(variances[0]), float(variances[1]), float(tau)))
    _, white_var, wander_var, tau = min(fits)
    kernel = wander_var * np.exp(-np.arange(run_bins) / tau)
    kernel[0] += white_var
    return kernel, (f'the coefficients\' covariance with the noise fitted to what the fit leaves, as the fit leaves '
                    f'it: 1 min means, white {math.sqrt(white_var) * DEG_PER_H_PER_DPS:.2f} deg/h and a wander of '
                    f'{math.sqrt(wander_var) * DEG_PER_H_PER_DPS:.2f} deg/h correlated for '
                    f'{tau * BIN_S / 60.0:.0f} min')


class _Fit:
    """The polynomial, a constant per run beyond the first and ``specs`` on the loop's steady rows, and its spread.

    ``beta`` (scaled, :class:`Design`) of all rows; ``influence`` (how beta moves with each bin's error) and
    ``kernel`` (the noise's covariance per lag, :func:`_kernel`); several runs: also ``replicates``, one per run
    left out.
    ``projection``: the term columns' least-squares projection on the polynomial's (and the runs' constants).
    ``free_time_constants``: each spec with a time constant has its twin (:data:`TWIN_LOG_STEP`) beside it, its
    columns among the spec's (``columns``).
    """

    def __init__(self, result: LoopResult, specs: Sequence[TermSpec], runs: Sequence[Run],
                 free_time_constants: bool = False) -> None:
        polynomial = result.art.polynomial
        index = result.segments.rows()
        self.runs, self.specs = runs, tuple(specs)
        twins = [replace(s, time_constant_s=s.time_constant_s * math.exp(TWIN_LOG_STEP)) for s in specs
                 if free_time_constants and s.time_constant_s > 0.0]
        self.design = Design(result.signals, polynomial.rows, polynomial.columns, [*specs, *twins], index)
        # Sums per bin of BIN_S of a run (consecutive rows), then per group of bins.
        t = result.signals.t
        run = run_of_rows(runs, index)
        k = np.floor((t[index] - t[[r.first_row for r in runs]][run]) / BIN_S).astype(np.int64)
        keys, first, bins = np.unique(run * (int(k.max()) + 1) + k, return_index=True, return_inverse=True)
        width = self.design.width   # the polynomial's, each later run's constant (Design's), the terms'
        gram = np.zeros((len(keys), width, width))
        cross = np.zeros((len(keys), width))
        instruments = Instruments(self.design)
        for chunk, x in self.design.chunks():
            rows = chunk.start + chunk.rows
            e = result.error[rows]
            b = bins[chunk.positions]
            cuts = np.flatnonzero(np.diff(b)) + 1
            for low, high in zip(np.r_[0, cuts], np.r_[cuts, len(b)]) if len(b) else ():
                gram[b[low]] += x[low:high].T @ x[low:high]
                cross[b[low]] += x[low:high].T @ e[low:high]
            instruments.add(chunk, x, e)
        if instruments.columns.size:   # as fit_model solves it: each instrument bin's rows in its first row's bin
            iv_gram, iv_cross = instruments.rows()
            owner = bins[instruments.first_rows()]
            own_gram = np.zeros((len(keys), *iv_gram.shape[1:]))
            own_cross = np.zeros((len(keys), iv_cross.shape[1]))
            np.add.at(own_gram, owner, iv_gram)
            np.add.at(own_cross, owner, iv_cross)
            gram[:, instruments.columns, :] = own_gram
            cross[:, instruments.columns] = own_cross
        total, rhs = gram.sum(axis=0), cross.sum(axis=0)
        self.beta = solve_normal(total, rhs)
        # The constant column is 1 on every row: a bin's residual sum is its error's less its columns' sums times beta.
        residual = (cross[:, 0] - gram[:, 0, :] @ self.beta) / gram[:, 0, 0]
        self.width = width
        # Per bin, how beta moves with its rows' error: a bin's columns' sums are the constant column's row.
        self.influence = solve_normal(total, gram[:, 0, :].T)
        # Each run's bins on one grid, runs apart by more than the longest run (the kernel's lags).
        run_bins = int(k.max()) + 1
        self.bin_k = run[first] * 2 * run_bins + k[first]
        self.kernel, self.method = _kernel(self.bin_k, run_bins, residual, gram[:, 0, :] / gram[:, 0, :1],
                                           self.influence)
        self.replicates: NDArray[np.float64] | None = None
        if len(runs) > 1:
            run_gram, run_cross = np.zeros((len(runs), width, width)), np.zeros((len(runs), width))
            np.add.at(run_gram, run[first], gram)
            np.add.at(run_cross, run[first], cross)
            self.replicates = np.array(
                [solve_normal(total - run_gram[r], rhs - run_cross[r]) for r in range(len(runs)) if run_gram[r, 0, 0]])
            self.method = f'the larger of leave-one-run-out over {len(runs)} runs and {self.method}'
        else:
            self.method = f'on the one run, {self.method}'
        p = polynomial.rows * polynomial.columns
        q = p + self.design.offsets
        self.poly_columns = np.r_[0:q]
        self.term_columns = np.arange(q, width)
        self.projection = solve_normal(total[np.ix_(self.poly_columns, self.poly_columns)],
                                       total[np.ix_(self.poly_columns, self.term_columns)])
        # Per spec, its columns among the term columns (and its twin's).
        edges = np.cumsum([0, *(s.width for s in self.design.specs)])
        own = [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:])]
        twin_of = iter(own[len(specs):])
        self.columns = [np.concatenate([c, next(twin_of)]) if free_time_constants and s.time_constant_s > 0.0 else c
                        for s, c in zip(specs, own)]

    def spread(self, statistic: NDArray[np.float64]) -> float:
        """The standard deviation of ``statistic @ beta`` (deg/s) from the noise, and at least over the runs left out.

        From the noise: at least its lag-0 product (a floor kept from the kernel read off the residual, whose long
        lags could read below zero; under the fitted kernel it binds only where the statistic's own influence
        alternates in sign). The runs left out alone may agree by chance (two or three runs).
        """
        h = np.zeros(int(self.bin_k[-1]) + 1)
        h[self.bin_k] = statistic @ self.influence
        n, lags = len(h), len(self.kernel)
        products = np.correlate(h, h, 'full')[n - 1:n - 1 + lags]
        white = float(products[0] * self.kernel[0])
        noise = math.sqrt(max(white + 2.0 * float(products[1:] @ self.kernel[1:]), white, 0.0))
        return noise if self.replicates is None else max(noise, _jackknife_std(self.replicates @ statistic))

    def beyond_polynomial(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """The term columns of ``x`` less their projection on the polynomial's."""
        return np.asarray(x[:, self.term_columns] - x[:, self.poly_columns] @ self.projection, dtype=np.float64)

    def term_beta(self, beta: NDArray[np.float64]) -> NDArray[np.float64]:
        """The term columns' coefficients of ``beta`` (scaled)."""
        return np.asarray(beta[..., self.term_columns], dtype=np.float64)

    def calibration_of(self, result: LoopResult) -> LoopResult:
        """``result`` with this fit's polynomial and terms as the extended calibration, its effects those kept."""
        model = self.design.model(self.beta[:self.design.width])
        kept = {term.signal: term for term in model.terms}
        effects = tuple(replace(e, term=kept[e.signal]) for e in result.effects if e.signal in kept)
        return replace(result, extended=replace(result.extended, polynomial=model.polynomial, terms=model.terms),
                       effects=effects)


def node_window(result: LoopResult, spec: TermSpec, run: Run, bias_samples: int) -> NDArray[np.float64]:
    """Per column of ``spec``, its mean over ``run``'s static-bias window as the node takes it (refined if it is).

    The node's own path (:func:`compensation.apply_calibration`) with the term alone of a unit
    coefficient on that column: its ``CalcStaticBiasDrift`` once the refinement (a temperature
    rate's) has run.
    """
    signals = result.signals
    t, a = signals.t, run.first_row
    span_s = refinement_span_s(result.extended.filters.refinement_scale_s)
    stop = min(run.stop, max(a + bias_samples, int(np.searchsorted(t, t[a] + span_s)) + 2))
    part = slice(a, stop)
    log = GyroLog(t[part], signals.rate[part], signals.temperature[part], None,
                  {k: v[part] for k, v in signals.extras.items()})
    zero = replace(result.extended, polynomial=ArtPolynomial(np.zeros((1, 1))))
    out = np.empty(spec.width)
    for j, unit in enumerate(np.eye(spec.width)):
        applied = apply_calibration(log, replace(zero, terms=(spec.term(unit),)), bias_samples, math.inf, math.inf,
                                    start=RunStart(powered_on_at_start=run.powered_on_at_start))
        out[j] = applied.bias.calc_static_bias_drift_dps
    return out


def _windows(result: LoopResult, fit: _Fit, bias_samples: int) -> NDArray[np.float64]:
    """Per run (rows), each term column's mean over its window as the node takes it, scaled, beyond the polynomial."""
    design, signals = fit.design, result.signals
    out = np.empty((len(fit.runs), len(fit.term_columns)))
    for r, run in enumerate(fit.runs):
        rows = slice(run.first_row, run.first_row + bias_samples)
        poly = np.zeros(len(fit.poly_columns))
        p = design.rows * design.columns
        poly[:p] = polynomial_basis(signals.rate[rows], signals.temperature[rows], design.rows, design.columns,
                                    design.scaling).mean(axis=0)
        if r:
            poly[p + r - 1] = 1.0
        raw = np.concatenate([node_window(result, spec, run, bias_samples) for spec in design.specs])
        terms = fit.term_columns
        out[r] = (raw - design.column_offset[terms]) / design.column_scale[terms] - poly @ fit.projection
    return out


def _after_window(result: LoopResult, fits: Sequence[_Fit], windows: Sequence[NDArray[np.float64]],
                  bias_samples: int) -> Iterator[tuple[NDArray[np.int64], list[NDArray[np.float64]]]]:
    """Chunk by chunk over the rows after each run's window: the run of each row, and per fit its corrections.

    Per fit, per spec of it: what the term corrects there beyond the polynomial, net of its window value
    (deg/s, rows x specs).
    """
    runs = fits[0].runs
    rows = np.concatenate([np.arange(run.first_row + bias_samples, run.stop) for run in runs])
    for chunk in chunks(result.signals, rows):
        if not len(chunk.rows):
            continue
        where = chunk.start + chunk.rows
        run = run_of_rows(runs, where)
        out = []
        for fit, window in zip(fits, windows):
            beyond = fit.beyond_polynomial(fit.design.matrix(chunk)) - window[run]
            beta = fit.term_beta(fit.beta)
            out.append(np.stack([beyond[:, c] @ beta[c] for c in fit.columns], axis=1))
        yield run, out


def _jackknife_std(values: NDArray[np.float64]) -> float:
    """The jackknife's standard deviation of a statistic from its replicates (one per run left out)."""
    g = len(values)
    return float(np.sqrt((g - 1) / g * np.sum((values - values.mean()) ** 2))) if g > 1 else math.inf


def _implied(fit: _Fit, window: NDArray[np.float64], specs: Sequence[int]) -> float:
    """The uncertainty of the window value of the specs numbered ``specs`` together, rms over the runs, deg/s."""
    columns = np.concatenate([fit.columns[i] for i in specs])
    spreads = []
    for w in window:
        statistic = np.zeros(fit.width)
        statistic[fit.term_columns[columns]] = w[columns]
        spreads.append(fit.spread(statistic))
    return float(np.sqrt(np.mean(np.square(spreads))))


def _uncertainty(fit: _Fit, windows: NDArray[np.float64], spread: tuple[_Fit, NDArray[np.float64]],
                 specs: Sequence[int]) -> float:
    """The larger of :func:`_implied` with the time constants held and free (:func:`_spread`), deg/s.

    Free, the amplitude at power-on trades with the time constant (a warm-up fitted at 976 s for 1200 s
    is 16 % high at power-on); held, the written shape alone.
    """
    return max(_implied(fit, windows, specs), _implied(*spread, specs))


def settle(signal: str, signals: Sequence[str], runs: Sequence[Run]) -> str:
    """Which run would settle a window term on ``signal`` (``signals``: the window terms beside it)."""
    cold = sum(run.powered_on_at_start for run in runs)
    warm = len(runs) - cold
    if signal == POWER_ON_SIGNAL:
        if 'temperature_rate' in signals and not warm:
            return 'a warm restart would tell the warm-up from the Shupe (temperature-rate) term'
        return ('a second power-on' if cold < 2 else 'another power-on') + ' (a cold start at another chamber ' \
            'temperature) would fix the warm-up\'s amplitude apart from a turn-on bias'
    if signal == 'temperature_rate':
        return ('a second power-on (its self-heating is the temperature rate the window sees) or a warm restart '
                'during a chamber ramp would fix the temperature rate\'s coefficient where the window takes it')
    if signal == LAGGED_SIGNAL:
        return 'a warm restart during a chamber ramp would tell the lagged temperature from the temperature'
    return 'more table steps of both signs would fix the rate change\'s coefficient'


def window_cost(result: LoopResult, runs: Sequence[Run], bias_samples: int) -> WindowCost:
    """Each window term of ``result.extended``: its implied mission bias, what it removes; the terms to write.

    ``runs``: the runs among the loop's rows (one over the whole log for a single log). First, when
    several window terms are written, one alone replaces them if it corrects what they do within their
    implied bias (of several such, one that would be written first, then the fewest coefficients, then
    the smallest implied bias: a stand-in as good as the set may be as uncertain too); then a term whose
    implied bias exceeds what it removes is dropped and the rest refitted.
    """
    specs = [_spec(t) for t in result.extended.terms]
    window = [s for s in specs if s.signal in WINDOW_SIGNALS]
    if not window:
        return WindowCost(result, (), '', len(runs))
    fit = _Fit(result, specs, runs)
    windows = _windows(result, fit, bias_samples)
    stand_ins = ''
    if len(window) > 1:
        others = [s for s in specs if s not in window]
        singles = [_Fit(result, [*others, s], runs) for s in window]
        single_windows = [_windows(result, f, bias_samples) for f in singles]
        in_set = np.array([specs.index(s) for s in window])
        squares = np.zeros(len(singles))
        count = 0
        for _, corrections in _after_window(result, [fit, *singles], [windows, *single_windows], bias_samples):
            corrected = corrections[0][:, in_set].sum(axis=1)
            squares += [np.sum((corrected - c[:, -1]) ** 2) for c in corrections[1:]]
            count += len(corrected)
        differ = np.sqrt(squares / max(count, 1))
        uncertainty = _uncertainty(fit, windows, _spread(result, fit, windows, bias_samples), list(in_set))
        single_costs = {k: _costs(result, singles[k], single_windows[k],
                                  _spread(result, singles[k], single_windows[k], bias_samples),
                                  [*others, window[k]], [window[k]], bias_samples)
                        for k in range(len(window)) if differ[k] <= uncertainty}
        if single_costs:
            k = min(single_costs, key=lambda k: (not single_costs[k][0].written, window[k].width,
                                                 single_costs[k][0].implied_bias_dph))
            stand_ins = (f'{window[k].signal} alone corrects what {", ".join(s.signal for s in window)} correct '
                         f'together within {differ[k] * DEG_PER_H_PER_DPS:.2f} deg/h (rms after the window), '
                         f'inside their implied bias of {uncertainty * DEG_PER_H_PER_DPS:.2f} deg/h: it is written '
                         'alone')
            fit, specs, window = singles[k], [*others, window[k]], [window[k]]
            result = fit.calibration_of(result)
            costs = single_costs[k]
    if not stand_ins:
        costs = _costs(result, fit, windows, _spread(result, fit, windows, bias_samples), specs, window, bias_samples)
    dropped = {c.signal for c in costs if not c.written}
    if dropped:
        result = _Fit(result, [s for s in specs if s.signal not in dropped], runs).calibration_of(result)
    free = any(s.time_constant_s > 0.0 for s in window)
    method = fit.method + ('; the larger spread of the time constants held and free' if free else '')
    return WindowCost(result, costs, method, len(runs), stand_ins)


def _spread(result: LoopResult, fit: _Fit, windows: NDArray[np.float64],
            bias_samples: int) -> tuple[_Fit, NDArray[np.float64]]:
    """``fit`` with its time constants free (:data:`TWIN_LOG_STEP`) and its windows: what the spread is taken of."""
    if not any(s.time_constant_s > 0.0 for s in fit.specs):
        return fit, windows
    spread = _Fit(result, fit.specs, fit.runs, free_time_constants=True)
    return spread, _windows(result, spread, bias_samples)


def _costs(result: LoopResult, fit: _Fit, windows: NDArray[np.float64], spread: tuple[_Fit, NDArray[np.float64]],
           specs: Sequence[TermSpec], window: Sequence[TermSpec], bias_samples: int) -> tuple[TermCost, ...]:
    """Each window term's :class:`TermCost` under ``fit``, its implied bias from ``spread`` (:func:`_spread`)."""
    runs = fit.runs
    squares = np.zeros((len(runs), len(specs)))
    counts = np.zeros(len(runs))
    for run, corrections in _after_window(result, [fit], [windows], bias_samples):
        np.add.at(squares, run, corrections[0] ** 2)
        counts += np.bincount(run, minlength=len(runs))
    removes = np.sqrt(squares.sum(axis=0) / max(counts.sum(), 1.0))
    beta = fit.term_beta(fit.beta)
    terms = {t.signal: t for t in fit.design.model(fit.beta[:fit.design.width]).terms}
    out = []
    for spec in window:
        i = specs.index(spec)
        columns = fit.columns[i]
        implied = _uncertainty(fit, windows, spread, [i]) * DEG_PER_H_PER_DPS
        value = float(np.sqrt(np.mean((windows[:, columns] @ beta[columns]) ** 2))) * DEG_PER_H_PER_DPS
        written = bool(implied <= removes[i] * DEG_PER_H_PER_DPS)
        out.append(TermCost(spec.signal, terms[spec.signal].describe(), value, implied,
                            float(removes[i]) * DEG_PER_H_PER_DPS, written,
                            settle(spec.signal, [s.signal for s in window], runs)))
    return tuple(out)
