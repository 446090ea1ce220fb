"""A second real record as a cross-check of the noise model: a phone lying still for six hours.

``samsung_galaxy_s5.nc`` (same wheel): 10 Hz, two gyro streams (the phone's output and
its measured stream, nearly the same readings), no temperature. Its Allan deviation is
set beside the CATS gyro's, and the package's loop runs on its first two thirds with the
last third held out (:func:`measured_folds.run_fold` with no temperature power).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.allan import AllanDeviation, allan_deviation
from art_gyro_calibration.log import GyroLog

from importers import StaticRecord, segment_labels, static_log
from measured_folds import Fold, run_fold, sample_rate_hz
from measured_record import AXES, RUN_GAP_S

# The phone logs no temperature: a constant stands in, so the fit has one temperature power (a constant).
STAND_IN_C = 20.0
STREAMS = ('gyro', 'gyro_measured')
TRAIN_FRACTION = 2.0 / 3.0
# The other stream repeats the rate itself: never a candidate.
TWINS = tuple(f'gyro_measured_{a}' for a in AXES)


@dataclass(frozen=True)
class PhoneAxis:
    """One axis of the phone: the Allan deviation of both streams and the loop on the output stream."""

    axis: str
    log: GyroLog
    allan: dict[str, AllanDeviation]
    fold: Fold


def stream_allan(record: StaticRecord, still: NDArray[np.bool_], channel: str) -> AllanDeviation:
    """Allan deviation of one rate channel over the still samples."""
    t = record.t[still]
    hz = 1.0 / float(np.median(np.diff(t)))
    return allan_deviation(record.channels[channel][still], hz, segment_labels(t, RUN_GAP_S))


def run_phone_axis(record: StaticRecord, still: NDArray[np.bool_], axis: str, max_effects: int) -> PhoneAxis:
    """Allan deviations of both streams of ``axis`` and the loop on the output stream's first two thirds."""
    log = static_log(record, f'gyro_{axis}', still, temperature_c=STAND_IN_C)
    days = (log.t >= log.t[0] + TRAIN_FRACTION * (log.t[-1] - log.t[0])).astype(int)
    fold = run_fold(log, days, 1, 'last third', axis, max_effects, rows=1, exclude=TWINS,
                    serial_number='phone_gyro')
    allan = {stream: stream_allan(record, still, f'{stream}_{axis}') for stream in STREAMS}
    return PhoneAxis(axis, log, allan, fold)


def phone_summary(phone: PhoneAxis) -> tuple[float, float, float, float]:
    """White noise at 1 s, floor, tau of the floor (s) of the output stream; its sample rate (Hz)."""
    a = phone.allan['gyro']
    k = int(np.argmin(a.adev))
    return a.at(1.0), float(a.adev[k]), float(a.tau_s[k]), sample_rate_hz(phone.log)
