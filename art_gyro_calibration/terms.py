"""Extended error terms: one physical effect the report's polynomial lacks, on one signal.

A term is linear in its coefficients, so it is fitted jointly with the polynomial;
its non-linear shape (the decay time of a warm-up) is fixed before the linear solve.

Forms (the correction in deg/s; ``x`` is the term's signal, ``r`` the measured rate):
- ``power``: ``sum(c_jk * x**p_j * r**q_k)`` over ``powers`` p and ``rate_powers`` q (default
  ``[0]``: no rate); e.g. the Shupe effect of a fibre coil is ``c * dT/dt`` (signal
  ``temperature_rate``, powers ``[1]``), a scale factor that follows it ``c * r * dT/dt``
  (rate_powers ``[1]``), a coil temperature lagging the sensor ``sum c_jk T_lag**j r**k``
  (signal ``temperature_lag``, its lag in ``time_constant_s``).
- ``exp_decay``: ``c * exp(-x / time_constant_s)``; warm-up after power-on (signal
  ``time_since_power_on``).
- ``harmonic``: ``c0 * sin(x) + c1 * cos(x)`` with ``x`` in degrees; once-per-turn
  effects of the heading (a magnetic or tilt coupling). Offline findings only: the node
  has no absolute heading, so a calibration file refuses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

# The signal whose value a term's own time constant sets: the temperature through a first-order lag.
from art_gyro_calibration.signals import LAGGED_SIGNAL

FORMS = ('power', 'exp_decay', 'harmonic')


@dataclass(frozen=True)
class Term:
    """One extended term: ``signal``, its ``form`` and the fitted ``coefficients``."""

    signal: str
    form: str
    coefficients: tuple[float, ...]
    powers: tuple[int, ...] = ()
    time_constant_s: float = 0.0
    rate_powers: tuple[int, ...] = (0,)

    def __post_init__(self) -> None:
        where = f'extended term on {self.signal!r}'
        if self.form not in FORMS:
            raise ValueError(f'{where}: form {self.form!r} is not one of {", ".join(FORMS)}')
        if not all(math.isfinite(c) for c in self.coefficients):
            raise ValueError(f'{where}: coefficients must be finite, got {self.coefficients}')
        if (not self.rate_powers or any(q < 0 for q in self.rate_powers)
                or len(set(self.rate_powers)) != len(self.rate_powers)):
            raise ValueError(f'{where}: rate_powers must be distinct whole numbers >= 0, got {self.rate_powers}')
        if self.form != 'power' and self.rate_powers != (0,):
            raise ValueError(f'{where}: only the power form takes rate_powers, got {self.rate_powers}')
        width = self.width(self.form, self.powers, self.rate_powers)
        if len(self.coefficients) != width:
            raise ValueError(f'{where}: form {self.form!r} needs {width} coefficients, got {len(self.coefficients)}')
        if self.form == 'power' and (not self.powers or any(p < 1 for p in self.powers)):
            raise ValueError(f'{where}: powers must be whole numbers >= 1, got {self.powers}')
        needs_tau = self.form == 'exp_decay' or self.signal == LAGGED_SIGNAL
        if needs_tau and not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise ValueError(f'{where}: time_constant_s must be positive, got {self.time_constant_s}')

    @staticmethod
    def width(form: str, powers: tuple[int, ...] = (), rate_powers: tuple[int, ...] = (0,)) -> int:
        """Number of coefficients of a term of this form."""
        return {'power': len(powers) * len(rate_powers), 'exp_decay': 1, 'harmonic': 2}[form]

    def basis(self, x: NDArray[np.float64], rate: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Columns the coefficients multiply, shape (len(x), width); ``rate`` is needed with rate_powers."""
        return term_basis(self.form, x, self.powers, self.time_constant_s, self.rate_powers, rate)

    def evaluate(self, x: NDArray[np.float64], rate: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Correction in deg/s for every sample of signal ``x`` (and measured ``rate``)."""
        return cast(NDArray[np.float64], self.basis(np.asarray(x, dtype=float), rate) @ np.asarray(self.coefficients))

    def evaluate_one(self, x: float, rate: float = 0.0) -> float:
        """Correction in deg/s for one sample."""
        c = self.coefficients
        if self.form == 'power':
            q = self.rate_powers
            return sum(c[j * len(q) + k] * x ** p * rate ** qk
                       for j, p in enumerate(self.powers) for k, qk in enumerate(q))
        if self.form == 'exp_decay':
            return c[0] * math.exp(-x / self.time_constant_s)
        angle = math.radians(x)
        return c[0] * math.sin(angle) + c[1] * math.cos(angle)

    def describe(self) -> str:
        """One line for people."""
        c = ', '.join(f'{v:.6g}' for v in self.coefficients)
        if self.form == 'power':
            of = self.signal if self.signal != LAGGED_SIGNAL else f'{self.signal} ({self.time_constant_s:.6g} s lag)'
            rate = '' if self.rate_powers == (0,) else f' x rate powers {list(self.rate_powers)}'
            return f'power {list(self.powers)} of {of}{rate}: [{c}]'
        if self.form == 'exp_decay':
            return f'exp(-{self.signal}/{self.time_constant_s:.6g} s) with amplitude [{c}] deg/s'
        return f'once-per-turn harmonic of {self.signal} (sin, cos): [{c}] deg/s'


def term_basis(form: str, x: NDArray[np.float64], powers: tuple[int, ...] = (), time_constant_s: float = 0.0,
               rate_powers: tuple[int, ...] = (0,), rate: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Basis columns of a term of ``form`` on signal values ``x`` (and the measured ``rate``, with rate_powers)."""
    if form == 'power':
        if rate_powers == (0,):
            return np.stack([x ** p for p in powers], axis=1)
        if rate is None:
            raise ValueError(f'a term with rate_powers {list(rate_powers)} needs the rate')
        # Each power once (a power other than 0, 1, 2 is a pow() per element), each product as before.
        of_x, of_rate = [x ** p for p in powers], [rate ** q for q in rate_powers]
        return np.stack([xp * rq for xp in of_x for rq in of_rate], axis=1)
    if form == 'exp_decay':
        return np.exp(-x / time_constant_s)[:, None]
    if form == 'harmonic':
        angle = np.radians(x)
        return np.stack([np.sin(angle), np.cos(angle)], axis=1)
    raise ValueError(f'form {form!r} is not one of {", ".join(FORMS)}')
