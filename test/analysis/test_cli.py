"""``calibrate`` end to end on a small simulated log: simulate, fit, apply, and the node's per-sample path."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.compensation import Compensator, apply_calibration
from art_gyro_calibration.log import RawLogWriter, read_log

REPO = Path(__file__).resolve().parents[2]


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
    # Each effect as the loop fitted it with its refit polynomial, and a held-out error it lowers; the simulated
    # gyro's polynomial is its packaged one, which is kept, with the term fitted again on top of it.
    assert report['baseline']['verdict'] == 'baseline'
    for effect, term in zip(report['effects'], cal.terms):
        assert effect['signal'] == term.signal and effect['form'] == term.form
        assert effect['coefficients'] == pytest.approx(term.coefficients, rel=0.05)
        assert effect['held_out_rms_with_dps'] < effect['held_out_rms_without_dps']
    for stage in ('uncalibrated', 'art', 'extended'):
        assert set(report['errors'][stage]) == {'rms_dps', 'systematic_rms_dps', 'heading_360_deg_max'}
    errors = report['errors']
    assert errors['extended']['systematic_rms_dps'] < errors['art']['systematic_rms_dps'] \
        < errors['uncalibrated']['systematic_rms_dps']
    assert report['noise_floor_dps'] > 0
    assert (fitted / 'REPORT.md').read_text().startswith('# Calibration of NAVC4058')
    pngs = sorted(p.name for p in (fitted / 'plots').glob('*.png'))
    assert pngs == ['error-vs-rate.png', 'heading-360.png', 'residual-temperature_rate.png', 'residual-vs-signals.png']
    # The loop's statistics in physical units, the alarm, and the forms tried.
    assert report['model_adequate'] is True and report['adequacy']['budget_dph'] > 0
    assert report['materiality_dph'] == pytest.approx(report['bias_instability_dph'])
    shupe = report['effects'][0]
    assert 0 < shupe['p_value'] <= 0.05 and shupe['effect_dph'] > report['materiality_dph']
    assert {'temperature_lag', 'time_since_power_on', 'rate_x_temperature_rate'} <= set(report['forms_tried'])
    assert report['screens'][0]['draws'] == 200 and report['screens'][0]['alpha'] == 0.01
    assert report['findings_not_written'] == []
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
     '1 of 200 rows excluded: values not finite (1 in supply_v)'),
])
def test_bad_inputs_are_clear_errors(fitted, monkeypatch, capsys, args, message):
    monkeypatch.chdir(fitted)
    (fitted / 'moving.csv').write_text('t,rate_dps,temp_c\n' + ''.join(f'{i},{5.0},{20}\n' for i in range(200)))
    (fitted / 'noref.csv').write_text('t,rate_dps,temp_c\n' + ''.join(f'{i},0.01,{20 + i / 100}\n' for i in range(200)))
    (fitted / 'bad.csv').write_text('t,rate_dps,temp_c\n0,0.1,20\n1,abc,20\n')
    (fitted / 'nanextra.csv').write_text('t,rate_dps,temp_c,ref_rate,supply_v\n'
                                         + ''.join(f'{i},0.01,{20 + i / 20},{0 if i < 100 else 30},'
                                                   f'{"nan" if i == 2 else 24}\n' for i in range(200)))
    assert main(args) == 1
    err = capsys.readouterr().err
    assert f'calibrate {args[0]}: error:' in err and message in err


def test_excluded_signal_is_not_used(fitted):
    d = fitted
    assert main(['fit', str(d / 'LOG.csv'), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--exclude', 'temperature_rate', '--max-effects', '1',
                 '--out', str(d / 'X.yaml'), '--report', str(d / 'X.json')]) == 0
    report = json.loads((d / 'X.json').read_text())
    assert all(c['signal'] != 'temperature_rate' for screen in report['screens'] for c in screen['candidates'])


def test_python_dash_m_is_calibrate():
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), env.get('PYTHONPATH', '')])
    done = subprocess.run([sys.executable, '-m', 'art_gyro_calibration', 'apply', '--help'],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith('usage: calibrate apply')


@pytest.mark.parametrize('flag, value', [('--rows', '0'), ('--alpha', '0'), ('--alpha', '1.5')])
def test_usage_errors(capsys, flag, value):
    args = {'--rows': '3', '--alpha': '0.01', flag: value}
    with pytest.raises(SystemExit) as exc:
        main(['fit', 'LOG.csv', '--columns', '2', '--out', 'c', '--report', 'r',
              *[x for pair in args.items() for x in pair]])
    assert exc.value.code == 2
    assert flag in capsys.readouterr().err


def test_record_writes_the_raw_log_through_the_driver(tmp_path, capsys):
    """``calibrate record`` reads a fake RD2100 on a pty through the node's driver."""
    from art_gyro_calibration.fake_gyro import FakeGyro
    out = tmp_path / 'REC.csv'
    with FakeGyro('NAVC3545', rate_hz=100, profile='30', temperature=31.5, seed=5) as fake:
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


