"""``ros.bias_service``: a parked collection's mean is checked against the bias in force, not the service's way."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip('rclpy')

from art_gyro_calibration.parked import ParkedRefusal  # noqa: E402
from art_gyro_calibration.ros.bias_service import _ParkedCollection  # noqa: E402
from art_gyro_calibration.static_bias import StaticBias  # noqa: E402


def collected(reference: StaticBias, mean_dps: float, gyro_stillness: bool = False) -> _ParkedCollection:
    collection = _ParkedCollection(100, 0.1, 0.05, False, reference, gyro_stillness)
    for rate in mean_dps + np.random.default_rng(1).normal(0.0, 0.005, 100):
        collection.add(float(rate), 0.0)
    return collection


def test_a_large_bias_in_force_passes_and_a_turn_relative_to_it_does_not() -> None:
    """A gyro whose bias is 0.3 deg/s: the service's check on the mean itself would refuse it, this one does not."""
    reference = StaticBias(0.3, 0.0, 100, 0.005)
    bias = collected(reference, 0.32).result()
    assert math.isclose(bias.static_bias_drift_dps, 0.32, abs_tol=0.002)
    with pytest.raises(ParkedRefusal, match='with the bias in force') as refused:
        collected(reference, 0.45).result()
    assert refused.value.reason == 'mean'
    with pytest.raises(ParkedRefusal, match=r'exceeds 0\.00[0-9]+ deg/s'):   # the gyro's stillness: a few mdeg/s
        collected(reference, 0.32, gyro_stillness=True).result()
