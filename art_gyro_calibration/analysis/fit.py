"""Least-squares fit of the ART polynomial (and extended terms) to a rate-table log.

The measured error ``e = rate_dps - ref_rate`` is fitted against ``T**a * r**b``
(a < rows, b < columns) plus the bases of the extended terms. The raw monomials span
1e-9 to 1e-2 in coefficient and their columns are nearly collinear (T in [10, 50] degC),
so the solve runs on a scaled basis: ``u = (T - Tc) / Ts`` and ``v = r / Rs`` with u, v in
[-1, 1], term columns divided by their largest magnitude. The coefficients are then
mapped back exactly (binomial expansion of ``(Tc + Ts u)**a``) into the report's form.

Note on the constant: the log's error holds the run's turn-on bias and the Earth's
rate, so the fitted constant (``T**0 r**0``) absorbs them; the static bias collection
before every mission removes that constant again (``CalcStaticBiasDrift``), so only the
shape of the surface matters, not its offset.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from math import comb

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.model import ArtPolynomial, ErrorModel
from art_gyro_calibration.signals import Signals
from art_gyro_calibration.terms import Term, term_basis


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

    def basis(self, signals: Signals) -> NDArray[np.float64]:
        """Unscaled basis columns over every sample of ``signals``."""
        return term_basis(self.form, signals.for_term(self), self.powers, self.time_constant_s, self.rate_powers,
                          signals.rate)

    def term(self, coefficients: Sequence[float]) -> Term:
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


def centred(basis: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Offsets, scales and the columns ``(basis - offset) / scale`` within [-1, 1].

    A term's signal may sit far from zero (a 24 V supply, an air pressure in Pa); centring
    keeps its column from nearly repeating the polynomial's constant.
    """
    offset = 0.5 * (basis.max(axis=0) + basis.min(axis=0))
    scale = 0.5 * (basis.max(axis=0) - basis.min(axis=0))
    scale[scale == 0.0] = 1.0
    return offset, scale, (basis - offset) / scale


class Design:
    """Scaled design matrix of the polynomial and the terms ``specs`` over the rows ``index``.

    Polynomial columns are scaled monomials; term columns are centred and scaled (:func:`centred`).
    """

    def __init__(self, signals: Signals, rows: int, columns: int, specs: Sequence[TermSpec] = (),
                 index: NDArray[np.int64] | None = None) -> None:
        idx = np.arange(len(signals)) if index is None else np.asarray(index)
        if rows < 1 or columns < 1:
            raise ValueError(f'the polynomial needs rows and columns >= 1, got {rows} x {columns}')
        self.rows, self.columns, self.specs = rows, columns, tuple(specs)
        self.scaling = Scaling.of(signals.temperature[idx], signals.rate[idx])
        parts = [polynomial_basis(signals.rate[idx], signals.temperature[idx], rows, columns, self.scaling)]
        offsets, scales = [np.zeros(rows * columns)], [np.ones(rows * columns)]
        for spec in self.specs:
            offset, scale, basis = centred(spec.basis(signals)[idx])
            parts.append(basis)
            offsets.append(offset)
            scales.append(scale)
        self.matrix = np.hstack(parts)
        self.column_offset = np.concatenate(offsets)
        self.column_scale = np.concatenate(scales)

    @property
    def width(self) -> int:
        """Number of columns."""
        return self.matrix.shape[1]

    def model(self, beta: ArrayLike) -> ErrorModel:
        """The error model of scaled coefficients ``beta``."""
        coef = np.asarray(beta, dtype=float) / self.column_scale
        # Term columns were centred: the polynomial's constant (column 0, u**0 v**0) takes their means back.
        coef[0] -= coef @ self.column_offset
        p = self.rows * self.columns
        polynomial = polynomial_from_scaled(coef[:p], self.rows, self.columns, self.scaling)
        terms = []
        for spec in self.specs:
            terms.append(spec.term(coef[p:p + spec.width]))
            p += spec.width
        return ErrorModel(polynomial, tuple(terms))


def solve_normal(gram: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least-squares solution of normal equations on a scaled basis (minimum norm if rank-deficient)."""
    return np.linalg.lstsq(gram, rhs, rcond=1e-13)[0]


@dataclass(frozen=True)
class Fit:
    """A fitted model and its residual over the rows it was fitted on."""

    model: ErrorModel
    index: NDArray[np.int64]
    residual: NDArray[np.float64]


def fit_model(signals: Signals, error: ArrayLike, rows: int, columns: int,
              specs: Sequence[TermSpec] = (), index: NDArray[np.int64] | None = None) -> Fit:
    """Fit the rows x columns polynomial and the terms ``specs`` jointly to ``error`` (deg/s, one per sample).

    ``index`` selects the rows to fit (e.g. the steady rows of a rate-table log); the
    residual returned is over those rows.
    """
    e = np.asarray(error, dtype=float)
    idx = np.arange(len(e)) if index is None else np.asarray(index)
    if idx.size < rows * columns + sum(s.width for s in specs):
        raise ValueError(f'{idx.size} samples cannot determine a {rows} x {columns} polynomial '
                         f'and {len(specs)} extended terms')
    design = Design(signals, rows, columns, specs, idx)
    x = design.matrix
    beta = solve_normal(x.T @ x, x.T @ e[idx])
    return Fit(design.model(beta), idx, e[idx] - x @ beta)