def _raw_log(path: Path, n: int, t0: float = 1.7e9, rate_hz: float = 1000.0, bad_temp_rows: tuple[int, ...] = ()):
    """A raw log of a still, then turning gyro as the node writes it; rows ``bad_temp_rows`` claim 200 degC."""
    rng = np.random.default_rng(7)
    t = t0 + np.arange(n) / rate_hz + rng.uniform(0, 0.2 / rate_hz, n)
    raw_rate = np.where(np.arange(n) < 300, 0, 9000) + rng.integers(-3, 4, n)
    raw_temp = 400 + np.arange(n) // 500
    raw_temp[list(bad_temp_rows)] = 4000
    with open(path, 'w', encoding='utf-8') as stream:
        writer = RawLogWriter(stream)
        for row in zip(t.tolist(), raw_rate.tolist(), raw_temp.tolist()):
            writer.write(*row)
        writer.close()
    return t


def test_apply_keeps_epoch_time_to_the_microsecond(fitted, tmp_path):
    """A node log in epoch seconds at 1 kHz: every output time is the input's, to the microsecond."""
    t = _raw_log(tmp_path / 'epoch.csv', 3000)
    out = tmp_path / 'out.csv'
    assert main(['apply', str(tmp_path / 'epoch.csv'), '--calibration', str(fitted / 'CAL.yaml'),
                 '--out', str(out)]) == 0
    written = read_log(out).t
    assert len(np.unique(written)) == len(t)
    assert np.max(np.abs(written - t)) <= 0.5e-6 + np.spacing(t[-1])


def _leftovers(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.startswith('.calibrate-'))


def test_apply_never_overwrites_its_input_and_asks_before_replacing(fitted, tmp_path, capsys):
    log = tmp_path / 'log.csv'
    _raw_log(log, 1000)
    original = log.read_bytes()
    (tmp_path / 'link.csv').symlink_to(log)
    os.link(log, tmp_path / 'hard.csv')
    (tmp_path / 'sub').mkdir()
    cal = str(fitted / 'CAL.yaml')
    for out in (log, tmp_path / 'link.csv', tmp_path / 'hard.csv', tmp_path / 'sub' / '..' / 'log.csv', cal):
        for force in ([], ['--force']):
            assert main(['apply', str(log), '--calibration', cal, '--out', str(out), *force]) == 1
            assert 'is the input' in capsys.readouterr().err
    assert log.read_bytes() == original
    out = tmp_path / 'out.csv'
    out.write_text('precious\n')
    assert main(['apply', str(log), '--calibration', cal, '--out', str(out)]) == 1
    assert 'exists; pass --force to replace it' in capsys.readouterr().err
    assert out.read_text() == 'precious\n'
    assert main(['apply', str(log), '--calibration', cal, '--out', str(out), '--force']) == 0
    assert out.read_text().startswith('t,rate_dps,temp_c,comp_dps,corrected_dps\n')
    assert _leftovers(tmp_path) == []


def test_a_failing_apply_leaves_no_partial_output(fitted, tmp_path, capsys):
    """A bad row far into the log (after chunks were written): no output, and a replaced one intact."""
    log = tmp_path / 'log.csv'
    _raw_log(log, 150_000)
    lines = log.read_text().splitlines(keepends=True)
    lines[140_001] = lines[140_001].replace(',', ',?', 1)
    log.write_text(''.join(lines))
    out = tmp_path / 'out.csv'
    assert main(['apply', str(log), '--calibration', str(fitted / 'CAL.yaml'), '--out', str(out)]) == 1
    assert 'log.csv:140002: row 140001, column raw_rate' in capsys.readouterr().err
    assert not out.exists() and _leftovers(tmp_path) == []
    out.write_text('previous result\n')
    assert main(['apply', str(log), '--calibration', str(fitted / 'CAL.yaml'), '--out', str(out), '--force']) == 1
    assert out.read_text() == 'previous result\n' and _leftovers(tmp_path) == []


