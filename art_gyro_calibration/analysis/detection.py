"""Say what a log cannot see: the smallest effect of each candidate's form the loop would have found.

A log too short for a power target (under about 6 h) still bounds what it missed. For
every candidate of the loop's last screen (:func:`trace.trace_residual`), the detection
limit is the size, worst case over the logged envelope (half the range of what the effect
adds beyond the model, deg/h, as :meth:`trace.Screen.effect_dph` measures a found one), of
the smallest effect of the candidate's form that the screen would pass as beating chance.

The screen's statistic of a candidate with weighted bin columns ``C`` against a residual
``r`` (bins weighted to unit noise, ``N`` rows) is

    s(r) = r' C_perp (C_perp' C_perp)^-1 C_perp' r / N,

``C_perp`` the columns less what the model's columns ``X`` give of them. An effect
``a * c_j`` (column ``j``, coefficient ``a`` on the scaled basis) added to the residual
gives ``|P (r + a c_j)| >= |a| |c_j,perp| - |P r|`` (``P`` the projection above, so
``s(r) = |P r|**2 / N``), whatever its sign and however it lines up with the residual; it
beats the screen's threshold ``s_T`` when

    |a| |c_j,perp| / sqrt(N) = sqrt(s_T) + sqrt(s(r)),

``s(r)`` the statistic of this log's residual (held in by the model). The limit in deg/h is
``|a|`` times half the range of ``c_j,perp`` over the bin means. A form of several columns
(a lagged temperature's polynomial, a heading's sine and cosine) or several time constants
(a warm-up) gets the largest limit of its columns and time constants, each alone: any effect
of the form at that size passes. ``s_T`` is the screen's own
(:attr:`trace.CandidateScore.threshold_dps2`): the loop's level, its surrogate null and its
maximum statistic over all candidates included. A limit below the materiality is moot: the
loop also asks that size of any effect.

Not modelled: the screen draws its chance copies from the spectrum of the residual it tests,
so an effect present raises its own bar (less where the strongest candidate's fit is taken
out first, :func:`trace.null_spectrum`). So the limit is a lower bound: slow forms (a drift,
a Shupe effect) whose power falls where the chance spectrum is measured need a few times more
than it says to be found.

How the limit scales with the log's length is measured: the same computation on the log's
first half and first quarter (the model refitted there), with the threshold scaled
by how the chance mean ``m`` of the candidate's statistic changes,
``s_T,L = s_T m_L / m_1``, and ``s(r)`` of that part's residual, each ``m`` from :data:`DETECTION_DRAWS`
phase-randomised copies of that part's residual (the screen's own surrogates; a slow wander
keeps a slow candidate's chance high however long the log). ``limit ~ hours**-p`` is fitted
to the three, and a candidate above the materiality gets the length that brings it below,
``hours * (limit / materiality)**(1 / p)``: none when ``p <= MIN_EXPONENT`` (more of the
same log does not help), flagged when that is beyond :data:`FAR_EXTRAPOLATION` times the
log. With white noise alone ``p = 1/2``.

Cost: small matrices per variant and ``DETECTION_DRAWS`` surrogates per length, on the bins
and candidate columns the screen already holds (no pass over the log).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.fit import TermSpec, solve_normal
from art_gyro_calibration.analysis.trace import (JUDGED_PER_VARIANT, Binned, Screen, TraceResult, candidate_specs,
                                                 mirrored_spectrum, phase_surrogates)
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

# Chance copies per length for the chance mean of each candidate's statistic (a mean, not a tail quantile).
DETECTION_DRAWS = 32
# The shares of the log (its first part) the limit is computed on, to measure how it scales with length.
LENGTH_SHARES = (0.25, 0.5, 1.0)
# A limit falling more slowly than hours**-MIN_EXPONENT is said not to shrink with more of the same log.
MIN_EXPONENT = 0.1
# A length needed beyond this many times the log's is flagged as a far extrapolation.
FAR_EXTRAPOLATION = 8.0


@dataclass(frozen=True)
class DetectionLimit:
    """The smallest effect of one candidate's form the loop would have found in this log.

    ``limit_dph``: its worst case over the logged envelope, deg/h, on the whole log;
    ``shape``: the column or time constant that sets it; ``by_length``: (hours, limit_dph)
    on the log's first quarter, half and whole; ``exponent``: p in ``limit ~ hours**-p``
    fitted to them; ``hours_to_materiality``: the length of log that would bring the limit
    below the materiality (None: already below, or p too small, see ``note``);
    ``coefficient``: the effect's coefficient at the limit on the shape's own column,
    deg/s per unit of the term's basis (as :class:`terms.Term` evaluates it).
    """

    signal: str
    limit_dph: float
    shape: str
    by_length: tuple[tuple[float, float], ...]
    exponent: float
    hours_to_materiality: float | None
    note: str
    spec: TermSpec
    column: int
    coefficient: float

    def to_dict(self) -> dict[str, Any]:
        """REPORT.json's entry (non-finite numbers as None)."""
        def number(x: float | None) -> float | None:
            return x if x is not None and math.isfinite(x) else None
        return {'limit_dph': number(self.limit_dph), 'shape': self.shape,
                'by_length': [[hours, number(limit)] for hours, limit in self.by_length],
                'exponent': number(self.exponent), 'hours_to_materiality': number(self.hours_to_materiality),
                'note': self.note}


