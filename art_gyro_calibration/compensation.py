"""The report's sample program: scale, compensate, and correct with the static bias.

:class:`Compensator` does it one sample at a time (the node); :func:`apply_calibration`
over a whole log or chunk after chunk of one (``calibrate apply``). Both give
``CompRate = GyroRate - StaticBiasDrift - comp + CalcStaticBiasDrift``, and both drop the
samples :func:`plausible` refuses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import Calibration, check_signals_available
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import DERIVED_SIGNALS, SignalState, SignalTracker, compute_signals
from art_gyro_calibration.static_bias import (DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, NO_BIAS, Rate,
                                              StaticBias, static_bias)


# A frame claiming a temperature outside what any electronics survives is corrupt (its 8-bit
# checksum passed by luck) or the temperature field is not where this package assumes it: at
# +-1600 degC the polynomial alone would add 70-80 deg/s, so such a frame is dropped and counted.
PLAUSIBLE_TEMPERATURE_C = (-60.0, 130.0)


def plausible(temp_c: Rate) -> Rate:
    """Whether a sample (or each of an array of them) is kept: its temperature is physically possible."""
    low, high = PLAUSIBLE_TEMPERATURE_C
    return (low <= temp_c) & (temp_c <= high)


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
    """A log (or one chunk of it) after compensation: the kept samples' values, and what was dropped."""

    comp_dps: NDArray[np.float64]
    corrected_dps: NDArray[np.float64]
    bias: StaticBias
    kept: NDArray[np.bool_]     # per row of the log: plausible, so compensated (the node drops the rest)
    state: SignalState          # the signals after the last kept sample: where the next chunk continues


def apply_calibration(log: GyroLog, calibration: Calibration, bias_samples: int,
                      max_mean_dps: float = DEFAULT_MAX_MEAN_DPS,
                      max_std_dps: float = DEFAULT_MAX_STD_DPS, *, after: Applied | None = None) -> Applied:
    """Static bias over the first ``bias_samples`` kept rows, then compensation of every kept row.

    Rows :func:`plausible` refuses are dropped, as the node drops their frames. A log read in
    chunks passes each chunk with ``after`` = the previous chunk's result (the first chunk
    holding at least ``bias_samples`` kept rows): its signals continue, and its bias is kept.
    """
    kept = plausible(log.temp_c)
    if not kept.all():
        log = log.slice(kept)
    if after is None:
        if not 2 <= bias_samples <= len(log):
            raise ValueError(f'bias_samples must be between 2 and the {len(log)} plausible rows of the log, '
                             f'got {bias_samples}')
        check_signals_available(calibration, DERIVED_SIGNALS + tuple(log.extras))
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, calibration.filters,
                              None if after is None else after.state)
    comp = calibration.model.error(signals)
    bias = static_bias(log.rate_dps[:bias_samples], comp[:bias_samples], max_mean_dps, max_std_dps) \
        if after is None else after.bias
    return Applied(comp, bias.correct(log.rate_dps, comp), bias, kept, signals.end_state())