def test_fit_checks_its_outputs_before_fitting(fitted, tmp_path, monkeypatch, capsys):
    import art_gyro_calibration.analysis.pipeline as pipeline

    def no_fit(*args, **kwargs):
        raise AssertionError('the fit ran before its outputs were checked')
    monkeypatch.setattr(pipeline, 'close_loop', no_fit)
    log = str(fitted / 'LOG.csv')
    (tmp_path / 'CAL.yaml').write_text('keep me\n')
    (tmp_path / 'REPORT.md').write_text('keep me\n')
    (tmp_path / 'plots').mkdir()
    (tmp_path / 'plots' / 'sim-heading-360.png').write_bytes(b'keep me')
    fit = ['fit', log, '--rows', '3', '--columns', '2']
    for args, message in (
            (['--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'new.json')], 'CAL.yaml: exists'),
            (['--out', str(tmp_path / 'new.yaml'), '--report', str(tmp_path / 'REPORT.json')], 'REPORT.md: exists'),
            (['--out', log, '--report', str(tmp_path / 'new.json'), '--force'], 'is the input'),
            (['--out', str(tmp_path / 'new.yaml'), '--report', str(tmp_path / 'new.json'),
              '--plots', str(tmp_path / 'plots'), '--plot-prefix', 'sim-'], 'already holds sim-heading-360.png'),
            (['--out', str(tmp_path / 'new.yaml'), '--report', str(tmp_path / 'no' / 'new.json')], 'does not exist')):
        assert main(fit + args) == 1
        assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['CAL.yaml', 'REPORT.md', 'plots']
    assert (tmp_path / 'CAL.yaml').read_text() == 'keep me\n'


def test_a_failing_fit_writes_nothing(fitted, tmp_path, monkeypatch, capsys):
    """The plots fail after the calibration and report were written: none of them appears."""
    import art_gyro_calibration.analysis.plots as plots

    def broken(*args, **kwargs):
        raise OSError('disk full')
    monkeypatch.setattr(plots, 'plot_all', broken)
    assert main(['fit', str(fitted / 'LOG.csv'), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json'),
                 '--plots', str(tmp_path / 'plots')]) == 1
    assert 'disk full' in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_simulate_self_heating_and_a_shupe_effect_on_the_true_rate(tmp_path, capsys):
    out = tmp_path / 'sim.csv'
    assert main(['simulate', '--serial', 'NAVC3545', '--hours', '0.1', '--out', str(out), '--effect', 'shupe_true_rate',
                 '--self-heating-c', '3', '--self-heating-tau-s', '300']) == 0
    truth = json.loads((tmp_path / 'sim.truth.json').read_text())
    assert truth['self_heating']['c'] == 3.0 and truth['self_heating']['time_constant_s'] == 300.0
    assert list(truth['effects']) == ['shupe_true_rate']
    cal = load_packaged_calibration('NAVC3545')
    log = read_log(out, cal.rate_scale_factor, cal.temp_scale_factor)
    # The chamber holds for 15 minutes at the bottom: what the gyro reads rise is its own warming.
    assert log.temp_c[-1] - log.temp_c[0] == pytest.approx(3.0 * (1 - np.exp(-log.t[-1] / 300.0)),
                                                           abs=cal.temp_scale_factor)


@pytest.mark.parametrize('option, value, message', [
    ('--self-heating-c', '-1', 'argument --self-heating-c: must be a number >= 0, got -1'),
    ('--self-heating-c', 'inf', 'argument --self-heating-c: must be a number >= 0'),
    ('--self-heating-c', '40', '--self-heating-c: self_heating_c 40 degC must be smaller than the calibrated range'),
    ('--self-heating-tau-s', '0', 'argument --self-heating-tau-s: must be a positive number, got 0')])
def test_simulate_refuses_a_bad_self_heating(tmp_path, capsys, option, value, message):
    out = tmp_path / 'sim.csv'
    try:
        status = main(['simulate', '--serial', 'NAVC3545', '--hours', '0.01', '--out', str(out), option, value])
    except SystemExit as e:   # argparse's refusal
        status = e.code
    assert status in (1, 2)
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_simulate_refuses_to_replace_a_log(tmp_path, capsys):
    out = tmp_path / 'sim.csv'
    (tmp_path / 'sim.truth.json').write_text('{}')
    args = ['simulate', '--serial', 'NAVC3545', '--hours', '0.01', '--out', str(out)]
    assert main(args) == 1
    assert 'sim.truth.json: exists; pass --force' in capsys.readouterr().err
    assert not out.exists()
    assert main(args + ['--force']) == 0
    assert read_log(out, 0.00305, 0.05).t.size == 360 and (tmp_path / 'sim.truth.json').read_text() != '{}'


def test_record_with_a_wrong_port_leaves_an_existing_log_alone(tmp_path, capsys):
    out = tmp_path / 'field.csv'
    out.write_text('t,raw_rate,raw_temp\n1.0,2,500\n')
    assert main(['record', '--port', str(tmp_path / 'nothing'), '--out', str(out), '--duration', '0.3']) == 1
    assert 'exists; pass --force' in capsys.readouterr().err
    assert main(['record', '--port', str(tmp_path / 'nothing'), '--out', str(out), '--duration', '1.3',
                 '--force']) == 1
    err = capsys.readouterr().err
    assert f'nothing from {tmp_path / "nothing"} for 1 s (cannot open' in err, err
    assert 'error: no frames from' in err and 'field.csv not written' in err
    assert out.read_text() == 't,raw_rate,raw_temp\n1.0,2,500\n' and _leftovers(tmp_path) == []
    assert main(['record', '--port', str(out), '--out', str(out), '--force']) == 1
    assert 'is the input' in capsys.readouterr().err


def test_record_says_when_an_open_port_is_silent(tmp_path, capsys):
    from art_gyro_calibration.fake_gyro import FakeGyro
    fake = FakeGyro('NAVC3545', rate_hz=100)   # a pty, never started: open, and quiet
    try:
        assert main(['record', '--port', fake.path, '--out', str(tmp_path / 'r.csv'), '--duration', '1.3']) == 1
    finally:
        fake.stop()
    assert 'for 1 s (port open, no frames); still waiting' in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_force_never_replaces_a_special_file(fitted, tmp_path, capsys):
    """``--force`` replaced a FIFO given as ``--out`` with a regular file."""
    log = tmp_path / 'log.csv'
    _raw_log(log, 1000)
    fifo = tmp_path / 'out.csv'
    os.mkfifo(fifo)
    assert main(['apply', str(log), '--calibration', str(fitted / 'CAL.yaml'), '--out', str(fifo), '--force']) == 1
    assert f'{fifo}: is a FIFO, not a regular file: never replaced' in capsys.readouterr().err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and _leftovers(tmp_path) == []


def test_ctrl_c_on_apply_is_a_clean_stop(fitted, tmp_path, monkeypatch, capsys):
    """Ctrl-C printed a traceback: now one line, exit 130, nothing written or staged."""
    import art_gyro_calibration.analysis.streaming as streaming

    def interrupted(log_path, calibration, bias_samples, out, **kwargs):
        out.write(b'half a result\n')
        raise KeyboardInterrupt
    monkeypatch.setattr(streaming, 'apply_to_csv', interrupted)
    log = tmp_path / 'log.csv'
    _raw_log(log, 1000)
    out = tmp_path / 'out.csv'
    try:
        code = main(['apply', str(log), '--calibration', str(fitted / 'CAL.yaml'), '--out', str(out)])
    except KeyboardInterrupt:
        pytest.fail('Ctrl-C went through calibrate\'s main as a traceback')
    assert code == 130 and capsys.readouterr().err == 'calibrate apply: interrupted: no output written\n'
    assert not out.exists() and _leftovers(tmp_path) == []


def test_staging_of_a_killed_run_is_removed_by_the_next(fitted, tmp_path):
    """SIGKILL left a hidden staging directory (497 MB of a half-written apply) for ever."""
    script = ('import sys, time\n'
              'from art_gyro_calibration.analysis.outputs import Outputs\n'
              'staged = Outputs([]).claim(sys.argv[1])\n'
              'staged.write_bytes(bytes(1 << 20))\n'
              'print(staged, flush=True)\n'
              'time.sleep(60)\n')
    proc = subprocess.Popen([sys.executable, '-c', script, str(tmp_path / 'big.csv')], stdout=subprocess.PIPE,
                            text=True, cwd=REPO)
    staged = Path(proc.stdout.readline().strip())
    proc.kill()
    proc.wait()
    proc.stdout.close()
    assert staged.is_file() and _leftovers(tmp_path) == [staged.parent.name]
    log = tmp_path / 'log.csv'
    _raw_log(log, 1000)
    assert main(['apply', str(log), '--calibration', str(fitted / 'CAL.yaml'), '--out', str(tmp_path / 'o.csv')]) == 0
    assert _leftovers(tmp_path) == [] and not (tmp_path / 'big.csv').exists()


def _table_log(path: Path, rates: list[float], temp_c: tuple[float, float]) -> None:
    """A rate-table log: each of ``rates`` (deg/s) for 60 s at 2 Hz while the temperature ramps over ``temp_c``."""
    ref = np.repeat(rates, 120)
    t = np.arange(ref.size) / 2.0
    temp = np.linspace(*temp_c, ref.size)
    rng = np.random.default_rng(1)
    rate = ref * 1.001 + 0.01 * (temp - 25.0) + rng.normal(0.0, 0.005, ref.size)
    np.savetxt(path, np.column_stack([t, rate, temp, ref]), delimiter=',', header='t,rate_dps,temp_c,ref_rate',
               comments='', fmt='%.9f')


@pytest.mark.parametrize('rates, temp_c, rows, columns, message', [
    ([0.0] * 20, (10.0, 40.0), 3, 4, 'not enough motion for 4 columns: the table held 1 distinct rate(s) (0 deg/s); '
     'a polynomial with powers of the rate 0..3 needs at least 4: log more table rates, or fit --columns 1'),
    ([0.0, 30.0] * 10, (10.0, 40.0), 3, 4, 'held 2 distinct rate(s) (0, 30 deg/s)'),
    ([0.0, 30.0, -45.0, 60.0] * 5, (25.0, 25.3), 3, 4, 'not enough temperature range for 3 rows: the log spans '
     '0.30 degC (25.00..25.30); a polynomial with powers of the temperature 0..2 needs at least 2 degC (1 per power): '
     'log a wider temperature range, or fit --rows 1'),
], ids=['at_rest', 'two_rates', 'one_temperature'])
def test_fit_refuses_a_log_that_cannot_determine_the_polynomial(tmp_path, capsys, rates, temp_c, rows, columns,
                                                                message):
    """No motion: it wrote a calibration reading a true 30 deg/s as 5.9 deg/s, exit 0."""
    log = tmp_path / 'table.csv'
    _table_log(log, rates, temp_c)
    assert main(['fit', str(log), '--rows', str(rows), '--columns', str(columns), '--draws', '20',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 1
    err = capsys.readouterr().err
    assert f'calibrate fit: error: {log}: not enough ' in err and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['table.csv']


def test_fit_excludes_clipped_rows_and_says_how_many(tmp_path, capsys):
    """Rows at +-32767 counts were fitted as values: here four spurious effects (rate_sign, ...)."""
    sim = tmp_path / 'sim.csv'
    assert main(['simulate', '--serial', 'NAVC3545', '--hours', '2', '--rate-hz', '2', '--seed', '3',
                 '--out', str(sim)]) == 0
    with open(sim, encoding='utf-8') as stream:
        header = stream.readline().strip()
    data = np.loadtxt(sim, delimiter=',', skiprows=1)
    assert header.split(',')[1] == 'raw_rate'
    data[:, 1] = np.clip(data[:, 1], -32768, 32767)   # the table's +-100 deg/s beyond NAVC3545's 99.94: clipped
    clipped = int(np.count_nonzero(np.abs(data[:, 1]) >= 32767))
    assert clipped > 500
    log = tmp_path / 'clipped.csv'
    np.savetxt(log, data, delimiter=',', header=header, comments='', fmt=['%.6f', '%d', '%d', '%.9g', '%.9g'])
    capsys.readouterr()
    assert main(['fit', str(log), '--rows', '3', '--columns', '4', '--serial', 'NAVC3545',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    err = capsys.readouterr().err
    assert f'warning: {clipped} of {len(data)} rows excluded: the rate clipped (at +-99.9424 deg/s)' in err, err
    assert load_calibration(tmp_path / 'CAL.yaml').terms == ()


@pytest.fixture(scope='module')
def three_runs(tmp_path_factory):
    """Two cold starts of one gyro and a warm restart, as CSV logs (short: the CLI is what is tested)."""
    from art_gyro_calibration.analysis.simulate import (SimulationSettings, same_gyro, simulate_run, warm_restart,
                                                        write_run)
    d = tmp_path_factory.mktemp('runs')
    cal = load_packaged_calibration('NAVC4058')
    settings = SimulationSettings(hours=0.5, rate_hz=2.0, effects=('warmup',), seed=1)
    write_run(d / 'cold1.csv', simulate_run(cal, settings))
    write_run(d / 'cold2.csv', simulate_run(cal, same_gyro(settings, 2)))
    write_run(d / 'warm.csv', warm_restart(cal, same_gyro(settings, 3), 3600.0))
    write_run(d / 'other.csv', simulate_run(cal, same_gyro(settings, 4)))
    return d


def test_fit_of_several_runs_reports_each(three_runs, monkeypatch):
    monkeypatch.chdir(three_runs)
    assert main(['fit', 'cold1.csv', 'cold2.csv', 'warm.csv', '--warm-start', 'warm.csv', '--rows', '3', '--columns',
                 '2', '--serial', 'NAVC4058', '--out', 'CAL.yaml', '--report', 'REPORT.json']) == 0
    report = json.loads((three_runs / 'REPORT.json').read_text())
    # The warm-up was fitted on two power-ons: no warning that one log alone judged it.
    assert 'time_since_power_on' in report['written']['terms'] and 'warnings' not in report
    logs = [read_log(three_runs / name, 1.0, 1.0) for name in ('cold1.csv', 'cold2.csv', 'warm.csv')]
    assert [(r['name'], r['rows'], r['powered_on_at_start']) for r in report['runs']] == [
        ('cold1.csv', len(logs[0]), True), ('cold2.csv', len(logs[1]), True), ('warm.csv', len(logs[2]), False)]
    assert report['runs'][0]['turn_on_offset_dph'] == 0.0 and report['rows_read'] == sum(len(x) for x in logs)
    cal = load_calibration(three_runs / 'CAL.yaml')
    # The gyro's own polynomial is kept (the simulator's is the packaged one): it has no fitted range to clamp to.
    assert report['baseline']['verdict'] == 'baseline' and cal.temperature_range_c is None
    assert np.array_equal(cal.polynomial.coefficients, load_packaged_calibration('NAVC4058').polynomial.coefficients)
    assert 'cold1.csv and cold2.csv and warm.csv' in (three_runs / 'CAL.yaml').read_text()
    # The node's runs, replayed against the baseline and in the start-up check: each within one run, every run's start.
    names = ['cold1.csv', 'cold2.csv', 'warm.csv']
    assert sorted({r['run'].split(':')[0] for r in report['baseline']['runs']}) == names
    assert [r['source'] for r in report['startup_check']['runs']][:3] == [
        'cold1.csv: from the log\'s power-on', 'cold2.csv: from the log\'s power-on', 'warm.csv: from its start (warm)']
    assert 'Start-up check: the fitted log run from its power-on and restarted warm' in (
        three_runs / 'REPORT.md').read_text()


def test_several_runs_are_validated_on_another(three_runs, monkeypatch):
    monkeypatch.chdir(three_runs)
    assert main(['fit', 'cold1.csv', 'cold2.csv', 'warm.csv', '--warm-start', 'warm.csv', '--rows', '3', '--columns',
                 '2', '--serial', 'NAVC4058', '--out', 'VALIDATED.yaml', '--report', 'VALIDATED.json',
                 '--validate', 'other.csv', '--validate-powered-on-at-start']) == 0
    report = json.loads((three_runs / 'VALIDATED.json').read_text())
    assert [r['source'] for r in report['validation']['runs']] == ['other.csv']
    assert len(report['runs']) == 3


def test_fit_parses_several_logs_and_warm_starts():
    from art_gyro_calibration.analysis.cli import build_parser
    args = build_parser().parse_args(['fit', 'a.csv', 'b.csv', 'c', '--warm-start', 'b.csv', '--warm-start', 'c',
                                      '--rows', '3', '--columns', '2', '--out', 'o.yaml', '--report', 'r.json'])
    assert args.log == ['a.csv', 'b.csv', 'c'] and args.warm_start == ['b.csv', 'c']


@pytest.mark.parametrize('logs, warm, message', [
    (['cold1.csv', 'cold2.csv'], 'warm.csv',
     '--warm-start warm.csv: not one of the logs fitted (cold1.csv, cold2.csv)'),
    (['cold1.csv', 'cold1.csv'], None, 'cold1.csv: given twice'),
])
def test_fit_refuses_a_warm_start_not_fitted(three_runs, monkeypatch, capsys, logs, warm, message):
    monkeypatch.chdir(three_runs)
    assert main(['fit', *logs, *(['--warm-start', warm] if warm else []), '--rows', '3', '--columns', '2',
                 '--out', 'refused.yaml', '--report', 'refused.json']) == 1
    assert message in capsys.readouterr().err
    assert not (three_runs / 'refused.yaml').exists()
