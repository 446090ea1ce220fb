"""``analysis.pipeline``: ``fit_log`` on a small simulated log, what it finds, chooses, writes and reports."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.loop import DEFAULT_SERIAL, LoopOptions, close_loop
from art_gyro_calibration.analysis.pipeline import FitResult, FitSettings, _retraced, fit_log, scale_factors
from art_gyro_calibration.analysis.replay import _refit, startup_check
from art_gyro_calibration.analysis.runs import Run
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import (DEFAULT_RATE_SCALE_FACTOR, TEMP_SCALE_FACTOR, find_calibration_file,
                                              load_packaged_calibration)
from art_gyro_calibration.signals import POWER_ON_SIGNAL
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import DEG_PER_H_PER_DPS


def fit_simulated(directory: Path, serial: str = 'NAVC4058', validate: tuple[str, ...] = (),
                  warnings: list[str] | None = None) -> FitResult:
    """A 2 h rate-table log of NAVC4058 with a Shupe effect (2 Hz, seed 4), fitted 3 x 2 as ``calibrate fit`` does.

    ``serial``: the gyro the fit is told (``DEFAULT_SERIAL``: none); ``validate``: other runs to replay.
    """
    cal = load_packaged_calibration('NAVC4058')
    log = directory / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=2.0, rate_hz=2.0, seed=4, effects=('shupe',))))
    options = LoopOptions(serial_number=serial, rate_scale_factor=cal.rate_scale_factor,
                          temp_scale_factor=cal.temp_scale_factor)
    return fit_log(str(log), FitSettings(3, 2, options, validate=validate), str(directory / 'CAL.yaml'),
                   (warnings if warnings is not None else []).append)


@pytest.fixture(scope='module')
def fitted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, FitResult, list[str]]:
    directory = tmp_path_factory.mktemp('pipeline')
    warnings: list[str] = []
    return directory, fit_simulated(directory, warnings=warnings), warnings


def test_the_effect_found_is_the_one_written_and_the_report_says_so(fitted) -> None:
    directory, result, warnings = fitted
    assert [e.signal for e in result.loop.effects] == ['temperature_rate']
    assert [t.signal for t in result.calibration.terms] == ['temperature_rate']
    assert result.calibration.serial_number == 'NAVC4058'
    assert result.report['written'] == {'calibration': str(directory / 'CAL.yaml'), 'terms': ['temperature_rate']}
    assert [e['signal'] for e in result.report['effects']] == ['temperature_rate']
    assert result.report['findings_not_written'] == []
    assert result.comment == (f'Fitted by calibrate fit from {directory / "LOG.csv"}: the baseline\'s polynomial '
                              f'({find_calibration_file("NAVC4058")}; the refit was not better held out), effects '
                              'beyond it: temperature_rate.')
    # The model fits and a log from power-on judges its own warm-up: only the baseline's verdict is said.
    assert result.baseline is not None and warnings == [result.baseline.message]


def test_the_refit_is_judged_against_the_packaged_calibration_and_on_restarts_of_the_log(fitted) -> None:
    _, result, _ = fitted
    baseline = result.report['baseline']
    # The simulated gyro's polynomial is its packaged one: the refit, with its Shupe term, is judged against the
    # packaged polynomial with that term fitted on top (against the bare packaged file the term alone won it).
    assert baseline['source'] == str(find_calibration_file('NAVC4058')) and baseline['verdict'] == 'baseline'
    assert baseline['baseline_with_terms_field_dph'] + baseline['materiality_dph'] < baseline['baseline_field_dph']
    assert not baseline['refit_field_dph'] + baseline['materiality_dph'] < baseline['baseline_with_terms_field_dph']
    assert 'with the terms temperature_rate fitted on top of it' in baseline['message']
    assert np.array_equal(result.calibration.polynomial.coefficients,
                          load_packaged_calibration('NAVC4058').polynomial.coefficients)
    assert result.baseline is not None and result.baseline.source == baseline['source']
    assert result.startup is not None and result.report['startup_check']['runs']
    assert list(result.report['detection_limit_dph']) == [d.signal for d in result.loop.detection]
    assert result.validation is None and 'validation' not in result.report


def test_without_a_serial_nor_a_baseline_the_refit_is_written_unjudged(tmp_path: Path) -> None:
    result = fit_simulated(tmp_path, serial=DEFAULT_SERIAL)
    assert result.baseline is None
    assert result.report['baseline'] == {'source': None, 'verdict': 'none',
                                         'message': 'no baseline: neither --serial nor --baseline was given'}
    assert result.calibration.serial_number == DEFAULT_SERIAL
    assert [t.signal for t in result.calibration.terms] == ['temperature_rate']


def test_validation_runs_are_replayed_and_reported(tmp_path: Path) -> None:
    other = tmp_path / 'OTHER.csv'
    write_run(other, simulate_run(load_packaged_calibration('NAVC4058'),
                                  SimulationSettings(hours=1.0, rate_hz=2.0, seed=5, effects=('shupe',))))
    result = fit_simulated(tmp_path, validate=(str(other),))
    assert result.validation is not None and len(result.validation.runs) == 1
    [run] = result.report['validation']['runs']
    assert run['source'] == str(other) and {'art', 'extended'} <= set(run['calibrations'])
    assert result.report['written']['terms'] == [t.signal for t in result.calibration.terms]


def test_scale_factors_given_packaged_or_assumed() -> None:
    packaged = load_packaged_calibration('NAVC4058')
    given = scale_factors('NAVC4058', 0.001)
    assert (given.rate, given.temp, given.assumed) == (0.001, TEMP_SCALE_FACTOR, False)
    found = scale_factors('NAVC4058', None)
    assert (found.rate, found.temp, found.assumed) == (packaged.rate_scale_factor, packaged.temp_scale_factor, False)
    for serial in ('NAVC0000', None):   # a gyro never calibrated, or none named
        assumed = scale_factors(serial, None)
        assert (assumed.rate, assumed.temp, assumed.assumed) == (DEFAULT_RATE_SCALE_FACTOR, TEMP_SCALE_FACTOR, True)


def test_a_check_that_drops_a_term_asks_the_loop_again_without_it() -> None:
    # A Shupe effect (1.0 deg/s per degC/s on 0.3 degC/min ramps) beside a 0.012 deg/s warm-up, 4 degC of
    # self-heating over 25 min; a first pass as a loop once wrote it on the filter's rise at power-on: a 78 s coil
    # lag of eight coefficients and a 30 s warm-up beside the temperature rate, no 20 min warm-up. The start-up
    # check drops the lag; asked again without it, the loop finds the warm-up and the temperature rate, better on
    # the log's starts by far more than the noise: that pass is written.
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(hours=4.0, effects=('shupe_true_rate', 'warmup'), seed=7,
                                  effect_sizes={'shupe_true_rate': 1.0, 'warmup': 0.012}, ramp_c_per_min=0.3,
                                  self_heating_c=4.0, self_heating_tau_s=1500.0, wander_dps=1.0 / DEG_PER_H_PER_DPS,
                                  wander_tau_s=3600.0)
    log = simulate_run(cal, settings).log(cal)
    options = LoopOptions(serial_number='NAVC3545', rate_scale_factor=cal.rate_scale_factor, seed=7)
    loop = close_loop(log, 3, 4, options)
    rate = next(t for t in loop.extended.terms if t.signal == 'temperature_rate')
    lag = Term('temperature_lag', 'power', (0.0,) * 8, (1, 2), 78.0, (0, 1, 2, 3))
    stand_ins = _refit(loop, [rate, lag])
    warm_up = Term(POWER_ON_SIGNAL, 'exp_decay', (0.0036,), (), 30.0)
    first = replace(loop, extended=replace(stand_ins, terms=(*stand_ins.terms, warm_up)))
    checked, check, names = startup_check(first, log)
    assert [d.term.signal for d in check.dropped] == ['temperature_lag']
    retraced = _retraced(log, (Run('log', 0, len(log), True),), FitSettings(3, 4, options), options,
                         (first, checked, check, names))
    assert retraced is not None
    (_, written, _, _), section = retraced
    assert section['without'] == ['temperature_lag'] and section['kept'] == 'second', section['message']
    assert [p['without'] for p in section['tried']] == [['temperature_lag']]
    assert section['second_dph'] + 1.0 < section['first_dph']
    assert POWER_ON_SIGNAL in [t.signal for t in written.extended.terms]
    assert 'temperature_lag' not in [t.signal for t in written.extended.terms]
