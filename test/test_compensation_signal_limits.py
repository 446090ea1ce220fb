"""A value of a signal from outside the gyro far beyond the range its term was fitted over is not applied as it is.

A supply voltage of 24000 (millivolts sent as volts) on a 0.05 deg/s per V term published -1199 deg/s with the
calibrated covariance; ``calibrate apply`` wrote NaN or inf rows with exit 0 from a NaN or inf ``supply_v``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.calibration import (SIGNAL_RANGE_MARGIN, Calibration, load_calibration,
                                              load_packaged_calibration, write_calibration)
from art_gyro_calibration.compensation import Compensator, FrameCorrector, apply_calibration, run_signals
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.signals import SignalFeed
from art_gyro_calibration.static_bias import StaticBiasCollector
from art_gyro_calibration.terms import Term

COEFFICIENT = 0.05   # deg/s per volt
FITTED_V = (23.0, 25.0)
LIMITS_V = (23.0 - 2.0 * SIGNAL_RANGE_MARGIN, 25.0 + 2.0 * SIGNAL_RANGE_MARGIN)


def _calibration(fitted: bool = True) -> Calibration:
    """NAVC3545 with a supply term ``c * v``, its constant at 24 V moved into the polynomial (as a fit holds it)."""
    cal = load_packaged_calibration('NAVC3545')
    coefficients = cal.polynomial.coefficients.copy()
    coefficients[-1, -1] -= COEFFICIENT * 24.0
    return dataclasses.replace(cal, polynomial=ArtPolynomial(coefficients),
                               terms=(Term('supply_v', 'power', (COEFFICIENT,), (1,)),),
                               signal_ranges={'supply_v': FITTED_V} if fitted else {})


def test_the_fitted_range_is_written_and_read_and_an_older_file_without_it_loads(tmp_path) -> None:
    write_calibration(tmp_path / 'cal.yaml', _calibration())
    assert 'fitted_range: [23.0, 25.0]' in (tmp_path / 'cal.yaml').read_text()
    loaded = load_calibration(tmp_path / 'cal.yaml')
    assert loaded.signal_ranges == {'supply_v': FITTED_V} and loaded.signal_limits('supply_v') == LIMITS_V
    write_calibration(tmp_path / 'old.yaml', _calibration(fitted=False))
    old = load_calibration(tmp_path / 'old.yaml')
    assert old.signal_ranges == {} and old.signal_limits('supply_v') == (-math.inf, math.inf)
    assert old.signal_problem('supply_v', 24000.0) == ''


@pytest.mark.parametrize('volts', [24000.0, 1e300, 0.0, -5.0])
def test_a_value_beyond_the_limits_is_applied_at_the_limit_flagged_and_takes_no_static_bias(volts: float) -> None:
    cal = _calibration()
    feed = SignalFeed('supply_v', 10.0, lambda: 0.0)
    corrector = FrameCorrector(cal, feeds=(feed,))
    collector = StaticBiasCollector(5, max_mean_dps=10.0)
    corrector.collect(collector, lambda c: None)
    feed.put(volts)
    assert corrector.step(1, 500, 0.0) == '' and not corrector.compensator.current
    limit = min(max(volts, LIMITS_V[0]), LIMITS_V[1])
    reference = Compensator(dataclasses.replace(cal, terms=()))
    rate = 1 * cal.rate_scale_factor
    expected = reference.correct(rate, cal.polynomial.error_one(rate, 25.0) + COEFFICIENT * limit)
    assert corrector.rate_dps == pytest.approx(expected, abs=1e-12) and abs(corrector.rate_dps) < 1.0
    assert corrector.compensator.beyond_limits == [1] and collector.count == 0
    assert cal.signal_problem('supply_v', volts) == (
        f'supply_v {volts:g} is beyond 22..26 (the range it was fitted over, 23..25, and half that each side): '
        f'applied as {limit:g}')
    feed.put(24.0)   # back within: current, collected
    assert corrector.step(1, 500, 0.1) == '' and corrector.compensator.current and collector.count == 1


def test_apply_holds_the_last_finite_value_clamps_beyond_the_limits_and_counts_both() -> None:
    cal = _calibration()
    n = 400
    t = np.arange(n) * 0.1
    rate = np.full(n, 0.01)
    temp = np.full(n, 25.0)
    supply = np.full(n, 24.0)
    supply[200], supply[250], supply[300] = np.nan, np.inf, 24000.0
    log = GyroLog(t, rate, temp, extras={'supply_v': supply})
    applied = apply_calibration(log, cal, 20, max_mean_dps=10.0)
    assert np.isfinite(applied.corrected_dps).all()
    # not finite: the last finite value (24) held; 24000: applied at 26.
    expected = supply.copy()
    expected[[200, 250]] = 24.0
    expected[300] = 26.0
    reference = apply_calibration(dataclasses.replace(log, extras={'supply_v': expected}), cal, 20, max_mean_dps=10.0)
    np.testing.assert_array_equal(applied.corrected_dps, reference.corrected_dps)
    assert applied.flagged == {'supply_v': (2, 1)}
    # In chunks: the held value carries over, the counts add up.
    first = apply_calibration(log.slice(slice(0, 250)), cal, 20, max_mean_dps=10.0)
    second = apply_calibration(log.slice(slice(250, n)), cal, 20, max_mean_dps=10.0, after=first)
    np.testing.assert_array_equal(second.corrected_dps, reference.corrected_dps[250:])
    assert second.flagged == {'supply_v': (2, 1)}


def test_calibrate_apply_says_how_many_rows_were_not_corrected_as_logged(tmp_path, capsys) -> None:
    cal = _calibration()
    write_calibration(tmp_path / 'cal.yaml', cal)
    rows = ['t,rate_dps,temp_c,supply_v'] + [f'{i / 10},0.01,25,{24 if i not in (150, 160) else "nan"}'
                                             for i in range(300)]
    rows[201] = '20.0,0.01,25,24000'
    (tmp_path / 'log.csv').write_text('\n'.join(rows) + '\n')
    assert main(['apply', str(tmp_path / 'log.csv'), '--calibration', str(tmp_path / 'cal.yaml'),
                 '--out', str(tmp_path / 'out.csv'), '--bias-samples', '20']) == 0
    err = capsys.readouterr().err
    assert ('supply_v: 2 rows not finite (the last finite value held) and 1 beyond 22..26 (applied at the limit): '
            'the node flags such rates uncorrected') in err, err
    out = np.loadtxt(tmp_path / 'out.csv', delimiter=',', skiprows=1)
    assert np.isfinite(out).all() and np.abs(out[:, 4]).max() < 1.0


def test_signals_made_once_for_a_run_give_what_each_calibration_computes_alone() -> None:
    # The baseline comparison replays many calibrations on one run with its signals made once (run_signals).
    # Where a calibration's limits move a supply voltage beyond them, its own signals are computed, not the shared.
    rng = np.random.default_rng(3)
    n = 600
    volts = np.where(np.arange(n) < 300, 24.0, 30.0)   # beyond the fitted 23..25 V half the run
    log = GyroLog(np.arange(n) * 0.1, rng.normal(0.0, 0.01, n), np.linspace(20.0, 26.0, n),
                  extras={'supply_v': volts})
    no_limits, limited = _calibration(fitted=False), _calibration()
    # A temperature-rate term on other filters: the shared signals (made with the default filters) would be wrong.
    faster = dataclasses.replace(no_limits.filters, temperature_rate_tau_s=30.0)
    other_filters = dataclasses.replace(no_limits, filters=faster,
                                        terms=no_limits.terms + (Term('temperature_rate', 'power', (1.0,), (1,)),))
    shared = run_signals(log, no_limits.filters)
    for cal in (no_limits, limited, other_filters):
        alone = apply_calibration(log, cal, 100, max_mean_dps=10.0)
        given = apply_calibration(log, cal, 100, max_mean_dps=10.0, signals=shared)
        np.testing.assert_array_equal(given.corrected_dps, alone.corrected_dps)
    assert apply_calibration(log, no_limits, 100, max_mean_dps=10.0, signals=shared).signals is shared
    assert apply_calibration(log, limited, 100, max_mean_dps=10.0, signals=shared).signals is not shared
    assert apply_calibration(log, other_filters, 100, max_mean_dps=10.0, signals=shared).signals is not shared
