"""Extended error terms: one physical effect the report's polynomial lacks, on one signal.

A term is linear in its coefficients, so it is fitted jointly with the polynomial;
its non-linear shape (the decay time of a warm-up) is fixed before the linear solve.

Forms (the correction in deg/s; ``x`` is the term's signal):
- ``power``: ``sum(c_k * x**p_k)`` over ``powers``; e.g. the Shupe effect of a fibre
  coil is ``c * dT/dt`` (signal ``temperature_rate``, powers ``[1]``).
- ``exp_decay``: ``c * exp(-x / time_constant_s)``; warm-up after power-on (signal ``time``).
- ``harmonic``: ``c0 * sin(x) + c1 * cos(x)`` with ``x`` in degrees; once-per-turn
  effects of the angle turned (a magnetic or tilt coupling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FORMS = ('power', 'exp_decay', 'harmonic')


@dataclass(frozen=True)
class Term:
    """One extended term: ``signal``, its ``form`` and the fitted ``coefficients``."""

    signal: str
    form: str
    coefficients: tuple[float, ...]
    powers: tuple[int, ...] = ()
    time_constant_s: float = 0.0

    def __post_init__(self) -> None:
        where = f'extended term on {self.signal!r}'
        if self.form not in FORMS:
            raise ValueError(f'{where}: form {self.form!r} is not one of {", ".join(FORMS)}')
        if not all(math.isfinite(c) for c in self.coefficients):
            raise ValueError(f'{where}: coefficients must be finite, got {self.coefficients}')
        if len(self.coefficients) != self.width(self.form, self.powers):
            raise ValueError(f'{where}: form {self.form!r} needs {self.width(self.form, self.powers)} '
                             f'coefficients, got {len(self.coefficients)}')
        if self.form == 'power' and (not self.powers or any(p < 1 for p in self.powers)):
            raise ValueError(f'{where}: powers must be whole numbers >= 1, got {self.powers}')
        if self.form == 'exp_decay' and not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise ValueError(f'{where}: time_constant_s must be positive, got {self.time_constant_s}')

    @staticmethod
    def width(form: str, powers: tuple[int, ...] = ()) -> int:
        """Number of coefficients of a term of this form."""
        return {'power': len(powers), 'exp_decay': 1, 'harmonic': 2}[form]

    def basis(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Columns the coefficients multiply, shape (len(x), width)."""
        return term_basis(self.form, x, self.powers, self.time_constant_s)

    def evaluate(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Correction in deg/s for every sample of signal ``x``."""
        return self.basis(np.asarray(x, dtype=float)) @ np.asarray(self.coefficients)

    def evaluate_one(self, x: float) -> float:
        """Correction in deg/s for one sample."""
        c = self.coefficients
        if self.form == 'power':
            return sum(ck * x ** p for ck, p in zip(c, self.powers))
        if self.form == 'exp_decay':
            return c[0] * math.exp(-x / self.time_constant_s)
        angle = math.radians(x)
        return c[0] * math.sin(angle) + c[1] * math.cos(angle)

    def describe(self) -> str:
        """One line for people."""
        c = ', '.join(f'{v:.6g}' for v in self.coefficients)
        if self.form == 'power':
            return f'power {list(self.powers)} of {self.signal}: [{c}]'
        if self.form == 'exp_decay':
            return f'exp(-{self.signal}/{self.time_constant_s:.6g} s) with amplitude [{c}] deg/s'
        return f'once-per-turn harmonic of {self.signal} (sin, cos): [{c}] deg/s'


def term_basis(form: str, x: NDArray[np.float64], powers: tuple[int, ...] = (),
               time_constant_s: float = 0.0) -> NDArray[np.float64]:
    """Basis columns of a term of ``form`` on signal values ``x``."""
    if form == 'power':
        return np.stack([x ** p for p in powers], axis=1)
    if form == 'exp_decay':
        return np.exp(-x / time_constant_s)[:, None]
    if form == 'harmonic':
        angle = np.radians(x)
        return np.stack([np.sin(angle), np.cos(angle)], axis=1)
    raise ValueError(f'form {form!r} is not one of {", ".join(FORMS)}')
