"""``calibrate fit`` is never worse than the calibration the gyro has.

Each calibration written is replayed on a second run of the same gyro exactly as the node
applies it (static bias over the first 100 rows, a cold start, bias included) and compared
with the gyro's packaged calibration (the baseline, here the simulator's true polynomial).
"""

import dataclasses
import json

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration, write_calibration
from art_gyro_calibration.compensation import RunStart
from art_gyro_calibration.analysis.baseline import BASELINE, beyond_log, compare_with_baseline, continued, paired_check
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.replay import replay_field
from art_gyro_calibration.analysis.simulate import (EFFECTS, SimulationSettings, same_gyro, simulate_run, warm_restart,
                                                    write_run)
from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.signals import POWER_ON_SIGNAL
from art_gyro_calibration.units import DEG_PER_H_PER_DPS

SERIAL = 'NAVC3545'   # a 3 x 4 gyro


def _fit(tmp_path, settings, *extra, chamber_c=None):
    """Simulate ``settings``, fit it with calibrate fit, and give the written file, the report and a second run.

    ``chamber_c``: the fitted log's chamber range (default the packaged file's 10..50 degC); the
    second run's is always the packaged one.
    """
    cal = load_packaged_calibration(SERIAL)
    log = tmp_path / 'LOG.csv'
    chamber = cal if chamber_c is None else dataclasses.replace(cal, temperature_warn_range_c=chamber_c)
    write_run(log, simulate_run(chamber, settings))
    assert main(['fit', str(log), '--serial', SERIAL, '--out', str(tmp_path / 'CAL.yaml'),
                 '--report', str(tmp_path / 'REPORT.json'), *extra]) == 0
    second = simulate_run(cal, same_gyro(settings, settings.seed + 100)).log(cal)
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    return load_calibration(tmp_path / 'CAL.yaml', expected_serial=SERIAL), report, second


def _stale_baseline(tmp_path, calibrated_c=None):
    """The gyro's file gone stale: its rate scale factor 300 ppm off (0.03 deg/s at 100 deg/s).

    ``calibrated_c``: its calibrated range (default: none, the packaged file's assumed 10..50 degC).
    """
    packaged = load_packaged_calibration(SERIAL)
    if calibrated_c is not None:
        packaged = dataclasses.replace(packaged, temperature_range_c=calibrated_c, temperature_warn_range_c=None)
    coefficients = packaged.polynomial.coefficients.copy()
    coefficients[-1, -2] += 3e-4
    stale = tmp_path / 'stale.yaml'
    write_calibration(stale, dataclasses.replace(packaged, polynomial=ArtPolynomial(coefficients)))
    return stale


def _field_dph(log, calibration):
    """Systematic rms with the bias on a cold second run, as the node applies the calibration (deg/h)."""
    return replay_field(log, calibration, 100, start=RunStart(powered_on_at_start=True)).systematic_rms_dps \
        * DEG_PER_H_PER_DPS


def test_a_refit_worse_than_the_baseline_is_not_written(tmp_path, capsys):
    # The case: 2 h, no effect, a slow bias wander (Gauss-Markov 3.6 deg/h, 1 h). The refit
    # polynomial follows the wander; on a second run it was 6.85 deg/h against the packaged file's 3.22.
    settings = SimulationSettings(hours=2.0, seed=3, wander_dps=3.6 / DEG_PER_H_PER_DPS, wander_tau_s=3600.0)
    written, report, second = _fit(tmp_path, settings, '--rows', '3', '--columns', '4')
    baseline = load_packaged_calibration(SERIAL)
    assert _field_dph(second, written) <= _field_dph(second, baseline) + 0.5
    section = report['baseline']
    assert section['verdict'] == 'baseline' and section['source'].endswith(f'{SERIAL}.yaml')
    assert section['refit_field_dph'] > section['baseline_field_dph']
    np.testing.assert_array_equal(written.polynomial.coefficients, baseline.polynomial.coefficients)
    err = capsys.readouterr()
    assert 'keeps the baseline polynomial' in err.err
    assert 'Verdict: the baseline polynomial is kept.' in err.out   # REPORT.md, printed


