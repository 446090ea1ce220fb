"""``calibrate fit``: no value that is not a number decides what is written.

A comparison with NaN is false either way: one NaN ``ref_rate`` among the rows, or stamps coarser
than the rows, made the baseline comparison NaN and kept a deliberately wrong baseline with exit 0.
"""

import dataclasses
import json

import numpy as np
import pytest

from art_gyro_calibration.analysis import baseline as baseline_module
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration, write_calibration
from art_gyro_calibration.model import ArtPolynomial

SERIAL = 'NAVC3545'   # a 3 x 4 gyro


@pytest.fixture(scope='module')
def logged(tmp_path_factory):
    """A 2 h simulated log of the gyro and a deliberately wrong baseline (+0.05 deg/s, +1 % scale)."""
    directory = tmp_path_factory.mktemp('fit_input')
    cal = load_packaged_calibration(SERIAL)
    log = directory / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=2.0, seed=5)))
    coefficients = cal.polynomial.coefficients.copy()
    coefficients[-1, -1] += 0.05
    coefficients[-1, -2] += 0.01
    wrong = directory / 'wrong.yaml'
    write_calibration(wrong, dataclasses.replace(cal, polynomial=ArtPolynomial(coefficients)))
    return log, wrong


def _edited(log, path, edit):
    """``log``'s rows, each a list of fields, changed by ``edit`` and written to ``path``."""
    header, *lines = log.read_text().splitlines()
    rows = [line.split(',') for line in lines]
    edit(header.split(','), rows)
    path.write_text('\n'.join([header, *(','.join(row) for row in rows)]) + '\n')
    return path


def _fit(tmp_path, log, wrong):
    return main(['fit', str(log), '--rows', '3', '--columns', '4', '--serial', SERIAL, '--baseline', str(wrong),
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')])


def test_a_nan_reference_and_repeated_stamps_are_dropped_counted_and_the_refit_beats_a_wrong_baseline(
        tmp_path, logged, capsys):
    log, wrong = logged

    def edit(header, rows):
        rows[30000][header.index('ref_rate')] = 'nan'
        rows[40000][header.index('supply_v')] = 'inf'
        for k in (50000, 50001, 60000):   # a logger that wrote a row's stamp again
            rows[k][0] = rows[k - 1][0]
    assert _fit(tmp_path, _edited(log, tmp_path / 'NAN.csv', edit), wrong) == 0
    err = capsys.readouterr().err
    assert 'nan against nan' not in err
    assert '2 of 72000 rows excluded: values not finite (1 in ref_rate, 1 in supply_v)' in err, err
    assert '3 of 71998 rows excluded: they repeat the previous row\'s stamp' in err, err
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    assert report['rows_read'] == 72000 and report['rows'] == 72000 - 5
    assert report['rows_dropped'] == {'not finite: ref_rate': 1, 'not finite: supply_v': 1, 'repeated stamp': 3}
    assert report['baseline']['verdict'] == 'refit'
    assert report['baseline']['refit_field_dph'] < report['baseline']['baseline_field_dph']
    written = load_calibration(tmp_path / 'CAL.yaml', expected_serial=SERIAL)
    assert not np.allclose(written.polynomial.coefficients, load_calibration(wrong).polynomial.coefficients)


def test_stamps_coarser_than_the_rows_are_refused_saying_what_was_found(tmp_path, logged, capsys):
    log, wrong = logged

    def edit(header, rows):
        for row in rows:
            row[0] = str(int(float(row[0])))   # 1 s stamps on a 10 Hz log
    assert _fit(tmp_path, _edited(log, tmp_path / 'COARSE.csv', edit), wrong) == 1
    err = capsys.readouterr().err
    assert (f'{tmp_path}/COARSE.csv: column t: 64800 of 72000 rows repeat the previous stamp: the stamps step by '
            '1 s while the log has 10 rows per second') in err, err
    assert 'Traceback' not in err and not (tmp_path / 'CAL.yaml').exists()


def test_a_column_mostly_not_finite_is_refused(tmp_path, logged, capsys):
    log, wrong = logged

    def edit(header, rows):
        for k, row in enumerate(rows):
            if k % 3:
                row[header.index('supply_v')] = 'nan'
    assert _fit(tmp_path, _edited(log, tmp_path / 'HALF.csv', edit), wrong) == 1
    assert '48000 of 72000 rows have values that are not finite (48000 in supply_v): too few rows left' in \
        capsys.readouterr().err


def test_a_comparison_that_cannot_be_computed_stops_the_fit(tmp_path, logged, capsys, monkeypatch):
    """Whatever made a score NaN, the fit says so and writes nothing, rather than keeping the baseline."""
    log, wrong = logged
    scores = iter([np.nan, 1000.0 / 3600.0, 900.0 / 3600.0])   # the refit's, the baseline's, its bias refitted's
    monkeypatch.setattr(baseline_module, 'field_score_dps', lambda runs: next(scores))
    assert _fit(tmp_path, log, wrong) == 1
    err = capsys.readouterr().err
    assert f'calibrate fit: error: the refit cannot be judged against the baseline {wrong} (nan against 1000 deg/h ' \
           'held out: a score is not a number; from the log\'s start' in err, err
    assert not (tmp_path / 'CAL.yaml').exists()


def test_a_bias_refitted_baseline_that_cannot_be_scored_stops_the_fit(tmp_path, logged, capsys, monkeypatch):
    log, wrong = logged
    scores = iter([500.0 / 3600.0, 1000.0 / 3600.0, np.nan])   # the refit's, the baseline's, its bias refitted's
    monkeypatch.setattr(baseline_module, 'field_score_dps', lambda runs: next(scores))
    assert _fit(tmp_path, log, wrong) == 1
    assert f'the refit cannot be judged against the baseline {wrong}: the baseline with its bias column refitted ' \
        'scores nan deg/h held out: nothing written' in capsys.readouterr().err
    assert not (tmp_path / 'CAL.yaml').exists()


def test_both_sides_refusing_the_static_bias_stops_the_fit(tmp_path, logged, capsys, monkeypatch):
    log, wrong = logged
    monkeypatch.setattr(baseline_module, 'field_score_dps', lambda runs: np.inf)
    assert _fit(tmp_path, log, wrong) == 1
    assert 'the node would refuse the static bias with either' in capsys.readouterr().err


def test_a_validation_run_with_a_nan_reference_is_judged_on_its_defined_rows(tmp_path, logged, capsys):
    log, wrong = logged

    def edit(header, rows):
        rows[30000][header.index('ref_rate')] = 'nan'
    other = _edited(log, tmp_path / 'OTHER.csv', edit)
    assert main(['fit', str(log), '--rows', '3', '--columns', '4', '--serial', SERIAL, '--baseline', str(wrong),
                 '--validate', str(other), '--out', str(tmp_path / 'CAL.yaml'),
                 '--report', str(tmp_path / 'REPORT.json')]) == 0
    assert f'{other}: 1 of 72000 rows excluded: values not finite (1 in ref_rate)' in capsys.readouterr().err
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    assert report['validation_rows_dropped'] == {str(other): {'not finite: ref_rate': 1}}
    # Before, the run's scores were NaN (null in REPORT.json): no term could be judged on it.
    scores = report['validation']['runs'][0]['calibrations']
    assert all(scores[name]['systematic_rms_dps'] is not None for name in ('art', 'extended')), scores
