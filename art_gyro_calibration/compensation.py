"""The report's sample program: scale, compensate, and correct with the static bias.

:class:`Compensator` does it one sample at a time (the node); :func:`apply_calibration`
over a whole log (``calibrate apply``). Both give
``CompRate = GyroRate - StaticBiasDrift - comp + CalcStaticBiasDrift``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import Calibration, check_signals_available
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import DERIVED_SIGNALS, SignalTracker, compute_signals
from art_gyro_calibration.static_bias import (DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, NO_BIAS,
                                              StaticBias, static_bias)


class Compensator:
    """Per-sample compensation with the signals the extended terms need, kept causally."""

    __slots__ = ('calibration', 'bias', '_model', '_tracker', '_rate_scale', '_temp_scale')

    def __init__(self, calibration: Calibration) -> None:
        check_signals_available(calibration)
        self.calibration = calibration
        self.bias: StaticBias = NO_BIAS
        self._model = calibration.model
        self._tracker = SignalTracker(calibration.filters)
        self._rate_scale = calibration.rate_scale_factor
        self._temp_scale = calibration.temp_scale_factor

    def scale(self, raw_rate: int, raw_temp: int) -> tuple[float, float]:
        """Counts to (GyroRate deg/s, GyroTemp degC)."""
        return raw_rate * self._rate_scale, raw_temp * self._temp_scale

    def error(self, t: float, rate_dps: float, temp_c: float) -> float:
        """Advance the signals to this sample and return comp, its modelled error."""
        self._tracker.update(t, rate_dps, temp_c)
        return self._model.error_one(self._tracker)

    def correct(self, rate_dps: float, error_dps: float) -> float:
        """``CompRate`` with the current static bias."""
        return self.bias.correct(rate_dps, error_dps)


@dataclass(frozen=True)
class Applied:
    """A log after compensation."""

    comp_dps: NDArray[np.float64]
    corrected_dps: NDArray[np.float64]
    bias: StaticBias


def apply_calibration(log: GyroLog, calibration: Calibration, bias_samples: int,
                      max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                      max_std_dps: float = DEFAULT_MAX_STD_DPS) -> Applied:
    """Static bias over the first ``bias_samples`` rows, then compensation of every row."""
    if not 2 <= bias_samples <= len(log):
        raise ValueError(f'bias_samples must be between 2 and the {len(log)} rows of the log, got {bias_samples}')
    check_signals_available(calibration, DERIVED_SIGNALS + tuple(log.extras))
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, calibration.filters)
    comp = calibration.model.error(signals)
    bias = static_bias(log.rate_dps[:bias_samples], comp[:bias_samples], max_mean_dps, max_std_dps)
    return Applied(comp, bias.correct(log.rate_dps, comp), bias)