def test_a_polynomial_too_small_for_the_gyro_shows_up_against_the_baseline(tmp_path, capsys):
    # 3 x 2 on a gyro that needs 3 x 4: the refit was 576 deg/h on a second run, the baseline 2.8.
    settings = SimulationSettings(hours=2.0, seed=0)
    written, report, second = _fit(tmp_path, settings, '--rows', '3', '--columns', '2')
    assert _field_dph(second, written) <= _field_dph(second, load_packaged_calibration(SERIAL)) + 1.0
    assert report['baseline']['verdict'] == 'baseline'
    assert report['baseline']['refit_field_dph'] > 100.0 > report['baseline']['baseline_field_dph']
    assert (written.polynomial.rows, written.polynomial.columns) == (3, 4)
    assert 'keeps the baseline polynomial' in capsys.readouterr().err


def test_a_refit_better_than_a_stale_baseline_is_written(tmp_path):
    stale = _stale_baseline(tmp_path)
    written, report, second = _fit(tmp_path, SimulationSettings(hours=2.0, seed=1), '--rows', '3', '--columns', '4',
                                   '--baseline', str(stale))
    assert report['baseline']['verdict'] == 'refit' and report['baseline']['source'] == str(stale)
    assert report['baseline']['refit_field_dph'] + report['materiality_dph'] < report['baseline']['baseline_field_dph']
    assert _field_dph(second, written) < _field_dph(second, load_calibration(stale)) - 10.0
    assert report['baseline']['beyond_log'] is None   # the log covers the baseline's 10..50 degC


def test_beyond_the_log_the_refit_is_continued_by_the_baseline(tmp_path, capsys):
    # The same stale file, fitted from a log over 20..32 degC alone: held out on it the refit is far
    # better (4.4 against 33.1 deg/h). Held at 20 and 32 degC it was 115.8 deg/h on a second run over
    # 10..50 degC, where the stale file is 33.2, and the verdict kept the stale file. Continued beyond the
    # log by the stale file's temperature dependence, the scale factor the log measured holds at every
    # temperature, as it does on the gyro.
    stale = _stale_baseline(tmp_path, calibrated_c=(10.0, 50.0))
    written, report, second = _fit(tmp_path, SimulationSettings(hours=2.0, seed=1), '--rows', '3', '--columns', '4',
                                   '--baseline', str(stale), '--operating-range', '10', '50', chamber_c=(20.0, 32.0))
    section = report['baseline']
    assert section['verdict'] == 'refit', section['message']
    assert written.temperature_range_c == (20.0, 32.0)
    np.testing.assert_array_equal(written.continuation.polynomial.coefficients,
                                  load_calibration(stale).polynomial.coefficients)
    assert written.continuation.temperature_range_c == (10.0, 50.0)
    assert report['written']['temperature_range_c'] == [20.0, 32.0]
    assert 'continued by the temperature dependence of the baseline' in report['written']['beyond_range']
    assert 3.0 * _field_dph(second, written) < _field_dph(second, load_calibration(stale))
    # Beyond the log it differs from the stale file by the scale factor the log measured at its edge (0.03 deg/s
    # at 100 deg/s): reported, not judged.
    beyond = section['beyond_log']
    assert beyond['log_range_c'] == [20.0, 32.0] and beyond['judged_c'] == [[10.0, 20.0], [32.0, 50.0]]
    assert beyond['differ_dph'] == pytest.approx(108.0, rel=0.2) and abs(beyond['at_rate_dps']) == 100.0
    assert 'the written file differs from the baseline by up to' in capsys.readouterr().out


