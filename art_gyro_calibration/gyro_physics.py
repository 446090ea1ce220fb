"""What a calibrated gyro reads: the physics the runtime fake gyro and the rate-table simulator share.

Numpy only (no ROS, no scipy): the fake gyro (:mod:`art_gyro_calibration.fake_gyro`) runs on a
robot's runtime install. Each simulator keeps its own defaults (noise level, turn-on bias,
temperature profile); the Earth's rate, the site, the inverse of the ART model, the white
noise per sample and the counts are the same in both.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.units import DEG_PER_H_PER_DPS

EARTH_RATE_DPS = 15.041 / DEG_PER_H_PER_DPS   # sidereal rate, deg/s
ANN_ARBOR_LATITUDE_DEG = 42.3      # where ART calibrated the gyros


def earth_rate_dps(latitude_deg: float) -> float:
    """What a level yaw gyro at rest reads of the Earth's rotation at ``latitude_deg``."""
    return EARTH_RATE_DPS * math.sin(math.radians(latitude_deg))


def white_noise_dps(arw_deg_rthr: float, rate_hz: float) -> float:
    """Per-sample standard deviation of white noise of angle random walk ``arw_deg_rthr`` (deg/sqrt(h)).

    A fixed noise density: the per-sample noise grows as sqrt(rate).
    """
    return arw_deg_rthr / 60.0 * math.sqrt(rate_hz)


def measured_from_true(polynomial: ArtPolynomial, true_rate_dps: ArrayLike, temp_c: ArrayLike,
                       tolerance_dps: float = 1e-12, max_iterations: int = 100) -> NDArray[np.float64]:
    """Reading ``m`` of a gyro whose error is ``comp(m, T)``: solves ``m - comp(m, T) = true``.

    The model is written in the measured rate, so a simulator must invert it; the
    fixed point converges because the scale-factor error is far below one.
    """
    true_rate = np.asarray(true_rate_dps, dtype=float)
    measured = true_rate.copy()
    for _ in range(max_iterations):
        updated = true_rate + polynomial.error(measured, temp_c)
        step = np.max(np.abs(updated - measured), initial=0.0)
        measured = updated
        if step <= tolerance_dps:
            return measured
    raise ValueError(f'the model does not invert: its rate derivative is not small over these inputs '
                     f'(last step {step:.3g} deg/s)')


def to_counts(value: ArrayLike, scale_factor: float) -> NDArray[np.float64]:
    """``value`` in whole counts of ``scale_factor`` (nearest, halves to even), as the gyro's ADC gives it."""
    return np.rint(np.asarray(value, dtype=float) / scale_factor)
