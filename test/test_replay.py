"""Field replay: a calibration applied to another run as the node applies it, and the field errors."""

import numpy as np
import pytest

from art_gyro_calibration.analysis.metrics import field_errors, heading_error_deg, steady_segments


def _table(hours: float = 1.5, rate_hz: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A still start (the static bias), then steps of +-10 deg/s and rests of 5 minutes each."""
    t = np.arange(int(hours * 3600 * rate_hz)) / rate_hz
    ref = np.where(t < 60.0, 0.0, np.array([10.0, 0.0, -10.0, 0.0])[((t - 60.0) // 300.0).astype(int) % 4])
    return t, ref


def test_field_errors_of_a_constant_bias():
    t, ref = _table()
    start = 100
    error = np.full(t.size, 1e-3)  # 3.6 deg/h
    fe = field_errors(t, error, steady_segments(t, ref), start)
    assert fe.mean_bias_dps == pytest.approx(1e-3)
    assert fe.to_dict()['mean_bias_dph'] == pytest.approx(3.6)
    assert fe.to_dict()['systematic_rms_dph'] == pytest.approx(3.6)
    assert fe.heading_10min_deg == pytest.approx(0.6)
    assert fe.heading_1h_deg == pytest.approx(3.6)


def test_field_errors_of_a_linear_drift():
    t, ref = _table()
    start = 100
    drift = 1e-6  # deg/s per s: 3.6 deg/h more every 1000 s
    error = drift * (t - t[start])
    fe = field_errors(t, error, steady_segments(t, ref, settle_s=0.0), start)
    assert fe.heading_10min_deg == pytest.approx(drift * 600.0 ** 2 / 2)
    assert fe.heading_1h_deg == pytest.approx(drift * 3600.0 ** 2 / 2)
    # Equal steady rows on each side of the middle of the log: the mean is the drift at the middle.
    rows = steady_segments(t, ref, settle_s=0.0).rows()
    rows = rows[rows >= start]
    assert fe.mean_bias_dps == pytest.approx(drift * (t[rows].mean() - t[start]))


def test_a_heading_beyond_the_log_is_unknown():
    t, ref = _table(hours=0.5)
    fe = field_errors(t, np.full(t.size, 1e-3), steady_segments(t, ref), 100)
    assert fe.heading_10min_deg == pytest.approx(0.6)
    assert np.isnan(fe.heading_1h_deg)
    assert fe.to_dict()['heading_1h_deg'] is None
    assert heading_error_deg(t, np.ones(t.size), 0, [0.0, 60.0]) == pytest.approx([0.0, 60.0])
