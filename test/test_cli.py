"""``calibrate`` end to end on a small simulated log: simulate, fit, apply, and the node's per-sample path."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.compensation import Compensator, apply_calibration
from art_gyro_calibration.log import read_log

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope='module')
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp('cli')
    log = d / 'LOG.csv'
    assert main(['simulate', '--serial', 'NAVC4058', '--hours', '6', '--rate-hz', '2', '--seed', '4',
                 '--effect', 'shupe', '--out', str(log)]) == 0
    assert main(['fit', str(log), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--out', str(d / 'CAL.yaml'), '--report', str(d / 'REPORT.json'), '--plots', str(d / 'plots')]) == 0
    return d


def test_fit_writes_calibration_report_and_plots(fitted):
    cal = load_calibration(fitted / 'CAL.yaml', expected_serial='NAVC4058')
    assert [t.signal for t in cal.terms] == ['temperature_rate']
    report = json.loads((fitted / 'REPORT.json').read_text())
    assert [e['signal'] for e in report['effects']] == ['temperature_rate']
    # Each effect as fitted: the calibration's term, what it describes, and a held-out error it lowers.
    for effect, term in zip(report['effects'], cal.terms):
        assert effect['coefficients'] == list(term.coefficients)
        assert effect['description'] == term.describe()
        assert effect['held_out_rms_with_dps'] < effect['held_out_rms_without_dps']
    for stage in ('uncalibrated', 'art', 'extended'):
        assert set(report['errors'][stage]) == {'rms_dps', 'systematic_rms_dps', 'heading_360_deg_max'}
    errors = report['errors']
    assert errors['extended']['systematic_rms_dps'] < errors['art']['systematic_rms_dps'] \
        < errors['uncalibrated']['systematic_rms_dps']
    assert report['noise_floor_dps'] > 0
    assert (fitted / 'REPORT.md').read_text().startswith('# Calibration of NAVC4058')
    pngs = sorted(p.name for p in (fitted / 'plots').glob('*.png'))
    assert pngs == ['error-vs-rate.png', 'heading-360.png', 'residual-temperature_rate.png']
    assert all((fitted / 'plots' / p).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' for p in pngs)


def test_apply_writes_the_compensated_log(fitted):
    out = fitted / 'OUT.csv'
    assert main(['apply', str(fitted / 'LOG.csv'), '--calibration', str(fitted / 'CAL.yaml'),
                 '--out', str(out), '--bias-samples', '50']) == 0
    header = out.read_text().splitlines()[0]
    assert header == 't,rate_dps,temp_c,comp_dps,corrected_dps'
    data = np.loadtxt(out, delimiter=',', skiprows=1)
    cal = load_calibration(fitted / 'CAL.yaml')
    log = read_log(fitted / 'LOG.csv', cal.rate_scale_factor, cal.temp_scale_factor)
    np.testing.assert_allclose(data[:, 4], apply_calibration(log, cal, 50).corrected_dps, atol=1e-8)


def test_node_path_matches_apply(fitted):
    """The CAL.yaml the fit wrote, applied sample by sample as the node does, equals apply over the log."""
    cal = load_calibration(fitted / 'CAL.yaml')
    log = read_log(fitted / 'LOG.csv', cal.rate_scale_factor, cal.temp_scale_factor)
    n = 100
    batch = apply_calibration(log, cal, n)
    comp = Compensator(cal)
    errors = [comp.error(t, r, T) for t, r, T in zip(log.t.tolist(), log.rate_dps.tolist(), log.temp_c.tolist())]
    comp.bias = batch.bias  # the same static bias over the first n samples
    corrected = np.array([comp.correct(r, e) for r, e in zip(log.rate_dps.tolist(), errors)])
    np.testing.assert_allclose(errors, batch.comp_dps, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(corrected, batch.corrected_dps, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize('args, message', [
    (['apply', 'missing.csv', '--calibration', 'CAL.yaml', '--out', 'o.csv'], 'cannot read'),
    (['apply', 'LOG.csv', '--calibration', 'missing.yaml', '--out', 'o.csv'], 'cannot read'),
    (['apply', 'LOG.csv', '--calibration', 'CAL.yaml', '--out', 'o.csv', '--bias-samples', '1'], 'bias_samples'),
    (['apply', 'moving.csv', '--calibration', 'CAL.yaml', '--out', 'o.csv'], 'turning'),
    (['fit', 'noref.csv', '--rows', '3', '--columns', '2', '--out', 'c.yaml', '--report', 'r.json'], 'ref_rate'),
    (['apply', 'bad.csv', '--calibration', 'CAL.yaml', '--out', 'o.csv'], 'bad.csv'),
    (['fit', 'nanextra.csv', '--rows', '3', '--columns', '2', '--out', 'c.yaml', '--report', 'r.json'],
     'column supply_v is not a finite number at row 3'),
])
def test_bad_inputs_are_clear_errors(fitted, monkeypatch, capsys, args, message):
    monkeypatch.chdir(fitted)
    (fitted / 'moving.csv').write_text('t,rate_dps,temp_c\n' + ''.join(f'{i},{5.0},{20}\n' for i in range(200)))
    (fitted / 'noref.csv').write_text('t,rate_dps,temp_c\n' + ''.join(f'{i},0.01,{20 + i / 100}\n' for i in range(200)))
    (fitted / 'bad.csv').write_text('t,rate_dps,temp_c\n0,0.1,20\n1,abc,20\n')
    (fitted / 'nanextra.csv').write_text('t,rate_dps,temp_c,ref_rate,supply_v\n'
                                         + ''.join(f'{i},0.01,20,0,{"nan" if i == 2 else 24}\n' for i in range(200)))
    assert main(args) == 1
    err = capsys.readouterr().err
    assert f'calibrate {args[0]}: error:' in err and message in err


def test_excluded_signal_is_not_used(fitted):
    d = fitted
    assert main(['fit', str(d / 'LOG.csv'), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--exclude', 'temperature_rate', '--max-effects', '1',
                 '--out', str(d / 'X.yaml'), '--report', str(d / 'X.json')]) == 0
    report = json.loads((d / 'X.json').read_text())
    assert all(c['signal'] != 'temperature_rate' for screen in report['screens'] for c in screen)


def test_python_dash_m_is_calibrate():
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), env.get('PYTHONPATH', '')])
    done = subprocess.run([sys.executable, '-m', 'art_gyro_calibration', 'apply', '--help'],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith('usage: calibrate apply')


def test_usage_errors(capsys):
    with pytest.raises(SystemExit) as exc:
        main(['fit', 'LOG.csv', '--rows', '0', '--columns', '2', '--out', 'c', '--report', 'r'])
    assert exc.value.code == 2
    assert '--rows' in capsys.readouterr().err


def test_record_writes_the_raw_log_through_the_driver(tmp_path, capsys):
    """``calibrate record`` reads a fake RD2100 on a pty through the node's driver."""
    from art_gyro_calibration.fake_rd2100 import FakeRd2100
    out = tmp_path / 'REC.csv'
    with FakeRd2100('NAVC3545', rate_hz=100, profile='30', temperature=31.5, seed=5) as fake:
        assert main(['record', '--port', fake.path, '--out', str(out), '--baud', '115200',
                     '--serial', 'NAVC3545', '--duration', '1.5']) == 0
    assert 'frames from' in capsys.readouterr().out
    cal = load_packaged_calibration('NAVC3545')
    log = read_log(out, cal.rate_scale_factor, cal.temp_scale_factor)
    assert len(log) > 20
    assert np.all(np.diff(log.t) >= 0)
    assert np.median(log.rate_dps) == pytest.approx(30.0, abs=1.0)
    assert np.median(log.temp_c) == pytest.approx(31.5, abs=0.1)


def test_record_without_a_gyro_fails(tmp_path, capsys):
    assert main(['record', '--port', str(tmp_path / 'nothing'), '--out', str(tmp_path / 'r.csv'),
                 '--duration', '0.3']) == 1
    assert 'calibrate record: error: no frames from' in capsys.readouterr().err
