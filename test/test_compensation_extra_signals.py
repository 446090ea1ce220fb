"""A term on a signal from outside the gyro (a supply voltage) as the node applies it: fed, held, flagged.

Before, the node refused any calibration with such a term: the tracker had no value for it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from art_gyro_calibration.calibration import (Calibration, CalibrationError, check_fed, extra_signals,
                                              load_packaged_calibration, node_parameters_needed)
from art_gyro_calibration.compensation import Compensator, FrameCorrector, apply_calibration
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import SignalFeed, SignalTracker
from art_gyro_calibration.static_bias import StaticBiasCollector
from art_gyro_calibration.terms import Term

COEFFICIENT = 0.05   # deg/s per volt: large, so that the term's part stands out of every rounding
SUPPLY = Term('supply_v', 'power', (COEFFICIENT,), (1,))


def _calibration() -> Calibration:
    return dataclasses.replace(load_packaged_calibration('NAVC3545'), terms=(SUPPLY,))


def _take(corrector: FrameCorrector, collector: StaticBiasCollector) -> None:
    """What the node's static bias service does with a collection complete: its bias in force, no more feeding."""
    corrector.compensator.bias, corrector.collector = collector.result(), None


class Clock:
    """A clock the test sets."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_feed_holds_the_latest_finite_value_and_ages() -> None:
    clock = Clock()
    feed = SignalFeed('supply_v', 2.0, clock)
    assert feed.latest is None and feed.problem() == 'no supply_v received yet'
    clock.now = 10.0
    assert feed.put(24.0) and feed.latest == (24.0, 10.0)
    clock.now = 12.0
    assert feed.problem() == ''
    clock.now = 12.5
    assert feed.problem() == 'the last supply_v (24) is 2.5 s old (max_age_s 2)'
    # A BatteryState's NaN is "unknown": not a value; the last one stays and keeps ageing.
    assert not feed.put(math.nan) and not feed.put(math.inf)
    assert feed.latest == (24.0, 10.0) and (feed.received, feed.not_finite) == (1, 2)
    with pytest.raises(ValueError, match='max_age_s must be a positive'):
        SignalFeed('supply_v', 0.0)


def test_the_tracker_gives_an_extra_signal_its_caller_set() -> None:
    tracker = SignalTracker(extras=('supply_v',))
    assert math.isnan(tracker.for_term(SUPPLY))
    tracker.extras['supply_v'] = 23.5
    assert tracker.for_term(SUPPLY) == tracker.value('supply_v') == 23.5
    with pytest.raises(KeyError, match=r'extra signals it is fed \(supply_v\)'):
        tracker.value('humidity')


def test_a_term_on_an_unfed_signal_is_refused_naming_the_node_parameter() -> None:
    cal = _calibration()
    assert extra_signals(cal) == ('supply_v',)
    assert list(node_parameters_needed(cal)) == ['extra_signals.supply_v.topic', 'extra_signals.supply_v.type']
    assert node_parameters_needed(load_packaged_calibration('NAVC3545')) == {}
    with pytest.raises(CalibrationError, match='set the node parameter extra_signals.supply_v.topic'):
        check_fed(cal, (), 'the file')
    check_fed(cal, ('supply_v',), 'the file')
    with pytest.raises(CalibrationError, match='extra_signals.supply_v.topic'):
        Compensator(cal)
    with pytest.raises(CalibrationError, match='extra_signals.supply_v.topic'):
        FrameCorrector(cal, feeds=(SignalFeed('humidity', 1.0),))


def test_the_frame_corrector_applies_the_fed_value_as_apply_applies_the_column() -> None:
    """Frames with the voltage fed before each: what the node publishes equals ``calibrate apply`` on the log."""
    cal = _calibration()
    n, rate_hz = 20, 10.0
    t = np.arange(300) / rate_hz
    raw_rate = (np.arange(t.size) % 3 - 1).astype(int)
    raw_temp = np.full(t.size, 500)   # 25 degC
    supply = 24.0 + np.where(t < 10.0, 0.0, 2.0) + 0.01 * np.sin(t)
    clock = Clock()
    feed = SignalFeed('supply_v', 1.0, clock)
    corrector = FrameCorrector(cal, feeds=(feed,))
    collector = StaticBiasCollector(n, max_mean_dps=10.0)   # the term adds 1.2 deg/s at 24 V: no constant against it
    corrector.collect(collector, lambda c: _take(corrector, c))
    published = []
    for ti, r, tc, v in zip(t, raw_rate, raw_temp, supply):
        clock.now = ti
        feed.put(v)
        assert corrector.step(r, tc, ti) == '' and corrector.compensator.current
        published.append(corrector.rate_dps)
    rate, temp = raw_rate * cal.rate_scale_factor, raw_temp * cal.temp_scale_factor
    applied = apply_calibration(GyroLog(t, rate, temp, extras={'supply_v': supply}), cal, n, max_mean_dps=10.0)
    np.testing.assert_allclose(published[n - 1:], applied.corrected_dps[n - 1:], rtol=0, atol=1e-12)
    # The 2 V step moved the published rate by the term's amount.
    step = np.mean(published[150:]) - np.mean(published[50:100])
    assert step == pytest.approx(-2.0 * COEFFICIENT, abs=2e-3)


def test_until_a_value_the_term_is_left_out_and_no_static_bias_is_taken_and_a_stale_one_is_flagged() -> None:
    cal = _calibration()
    clock = Clock()
    feed = SignalFeed('supply_v', 1.0, clock)
    corrector = FrameCorrector(cal, feeds=(feed,))
    collector = StaticBiasCollector(5)
    done: list[StaticBiasCollector] = []
    corrector.collect(collector, done.append)
    without = Compensator(dataclasses.replace(cal, terms=()))
    for i in range(10):   # no voltage yet: published, flagged, the polynomial alone, the collection waits
        t = i * 0.1
        assert corrector.step(1, 500, t) == '' and not corrector.compensator.current
        assert corrector.rate_dps == pytest.approx(without.correct(*((r := 1 * cal.rate_scale_factor),
                                                                     without.error(t, r, 25.0))), abs=1e-12)
    assert collector.count == 0 and not done
    clock.now = 1.0
    feed.put(24.0)
    for i in range(10, 15):
        assert corrector.step(1, 500, i * 0.1) == '' and corrector.compensator.current
    assert collector.count == 5 and done == [collector]
    # Older than max_age_s: still applied (the best value there is), flagged; a NaN does not refresh it.
    clock.now = 2.5
    feed.put(math.nan)
    assert corrector.step(1, 500, 2.5) == '' and not corrector.compensator.current
    expected = without.correct(1 * cal.rate_scale_factor, cal.polynomial.error_one(1 * cal.rate_scale_factor, 25.0)
                               + COEFFICIENT * 24.0)
    assert corrector.rate_dps == pytest.approx(expected, abs=1e-12)
    feed.put(24.0)
    assert corrector.step(1, 500, 2.6) == '' and corrector.compensator.current
