"""Static bias drift calibration: the report's ``StaticBias()`` with a check that the gyro was still.

Before every mission the gyro sits still for ``n`` samples (100 = 10 s at 10 Hz).
``StaticBiasDrift`` is the mean scaled rate (it holds the bias of the day and the
Earth's rate) and ``CalcStaticBiasDrift`` the mean modelled error over the same
samples; the output is ``rate - StaticBiasDrift - error + CalcStaticBiasDrift``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

DEFAULT_SAMPLES = 100
# At rest an RD2100 reads its modelled error plus well under 0.02 deg/s of bias drift and
# Earth rate, with a per-sample noise of a few counts (0.00305 deg/s each) at 10 Hz. So the
# motion check is on the mean of rate - error: beyond these bounds the robot was moving,
# not the gyro drifting (the modelled error alone reaches 0.1 deg/s at some temperatures).
DEFAULT_MAX_MEAN_DPS = 0.1
DEFAULT_MAX_STD_DPS = 0.05

# One sample (the node) or a whole log (apply_calibration).
Rate = TypeVar('Rate', float, NDArray[np.float64])


class MotionError(ValueError):
    """The samples of a static bias collection show the gyro was turning."""


@dataclass(frozen=True)
class StaticBias:
    """Result of one static bias collection (deg/s)."""

    static_bias_drift_dps: float
    calc_static_bias_drift_dps: float
    samples: int
    rate_std_dps: float

    def correct(self, rate_dps: Rate, error_dps: Rate) -> Rate:
        """``CompRate`` of the report, for one sample or arrays of them."""
        return rate_dps - self.static_bias_drift_dps - error_dps + self.calc_static_bias_drift_dps

    def describe(self) -> str:
        """One line for people: the values found."""
        return (f'StaticBiasDrift={self.static_bias_drift_dps:.6f} deg/s, '
                f'CalcStaticBiasDrift={self.calc_static_bias_drift_dps:.6f} deg/s '
                f'over {self.samples} samples (rate std {self.rate_std_dps:.6f} deg/s)')


NO_BIAS = StaticBias(0.0, 0.0, 0, 0.0)


def static_bias(rate_dps: ArrayLike, error_dps: ArrayLike,
                max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                max_std_dps: float = DEFAULT_MAX_STD_DPS) -> StaticBias:
    """Static bias over still samples; raises :class:`MotionError` if they show motion."""
    rate = np.asarray(rate_dps, dtype=float)
    error = np.asarray(error_dps, dtype=float)
    if rate.size == 0 or rate.shape != error.shape:
        raise ValueError(f'static bias needs equally many rates and errors, got {rate.shape} and {error.shape}')
    return _checked(float(rate.mean()), float(error.mean()), float(rate.std()), rate.size,
                    max_mean_dps, max_std_dps)


class StaticBiasCollector:
    """Collects a static bias one sample at a time, as the node receives frames."""

    __slots__ = ('samples', 'max_mean_dps', 'max_std_dps', '_n', '_sum_rate', '_sum_sq', '_sum_error')

    def __init__(self, samples: int = DEFAULT_SAMPLES, max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                 max_std_dps: float = DEFAULT_MAX_STD_DPS) -> None:
        if samples < 2:
            raise ValueError(f'a static bias needs at least 2 samples, got {samples}')
        self.samples = samples
        self.max_mean_dps = max_mean_dps
        self.max_std_dps = max_std_dps
        self._n = 0
        self._sum_rate = 0.0
        self._sum_sq = 0.0
        self._sum_error = 0.0

    def add(self, rate_dps: float, error_dps: float) -> bool:
        """Add a sample; True once ``samples`` have been collected."""
        self._n += 1
        self._sum_rate += rate_dps
        self._sum_sq += rate_dps * rate_dps
        self._sum_error += error_dps
        return self._n >= self.samples

    @property
    def count(self) -> int:
        """Samples collected so far."""
        return self._n

    def result(self) -> StaticBias:
        """The static bias of the collected samples; raises :class:`MotionError` on motion."""
        n = self._n
        mean = self._sum_rate / n
        std = math.sqrt(max(self._sum_sq / n - mean * mean, 0.0))
        return _checked(mean, self._sum_error / n, std, n, self.max_mean_dps, self.max_std_dps)


def _checked(mean: float, mean_error: float, std: float, n: int,
             max_mean_dps: float, max_std_dps: float) -> StaticBias:
    if not (math.isfinite(mean) and math.isfinite(std) and math.isfinite(mean_error)):
        raise ValueError(f'static bias over {n} samples: not finite (mean rate {mean}, mean modelled error '
                         f'{mean_error}, rate spread {std} deg/s): a rate or modelled error is NaN or infinite')
    if abs(mean - mean_error) > max_mean_dps:
        raise MotionError(f'mean compensated rate {mean - mean_error:.4f} deg/s over {n} samples exceeds '
                          f'{max_mean_dps} deg/s: the gyro is turning')
    if std > max_std_dps:
        raise MotionError(f'rate spread {std:.4f} deg/s over {n} samples exceeds {max_std_dps} deg/s: '
                          'the gyro is moving')
    return StaticBias(mean, mean_error, n, std)
