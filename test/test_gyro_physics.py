"""The physics both simulators share: the Earth's rate, white noise per sample, counts."""

import numpy as np
import pytest

from art_gyro_calibration.fake_gyro import default_noise_dps
from art_gyro_calibration.gyro_physics import earth_rate_dps, to_counts, white_noise_dps


def test_earth_rate():
    assert earth_rate_dps(90.0) == pytest.approx(15.041 / 3600, rel=1e-4)
    assert earth_rate_dps(0.0) == pytest.approx(0.0, abs=1e-15)


def test_white_noise_has_a_fixed_density():
    """An angle random walk of 0.1 deg/sqrt(h) is 0.1 / 60 deg/s per sqrt(Hz); the fake's RD2100 is 0.005 at 10 Hz."""
    assert white_noise_dps(0.1, 1.0) == pytest.approx(0.1 / 60.0, rel=1e-15)
    assert white_noise_dps(0.1, 400.0) == pytest.approx(20.0 * white_noise_dps(0.1, 1.0), rel=1e-15)
    assert default_noise_dps(10.0) == pytest.approx(0.005, rel=1e-15)


def test_counts_round_to_nearest_with_halves_to_even():
    assert to_counts([0.5, 1.5, -0.5, 2.49, -2.51], 1.0).tolist() == [0.0, 2.0, -0.0, 2.0, -3.0]
    assert to_counts(np.array([0.0061]), 0.00305).tolist() == [2.0]
