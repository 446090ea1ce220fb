"""A corrected rate beyond the unit's range is never published as valid, whatever produced it.

A term within its signal's limits (60 deg/s per V at 1.9 V, fitted over -1..1 V) or a static bias can give a corrected
rate no RD2100 can measure (beyond +-99.94 deg/s); it went out as a corrected rate, current.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from art_gyro_calibration.calibration import Calibration, load_packaged_calibration
from art_gyro_calibration.compensation import Compensator, FrameCorrector, apply_calibration
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import SignalFeed
from art_gyro_calibration.static_bias import StaticBias
from art_gyro_calibration.terms import Term

COEFFICIENT = 60.0   # deg/s per volt: 1.9 V, within the limits -2..2, adds 114 deg/s to the modelled error
VOLTS = 1.9


def supply_calibration() -> Calibration:
    """NAVC3545 with a term ``c * v`` on the supply's departure from its nominal, fitted over -1..1 V."""
    return dataclasses.replace(load_packaged_calibration('NAVC3545'),
                               terms=(Term('supply_v', 'power', (COEFFICIENT,), (1,)),),
                               signal_ranges={'supply_v': (-1.0, 1.0)})


def test_a_term_within_its_limits_that_corrects_beyond_the_range_is_published_uncorrected_and_flagged() -> None:
    cal = supply_calibration()
    feed = SignalFeed('supply_v', 10.0, lambda: 0.0)
    corrector = FrameCorrector(cal, feeds=(feed,))
    compensator = corrector.compensator
    feed.put(VOLTS)
    assert cal.signal_problem('supply_v', VOLTS) == ''   # within the limits: not the envelope's flag
    assert corrector.step(10, 500, 0.0) == ''
    rate = 10 * cal.rate_scale_factor
    assert corrector.rate_dps == rate and not compensator.current
    assert compensator.beyond_unit_range == 1 and compensator.beyond_limits == [0]
    assert compensator.last_beyond_dps == pytest.approx(rate - cal.polynomial.error_one(rate, 25.0)
                                                        - COEFFICIENT * VOLTS, abs=1e-9)
    assert compensator.last_beyond_dps < -cal.rate_range_dps
    feed.put(0.0)
    assert corrector.step(10, 500, 0.1) == '' and compensator.current and abs(corrector.rate_dps) < 1.0
    assert compensator.beyond_unit_range == 1


def test_a_static_bias_that_corrects_beyond_the_range_is_flagged_without_feeds_and_cleared_after() -> None:
    cal = load_packaged_calibration('NAVC3545')
    corrector = FrameCorrector(cal)
    compensator = corrector.compensator
    corrector.end_collection(StaticBias(-100.0, 0.0, 100, 0.01))
    assert corrector.step(0, 500, 0.0) == '' and corrector.rate_dps == 0.0 and not compensator.current
    assert compensator.beyond_unit_range == 1 and compensator.last_beyond_dps > cal.rate_range_dps
    corrector.end_collection(StaticBias(0.01, 0.0, 100, 0.01))
    assert corrector.step(0, 500, 0.1) == '' and compensator.current
    assert corrector.rate_dps == pytest.approx(-0.01 - cal.polynomial.error_one(0.0, 25.0), abs=1e-12)


def test_apply_writes_such_rows_uncorrected_and_counts_them_in_chunks_too() -> None:
    cal = supply_calibration()
    n = 300
    rate = np.full(n, 0.01)
    supply = np.zeros(n)
    supply[[150, 160, 270]] = VOLTS
    log = GyroLog(np.arange(n) * 0.1, rate, np.full(n, 25.0), extras={'supply_v': supply})
    applied = apply_calibration(log, cal, 20, max_mean_dps=10.0)
    assert applied.beyond_unit_range == 3
    np.testing.assert_array_equal(applied.corrected_dps[[150, 160, 270]], 0.01)
    assert np.abs(applied.corrected_dps).max() < 1.0
    first = apply_calibration(log.slice(slice(0, 200)), cal, 20, max_mean_dps=10.0)
    second = apply_calibration(log.slice(slice(200, n)), cal, 20, max_mean_dps=10.0, after=first)
    assert (first.beyond_unit_range, second.beyond_unit_range) == (2, 3)
    np.testing.assert_array_equal(second.corrected_dps, applied.corrected_dps[200:])


def test_apply_leaves_a_row_the_node_would_drop_as_beyond_the_range() -> None:
    """A rate beyond an RD2100's 99.94 deg/s (a simulated table's) is no frame the node corrects: not counted."""
    cal = load_packaged_calibration('NAVC3545')
    n = 100
    rate = np.where(np.arange(n) < 50, 0.0, 110.0)
    applied = apply_calibration(GyroLog(np.arange(n) * 0.1, rate, np.full(n, 25.0)), cal, 20)
    assert applied.beyond_unit_range == 0 and np.abs(applied.corrected_dps[50:]).min() > cal.rate_range_dps
    compensator = Compensator(cal)   # the same, a sample at a time (test_cli's node path against apply)
    compensator.bias = applied.bias
    error = float(applied.comp_dps[-1])
    assert compensator.correct(110.0, error) == applied.corrected_dps[-1] and compensator.beyond_unit_range == 0
