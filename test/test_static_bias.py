"""Static bias: the report's StaticBias() and the motion check, batch and per sample alike."""

import numpy as np
import pytest

from art_gyro_calibration.static_bias import MotionError, NoNoiseError, StaticBiasCollector, static_bias


def test_values_are_the_means_of_the_report() -> None:
    rng = np.random.default_rng(1)
    rate = 0.004 + rng.normal(0, 0.005, 100)
    error = 0.02 + rng.normal(0, 0.001, 100)
    bias = static_bias(rate, error)
    assert bias.static_bias_drift_dps == pytest.approx(rate.mean())
    assert bias.calc_static_bias_drift_dps == pytest.approx(error.mean())
    assert bias.samples == 100 and bias.rate_std_dps == pytest.approx(rate.std())
    assert bias.correct(1.0, 0.5) == pytest.approx(1.0 - rate.mean() - 0.5 + error.mean())


def test_collector_agrees_with_batch() -> None:
    rng = np.random.default_rng(2)
    rate, error = rng.normal(0.01, 0.004, 50), rng.normal(-0.03, 0.001, 50)
    collector = StaticBiasCollector(50)
    done = [collector.add(r, e) for r, e in zip(rate, error)]
    assert done == [False] * 49 + [True] and collector.count == 50
    a, b = collector.result(), static_bias(rate, error)
    assert a.static_bias_drift_dps == pytest.approx(b.static_bias_drift_dps, abs=1e-15)
    assert a.calc_static_bias_drift_dps == pytest.approx(b.calc_static_bias_drift_dps, abs=1e-15)
    assert a.rate_std_dps == pytest.approx(b.rate_std_dps, rel=1e-6)


def test_turning_is_refused() -> None:
    with pytest.raises(MotionError, match='mean compensated rate 5.0000 deg/s over 100 samples exceeds 0.1'):
        static_bias(np.full(100, 5.0), np.zeros(100))
    # Still, with a large modelled error (a gyro far from its calibration temperature): accepted.
    assert static_bias(np.full(100, 0.3), np.full(100, 0.29)).static_bias_drift_dps == pytest.approx(0.3)
    shaking = np.tile([0.2, -0.2], 50)
    with pytest.raises(MotionError, match='rate spread 0.2000 deg/s'):
        static_bias(shaking, np.zeros(100))
    collector = StaticBiasCollector(10)
    for _ in range(10):
        collector.add(1.0, 0.0)
    with pytest.raises(MotionError):
        collector.result()


def test_bad_input() -> None:
    with pytest.raises(ValueError, match='equally many'):
        static_bias([], [])
    with pytest.raises(ValueError, match='static bias over 3 samples: not finite .mean rate nan'):
        static_bias([float('nan')] * 3, [0.0] * 3)
    with pytest.raises(ValueError, match='at least 2'):
        StaticBiasCollector(1)


@pytest.mark.parametrize('value', [0.0, 0.00305, -0.0427])
def test_a_collection_without_any_spread_is_refused(value: float) -> None:
    """379 all-zero frames gave the node an "ok" bias of spread exactly 0: no gyro is that quiet."""
    collector = StaticBiasCollector(100)
    for _ in range(100):
        collector.add(value, 0.01, 0.0, 25.0)
    with pytest.raises(NoNoiseError, match=r'rate spread .* over 100 samples: no gyro is that quiet .*a stuck or '
                                           'all-zero stream'):
        collector.result()
    # A few equal samples can be a quantised gyro at rest: not refused.
    few = StaticBiasCollector(5)
    for _ in range(5):
        few.add(value, 0.01, 0.0, 25.0)
    assert few.result().rate_std_dps < 1e-9
