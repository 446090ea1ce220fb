"""The temperature's rate of change, estimated causally by a local quadratic fit (Brown's triple smoothing).

A Shupe term corrects the rate by a coefficient times dT/dt, so the estimate must follow a change of
slope (a chamber ramp starting or stopping, a self-heating curve) without a long lag, from 0.05 degC
counts at 10 Hz or a KVH unit's floats at up to 1 kHz. The first-order derivative ``(x - s1) / tau``
(``s1`` the temperature through a first-order lag of ``tau``) passes every count's step straight
through at ``1 / tau``: it needs a long ``tau`` (120 s) to smooth the counts, and lags by ``tau``.

Discounted least squares fits a polynomial in time to the past with weights ``exp(-age / tau)``; for a
quadratic its slope now is Brown's triple exponential smoothing (R. G. Brown, *Smoothing, Forecasting and
Prediction of Discrete Time Series*, 1963, ch. 7): with ``s1`` the temperature through a first-order lag
of ``tau``, ``s2`` ``s1`` through the same lag and ``s3`` ``s2`` through it,

    rate = (3 s1 - 5 s2 + 2 s3) / tau,

in Laplace terms ``(3 L - 5 L^2 + 2 L^3) / tau`` with ``L = 1 / (1 + tau s)``, which is ``s + O(s^3)``:
no lag on a ramp nor on a parabola (a self-heating's or a lagged chamber's bend), and a response that
falls off at high frequency where the first-order derivative's stays ``1 / tau``. A count's step moves
it smoothly instead of by a jump, so a far shorter ``tau`` gives less noise and follows a change of
slope within a few ``tau``.

Sampled, each step of ``dt`` has the gain ``a = 1 - exp(-dt / tau)`` of all three lags,
``s_k,i = s_k,i-1 + a_i (s_k-1,i - s_k,i-1)`` (``s_0`` the temperature), and

    rate_i = (a_i / dt_i) (3 (s1_i - s2_i-1) - 2 (s2_i - s3_i-1))
             (dt_i <= 0: the limit, the same with 1 / tau for a_i / dt_i)

which equals ``(3 s1_i - 5 s2_i + 2 s3_i) a_i / ((1 - a_i) dt_i)``: on a ramp sampled at a steady
``dt`` it is the ramp's slope exactly (each lag trails the one before by ``dt (1 - a) / a`` times the
slope). Every level lies within the temperature's span, and ``a / dt <= 1 / tau``: the estimate is
bounded by 5 times that span over ``tau``. At the first sample every level is the sample: the rate is 0.

:class:`LocalQuadraticRate` runs it one sample at a time (the node); :func:`local_quadratic_rate` gives it
from the three levels over a log (:class:`art_gyro_calibration.signals.Signals` smooths them in closed form).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

# The filters a calibration file may name (``filters.temperature_rate_form``).
FIRST_ORDER = 'first_order'           # (x - s1) / tau: every file written before the local quadratic fit
LOCAL_QUADRATIC = 'local_quadratic'   # (3 s1 - 5 s2 + 2 s3) / tau, Brown's triple smoothing
FORMS = (FIRST_ORDER, LOCAL_QUADRATIC)
# How far the estimate may reach, in the temperature's span over ``tau``, per form (see the module's docstring).
SPAN_FACTOR = {FIRST_ORDER: 1.0, LOCAL_QUADRATIC: 5.0}


def local_quadratic_rate(levels: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
                         start: tuple[float, float], dt: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """The rate at each sample from the levels ``s1, s2, s3`` there, degC/s.

    ``start``: ``s2, s3`` before the first sample (at a log's first sample, the sample itself);
    ``dt``: each sample's step from the one before (any value at a log's first sample).
    The batch twin of :meth:`LocalQuadraticRate.update`.
    """
    s1, s2, s3 = levels
    step = np.maximum(dt, 0.0)
    gain = -np.expm1(-step / tau_s)
    moved = step > 0.0
    np.divide(gain, step, out=gain, where=moved)
    gain[~moved] = 1.0 / tau_s
    out = 3.0 * (s1 - np.concatenate(([start[0]], s2[:-1])))
    out -= 2.0 * (s2 - np.concatenate(([start[1]], s3[:-1])))
    out *= gain
    return out


class LocalQuadraticRate:
    """Per-sample twin of :func:`local_quadratic_rate`: a few float operations a sample, no allocation."""

    __slots__ = ('tau_s', 'level', 'level2', 'level3', 'value')

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.level: float | None = None   # s1; None before the first sample
        self.level2 = 0.0                 # s2
        self.level3 = 0.0                 # s3
        self.value = 0.0

    def update(self, dt: float, x: float) -> None:
        """Advance by ``dt`` (s) to the temperature ``x``."""
        level = self.level
        if level is None:
            self.level = self.level2 = self.level3 = x
            return
        if dt > 0.0:
            gain = -math.expm1(-dt / self.tau_s)
            level += gain * (x - level)
            change2 = level - self.level2
            self.level2 += gain * change2
            change3 = self.level2 - self.level3
            self.level3 += gain * change3
            self.value = gain / dt * (3.0 * change2 - 2.0 * change3)
            self.level = level
        else:
            self.value = (3.0 * (level - self.level2) - 2.0 * (self.level2 - self.level3)) / self.tau_s