def test_beyond_the_log_the_written_file_differs_from_the_baseline_by_its_edge_correction():
    packaged = dataclasses.replace(load_packaged_calibration(SERIAL), temperature_range_c=(10.0, 50.0),
                                   temperature_warn_range_c=None)   # calibrated over 10..50 degC
    rates = np.array([-100.0, 10.0, 100.0])
    temp = np.arange(10.0, 50.5, 0.5)
    r, t = np.meshgrid(np.append(rates, 0.0), temp)
    # The refit equal to the baseline inside the log; held at its edge, it differs beyond by all the baseline moves.
    held = dataclasses.replace(packaged, temperature_range_c=(20.0, 32.0))
    moves = np.abs(packaged.polynomial.error(r, t) - packaged.polynomial.error(r, np.clip(t, 20.0, 32.0)))
    beyond = beyond_log(held, packaged, rates, (10.0, 50.0))
    assert beyond.differ_dph == pytest.approx(moves.max() * DEG_PER_H_PER_DPS)
    assert (beyond.log_range_c, beyond.baseline_range_c) == ((20.0, 32.0), (10.0, 50.0))
    # Continued by the baseline it follows it: nothing between them.
    assert beyond_log(continued(held, packaged, 'baseline.yaml'), packaged, rates, (10.0, 50.0)).differ_dph == 0.0
    # A refit off the baseline by a scale factor: continued, that correction beyond the log, and no more.
    coefficients = packaged.polynomial.coefficients.copy()
    coefficients[-1, -2] += 3e-4
    off = continued(dataclasses.replace(held, polynomial=ArtPolynomial(coefficients)), packaged, '')
    assert beyond_log(off, packaged, rates, (10.0, 50.0)).differ_dph == pytest.approx(3e-2 * DEG_PER_H_PER_DPS)
    # A log over the baseline's whole range, or a baseline calibrated nowhere, has no beyond.
    assert beyond_log(dataclasses.replace(packaged, temperature_range_c=(10.0, 50.0)), packaged, rates,
                      (10.0, 50.0)) is None
    assert beyond_log(held, load_packaged_calibration(SERIAL), rates, (10.0, 50.0)) is None
    # A baseline that does not move with temperature has nothing to continue.
    flat = dataclasses.replace(packaged, polynomial=ArtPolynomial(np.array([[1e-6, 0.0, 3e-4, 0.01]])))
    assert continued(held, flat, '').continuation is None


def test_a_baseline_with_other_scale_factors_is_refused(tmp_path, capsys):
    packaged = load_packaged_calibration(SERIAL)
    other = tmp_path / 'other.yaml'
    write_calibration(other, dataclasses.replace(packaged, rate_scale_factor=2 * packaged.rate_scale_factor))
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(packaged, SimulationSettings(hours=0.5, seed=0)))
    assert main(['fit', str(log), '--serial', SERIAL, '--rows', '3', '--columns', '4', '--baseline', str(other),
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'R.json')]) == 1
    err = capsys.readouterr().err
    assert str(other) in err and 'rate_scale_factor' in err
    assert not (tmp_path / 'CAL.yaml').exists()


