"""Steady segments, the noise floor and the error metrics."""

import numpy as np
import pytest

from art_gyro_calibration.analysis.metrics import (correlation_time_s, error_metrics, heading_errors_360, noise_floor,
                                                   steady_segments)


def test_segments_skip_the_settling_time():
    t = np.arange(40) * 0.5
    ref = np.r_[np.zeros(10), np.full(20, 10.0), np.zeros(10)]
    seg = steady_segments(t, ref, settle_s=1.0)
    assert list(seg.starts) == [2, 12, 32]
    assert list(seg.stops) == [10, 30, 40]
    assert list(seg.rate) == [0.0, 10.0, 0.0]


def test_metrics_of_a_known_error():
    t = np.arange(300) * 1.0
    ref = np.r_[np.zeros(100), np.full(100, 36.0), np.full(100, -1.0)]
    error = np.r_[np.zeros(100), np.full(100, 0.01), np.full(100, -0.002)]
    seg = steady_segments(t, ref, settle_s=0.0)
    m = error_metrics(error, seg)
    assert m.rms_dps == pytest.approx(np.sqrt((100 * 0.01 ** 2 + 100 * 0.002 ** 2) / 300))
    assert m.systematic_rms_dps == pytest.approx(np.sqrt((0.01 ** 2 + 0.002 ** 2) / 3))
    rate, heading = heading_errors_360(error, seg)
    assert list(rate) == [36.0, -1.0]
    # 0.01 deg/s for the 10 s of a turn at 36 deg/s; 0.002 deg/s for 360 s at 1 deg/s.
    assert heading == pytest.approx([0.1, -0.72])
    assert m.heading_360_deg_max == pytest.approx(0.72)


def test_noise_floor_ignores_slow_effects():
    rng = np.random.default_rng(0)
    t = np.arange(20000) * 0.1
    ref = np.repeat([0.0, 5.0, -5.0, 0.0], 5000)
    residual = 0.004 * rng.standard_normal(t.size) + 0.05 * np.sin(t / 300.0)
    seg = steady_segments(t, ref)
    assert noise_floor(residual, seg) == pytest.approx(0.004, rel=0.05)


def test_correlation_time_of_white_noise_and_of_a_slow_wander():
    rng = np.random.default_rng(5)
    t = np.arange(0, 48 * 3600.0, 1.0)
    ref = np.zeros_like(t)
    ref[40000:40100] = 10.0  # a turn: a gap in the steady rows
    segments = steady_segments(t, ref)
    assert correlation_time_s(t, rng.normal(0, 0.1, len(t)), segments) <= 60.0
    # First-order Gauss-Markov with a 2 h correlation time, far above the white noise in 1-min means.
    tau = 7200.0
    phi = np.exp(-1.0 / tau)
    wander = np.zeros(len(t))
    kicks = rng.normal(0, 0.01 * np.sqrt(1 - phi ** 2), len(t))
    for i in range(1, len(t)):
        wander[i] = phi * wander[i - 1] + kicks[i]
    measured = correlation_time_s(t, wander + rng.normal(0, 0.1, len(t)), segments)
    assert 0.5 * tau < measured < 2.0 * tau


def test_correlation_time_of_bins_too_sparse_to_pair_up():
    """Eleven one-sample bins on a Golomb ruler: each lag pairs up once (under a tenth); one bin, no IndexError."""
    t = np.array([0, 1, 4, 13, 28, 33, 47, 54, 64, 70, 72]) * 60.0 + 30.0
    residual = np.array([5.0, 5.0, -1, 1, -1, 1, -1, 1, -1, 1, -1])
    assert correlation_time_s(t, residual, steady_segments(t, np.zeros(len(t)), settle_s=0.0)) == 60.0


def test_a_segment_ends_where_a_run_of_several_begins():
    """The table rests at the end of one run and the start of the next: two segments, each settled apart."""
    t = np.arange(20.0)
    seg = steady_segments(t, np.zeros(20), settle_s=2.0, breaks=[0, 12])
    assert seg.starts.tolist() == [2, 14] and seg.stops.tolist() == [12, 20]
    assert steady_segments(t, np.zeros(20), settle_s=2.0).starts.tolist() == [2]