def _shape(spec: TermSpec, column: int) -> str:
    """Which column and time constant of a form set its limit, in words."""
    parts = []
    if spec.width > 1:
        parts.append(f'column {column + 1} of {spec.width}')
    if spec.time_constant_s > 0.0:
        parts.append(f'{"lag" if spec.form == "power" else "tau"} {spec.time_constant_s:.0f} s')
    return ', '.join(parts)


def _limits_on(binned: Binned, x: NDArray[np.float64], e: NDArray[np.float64], keep: NDArray[np.bool_],
               families: dict[str, list[TermSpec]], draws: int, rng: np.random.Generator
               ) -> dict[str, tuple[NDArray[np.float64], list[NDArray[np.float64]]]]:
    """Per family on the bins ``keep``: its statistics and each column's coefficient and size per unit.

    Per family: (2, variants), the chance mean of the judged statistic and the statistic of
    the residual as logged, per variant; and per variant a (2, columns) array, each column's
    coefficient per square root of statistic, ``sqrt(N / |c_j,perp|**2)``, and the half
    range of ``c_j,perp`` over the bin means (deg/h per unit coefficient).
    """
    w = binned.sqrt_counts[keep]
    n_rows = float(np.sum(w * w))
    x, e = x[keep], e[keep]
    gram = x.T @ x
    residual = e - x @ solve_normal(gram, x.T @ e)
    targets = np.column_stack([residual, phase_surrogates(mirrored_spectrum(residual), draws, rng)[:len(residual)]])
    target_beta = solve_normal(gram, x.T @ targets)
    unweighted = x / w[:, None]
    unweighted_gram = unweighted.T @ unweighted
    out = {}
    for name, variants in families.items():
        chance = []
        per_unit = []
        for spec in variants:
            means = binned.candidate_means([spec])[keep, 0, :]
            c = means * w[:, None]
            cx = c.T @ x
            beyond = c.T @ c - cx @ solve_normal(gram, cx.T)
            r = c.T @ targets - cx @ target_beta
            chance.append(np.einsum('wt,wt->t', r, solve_normal(beyond, r)) / n_rows)
            perp = means - unweighted @ solve_normal(unweighted_gram, unweighted.T @ means)
            norm = np.maximum(np.diag(beyond), 0.0)
            with np.errstate(divide='ignore'):
                amplitude = np.where(norm > 0.0, np.sqrt(n_rows / np.where(norm > 0.0, norm, 1.0)), np.inf)
            per_unit.append(np.stack([amplitude, 0.5 * np.ptp(perp, axis=0) * DEG_PER_H_PER_DPS]))
        stats = np.stack(chance)   # (variants, 1 + draws): the residual as logged, then the chance copies
        judged = (stats[:, 1:].mean(axis=1) if name in JUDGED_PER_VARIANT
                  else np.full(len(variants), stats[:, 1:].max(axis=0).mean()))
        out[name] = np.stack([judged, stats[:, 0]]), per_unit
    return out