def test_an_aged_bias_slope_refits_the_bias_column_and_keeps_the_report_s_rate_terms(tmp_path, capsys):
    # The gyro's bias slope moved by 0.5 deg/h per degC since its report (+-10 deg/h over 10..50 degC); its rate
    # terms did not. The whole polynomial refitted follows the log's wander in twelve coefficients; the report's
    # file misses the slope. Before, the refit was written (4.78 deg/h on the second run below; the written
    # file now 4.66, the aged truth 4.06, the report's file 14.60).
    packaged = load_packaged_calibration(SERIAL)
    coefficients = packaged.polynomial.coefficients.copy()
    coefficients[-2, -1] += 0.5 / DEG_PER_H_PER_DPS   # rate**0 x T**1
    aged = tmp_path / 'aged.yaml'
    write_calibration(aged, dataclasses.replace(packaged, polynomial=ArtPolynomial(coefficients)))
    settings = SimulationSettings(hours=2.0, seed=4)
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(load_calibration(aged), settings))
    assert main(['fit', str(log), '--serial', SERIAL, '--rows', '3', '--columns', '4', '--out',
                 str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    section = report['baseline']
    assert section['verdict'] == 'baseline_bias_refitted', section['message']
    assert section['baseline_bias_refitted_field_dph'] + report['materiality_dph'] < section['baseline_field_dph']
    assert section['bias_refitted_on_runs'] is None   # one run: the blocks alone judge it
    written = load_calibration(tmp_path / 'CAL.yaml', expected_serial=SERIAL)
    np.testing.assert_array_equal(written.polynomial.coefficients[:, :-1], packaged.polynomial.coefficients[:, :-1])
    assert written.polynomial.coefficients[-2, -1] == pytest.approx(coefficients[-2, -1], abs=0.1 / DEG_PER_H_PER_DPS)
    assert 'baseline\'s polynomial with its bias column refitted' in capsys.readouterr().out
    # On a second run of the gyro the written file is close to the aged truth through the node.
    second = simulate_run(load_calibration(aged), same_gyro(settings, settings.seed + 100)).log(packaged)
    dph = {name: _field_dph(second, cal) for name, cal in
           (('written', written), ('truth', load_calibration(aged)), ('packaged', packaged))}
    assert dph['written'] < 1.25 * dph['truth'] and dph['written'] + 1.0 < dph['packaged'], dph


def test_a_kept_baseline_reports_nothing_beyond_the_log(tmp_path):
    # The written file is the calibration the gyro has: no part of the operating range is new to it, and it
    # differs from itself nowhere. Reported before as "no log covers -10..0 degC ... the file written and the
    # baseline differ there by up to 0.00 deg/h", with the baseline's 0..60 degC given as the log's range.
    calibrated = tmp_path / 'calibrated.yaml'
    write_calibration(calibrated, dataclasses.replace(load_packaged_calibration(SERIAL),
                                                      temperature_range_c=(0.0, 60.0), temperature_warn_range_c=None))
    settings = SimulationSettings(hours=2.0, seed=3, wander_dps=3.6 / DEG_PER_H_PER_DPS, wander_tau_s=3600.0)
    _, report, _ = _fit(tmp_path, settings, '--rows', '3', '--columns', '4', '--baseline', str(calibrated),
                        '--operating-range', '-10', '60')
    section = report['baseline']
    assert section['verdict'] == 'baseline', section['message']
    assert section['beyond_log'] is None and section['unknown_beyond_log'] is None


def test_terms_kept_on_top_of_the_baseline_take_their_time_constants_again():
    # The loop tunes a warm-up's time constant beside its own polynomial; a baseline kept with the terms on top of it
    # held that time constant, so the amplitude fitted there traded for it and missed the warm-up at power-on, where
    # the node's static bias takes it for the whole mission (issue 35's lab protocol: 0.0102 deg/s at 1505 s written
    # for 0.012 deg/s at 1200 s, +6 deg/h on a cold second run). Here the loop's own fit is detuned by 2x.
    packaged = load_packaged_calibration(SERIAL)
    settings = SimulationSettings(hours=2.0, effects=('warmup',), seed=5)
    log = simulate_run(packaged, settings).log(packaged)
    result = close_loop(log, 3, 4, LoopOptions(draws=100))
    _, _, amplitude, tau, _ = EFFECTS['warmup']
    loop_term = next(t for t in result.extended.terms if t.signal == POWER_ON_SIGNAL)
    detuned = dataclasses.replace(result.extended, terms=tuple(
        dataclasses.replace(t, time_constant_s=2.0 * loop_term.time_constant_s) if t is loop_term else t
        for t in result.extended.terms))
    check = compare_with_baseline(log, result, detuned, packaged, 'packaged')
    assert check is not None and check.verdict == BASELINE, check
    written = next(t for t in check.calibration.terms if t.signal == POWER_ON_SIGNAL)
    assert written.time_constant_s == pytest.approx(tau, rel=0.25)
    assert written.coefficients[0] == pytest.approx(amplitude, rel=0.15)


def _aged(slope_dph_per_c):
    """The gyro with its bias slope moved by ``slope_dph_per_c`` since its report (rate**0 x T**1)."""
    packaged = load_packaged_calibration(SERIAL)
    coefficients = packaged.polynomial.coefficients.copy()
    coefficients[-2, -1] += slope_dph_per_c / DEG_PER_H_PER_DPS
    return dataclasses.replace(packaged, polynomial=ArtPolynomial(coefficients))


# The lab protocol (doc/calibration.md) on a Shupe gyro warming itself after power-on, on slow chamber ramps.
SHUPE_LAB = SimulationSettings(hours=2.0, effects=('shupe',), self_heating_c=4.0, self_heating_tau_s=900.0,
                               ramp_c_per_min=0.3, seed=1)


def _protocol(tmp_path, truth):
    """Two cold starts over 10..35 and 25..50 degC and a warm restart, fitted together; the report and written file."""
    runs = [simulate_run(dataclasses.replace(truth, temperature_warn_range_c=(10.0, 35.0)), SHUPE_LAB),
            simulate_run(dataclasses.replace(truth, temperature_warn_range_c=(25.0, 50.0)), same_gyro(SHUPE_LAB, 2)),
            warm_restart(truth, same_gyro(SHUPE_LAB, 3), 1.5 * 3600.0)]
    logs = [str(tmp_path / f'run{k}.csv') for k in range(len(runs))]
    for log, run in zip(logs, runs):
        write_run(log, run)
    assert main(['fit', *logs, '--warm-start', logs[-1], '--serial', SERIAL, '--rows', '3', '--columns', '4',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    return report, load_calibration(tmp_path / 'CAL.yaml', expected_serial=SERIAL)


def test_several_runs_refit_an_aged_bias_slope_that_a_shupe_term_hides_from_the_blocks(tmp_path):
    # Aged by 0.3 deg/h per degC under a Shupe effect: the temperature rate fitted on top of the report's stale
    # bias makes it worse, so the terms did not help the baseline, and the bias column refitted was not better by
    # the materiality on round-robin blocks (3.18 against 4.06 deg/h; materiality 1.23). Before, the baseline was
    # written as it is: 10.69 deg/h on the cold second run below, where the written file now gives 5.36 and the aged
    # truth (its polynomial alone) 4.86.
    truth = _aged(0.3)
    report, written = _protocol(tmp_path, truth)
    section = report['baseline']
    assert section['verdict'] == 'baseline_bias_refitted', section['message']
    on_runs = section['bias_refitted_on_runs']
    assert on_runs['passed'] and on_runs['t'] >= on_runs['min_t'], on_runs
    assert on_runs['differ_dph'] > on_runs['materiality_dph'], on_runs
    packaged = load_packaged_calibration(SERIAL)
    np.testing.assert_array_equal(written.polynomial.coefficients[:, :-1], packaged.polynomial.coefficients[:, :-1])
    second = simulate_run(truth, same_gyro(dataclasses.replace(SHUPE_LAB, hours=4.0), 101)).log(packaged)
    dph = {name: _field_dph(second, cal) for name, cal in
           (('written', written), ('truth', truth), ('packaged', packaged))}
    assert dph['written'] < 1.25 * dph['truth'] and dph['written'] + 3.0 < dph['packaged'], dph


def test_several_runs_of_a_gyro_that_did_not_age_keep_its_bias_column(tmp_path):
    # The same protocol on the report's own polynomial: the bias column refitted, judged against the baseline's with
    # the temperature rate on top of both, differs from it by less than the materiality. Judged against the
    # baseline alone (the terms did not help it by the materiality here), the refitted column won by what the
    # temperature rate removes and was written, here and on the protocol's runs from other seeds (there 7.29 deg/h
    # on a cold second run where the baseline gives 5.04).
    report, written = _protocol(tmp_path, load_packaged_calibration(SERIAL))
    section = report['baseline']
    assert section['verdict'] == 'baseline', section['message']
    on_runs = section['bias_refitted_on_runs']
    assert on_runs is not None and not on_runs['passed'] and on_runs['differ_dph'] < on_runs['materiality_dph'], \
        on_runs
    np.testing.assert_array_equal(written.polynomial.coefficients,
                                  load_packaged_calibration(SERIAL).polynomial.coefficients)


def test_the_paired_judge_wants_a_material_consistent_correction():
    # Per run: the bias-refitted file's and the baseline's mean errors (deg/h) over steady segments, and their parts.
    rng = np.random.default_rng(7)
    folds = np.repeat(np.arange(4), 5)

    def runs(rich, simple):
        return [(rich + rng.normal(0.0, 0.1, 20), simple + rng.normal(0.0, 0.1, 20), folds) for _ in range(3)]

    corrects = paired_check(runs(0.0, 2.0), 1.0)   # the refitted column removes a 2 deg/h error everywhere
    assert corrects.passed and corrects.units == 12 and corrects.differ_dph == pytest.approx(2.0, rel=0.05)
    assert corrects.fall_dph2 == pytest.approx(4.0, rel=0.1), corrects
    assert not paired_check(runs(0.0, 2.0), 2.5).passed                 # smaller than the materiality
    overshoots = paired_check(runs(-1.5, 2.0), 1.0)                   # more a difference than a correction
    assert overshoots.t > 2.0 and 0.0 < overshoots.fall_dph2 < 0.5 * overshoots.differ_dph ** 2, overshoots
    assert not overshoots.passed
    assert not paired_check(runs(2.0, 0.0), 1.0).passed                 # a change for the worse
    # A fall in one part of one run alone is not consistent over the parts.
    spike = [(np.zeros(20), np.where(folds == 0, 6.0, 0.0) if k == 0 else np.zeros(20), folds) for k in range(3)]
    alone = paired_check(spike, 1.0)
    assert alone.differ_dph > 1.0 and alone.fall_dph2 >= 0.5 * alone.differ_dph ** 2 and alone.t < 2.0, alone
    # A segment where the node dropped a row (NaN) is left out of the pairs.
    rich, simple, k = runs(0.0, 2.0)[0]
    rich[:5] = np.nan
    assert paired_check([(rich, simple, k)], 1.0).units == 3