def length_scaling(by_length: Sequence[tuple[float, float]], materiality_dph: float
                   ) -> tuple[float, float | None, str]:
    """Fit ``limit ~ hours**-p`` to (hours, limit) pairs; the hours that bring the last limit below the materiality.

    Returns ``(p, hours, note)``: ``hours`` None when the limit is already at or below the
    materiality, when ``p <= MIN_EXPONENT`` (noted) or a limit is not finite; noted when
    beyond :data:`FAR_EXTRAPOLATION` times the longest length.
    """
    hours = np.array([h for h, _ in by_length])
    limits = np.array([v for _, v in by_length])
    if len(hours) < 2 or not np.all(np.isfinite(limits) & (limits > 0.0) & (hours > 0.0)):
        return math.nan, None, 'not measured: a limit is not finite'
    p = -float(np.polyfit(np.log(hours), np.log(limits), 1)[0])
    last_hours, last = float(hours[-1]), float(limits[-1])
    if last <= materiality_dph or materiality_dph <= 0.0:
        return p, None, ''
    if p <= MIN_EXPONENT:
        return p, None, 'does not shrink with more of this log'
    needed = last_hours * (last / materiality_dph) ** (1.0 / p)
    note = f'extrapolated beyond {FAR_EXTRAPOLATION:g} times the log' if needed > FAR_EXTRAPOLATION * last_hours else ''
    return p, float(needed), note


def detection_limits(binned: Binned, specs: Sequence[TermSpec], found: TraceResult, rows: int, columns: int,
                     materiality_dph: float, still: bool = False, draws: int = DETECTION_DRAWS,
                     seed: int = 0) -> tuple[DetectionLimit, ...]:
    """Per candidate of the screen ``found`` (the loop's last), its detection limit on the model ``specs``.

    ``binned`` is the loop's (its candidate columns cached), ``rows`` x ``columns`` the
    polynomial. See the module's description for the computation.
    """
    names = {c.signal: c for c in found.candidates}
    families = {name: v for name, v in candidate_specs(binned.signals, rows, columns, still=still).items()
                if name in names}
    if not families:
        return ()
    screen = Screen(binned, specs)
    x, e = screen.x, screen.e
    t = binned.bin_times()
    span = max(float(t[-1] - t[0]), 1e-9)
    rng = np.random.default_rng(seed)
    per_length = []
    for share in LENGTH_SHARES:
        keep = (t - t[0]) <= share * span + 1e-9
        hours = float(t[keep][-1] - t[0] + (t[1] - t[0] if len(t) > 1 else 0.0)) / SECONDS_PER_HOUR
        per_length.append((hours, _limits_on(binned, x, e, keep, families, draws, rng)))
    whole = per_length[-1][1]
    out = []
    for name, variants in families.items():
        score = names[name]
        threshold = score.threshold_dps2 if math.isfinite(score.threshold_dps2) else math.inf
        by_length = []
        worst: tuple[float, int, int] = (-1.0, 0, 0)
        for hours, limits in per_length:
            (chance, real), per_unit = limits[name]
            full_chance = whole[name][0][0]
            ratio = np.where(full_chance > 0.0, chance / np.where(full_chance > 0.0, full_chance, 1.0), 1.0)
            # A statistic the part's rows cannot pose (columns degenerate there): no finite limit.
            ratio = np.where(np.isfinite(ratio), np.maximum(ratio, 0.0), np.inf)
            root = np.sqrt(max(threshold, 0.0) * ratio) + np.sqrt(np.maximum(np.nan_to_num(real, nan=np.inf), 0.0))
            # A column with nothing beyond the model (no range left) is no effect the screen could see: size 0.
            with np.errstate(invalid='ignore'):
                table = [np.where(u[1] > 0.0, g * u[0] * u[1], 0.0) for g, u in zip(root, per_unit)]
            by_length.append((hours, float(max(float(np.max(v)) for v in table))))
            if limits is whole:
                worst = max((float(v[j]), i, j) for i, v in enumerate(table) for j in range(len(v)))
        limit, i, j = worst
        spec = variants[i]
        p, needed, note = length_scaling(by_length, materiality_dph)
        # The coefficient at the limit on the term's own basis: the scaled basis is (basis - offset) / scale.
        half_dph = float(whole[name][1][i][1, j])
        scale = float(np.asarray(binned.ranges[spec][1])[j]) if spec in binned.ranges else 1.0
        coefficient = limit / half_dph / scale if half_dph > 0.0 else math.inf
        out.append(DetectionLimit(name, limit, _shape(spec, j), tuple(by_length), p, needed, note, spec, j,
                                  coefficient))
    out.sort(key=lambda d: d.limit_dph, reverse=True)
    return tuple(out)
