"""The refit judged against the baseline over the robot's operating range, never on a range nobody calibrated.

A gyro whose true polynomial is its packaged one plus a term cubic in temperature (a bias, or a
scale factor), logged over 14..54 degC: the packaged file's 10..50 degC is ``temperature_warn_range_c``,
an assumption of this package, not a calibrated range, so nothing is judged over 10..14 degC.
"""

import dataclasses
import json

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration, write_calibration
from art_gyro_calibration.compensation import RunStart
from art_gyro_calibration.analysis.baseline import beyond_log, unknown_beyond_log
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.replay import replay, replay_field
from art_gyro_calibration.analysis.simulate import SimulationSettings, same_gyro, simulate_run, write_run
from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.units import DEG_PER_H_PER_DPS

SERIAL = 'NAVC3545'   # a 3 x 4 gyro, its packaged file warned (assumed) over 10..50 degC
LOG_C = (14.0, 54.0)
# 4 h at 2 Hz: two chamber cycles, 120 rows of rest for the static bias, a fit in seconds.
SETTINGS = SimulationSettings(hours=4.0, rate_hz=2.0, seed=5)
# The cubic terms: size * u**3, u = (T - 34) / 20 (-1..1 over the log), on the bias (rate**0) or the scale
# factor (rate**1): 0.01 deg/s (36 deg/h) at the log's ends, or 300 ppm (0.03 deg/s at 100 deg/s).
CUBIC = {'bias': (3, 0.01), 'scale_factor': (2, 3e-4)}


def _gyro(cubic, chamber_c=LOG_C):
    """The simulated gyro: the packaged polynomial plus a cubic temperature term, in a chamber over ``chamber_c``."""
    packaged = load_packaged_calibration(SERIAL)
    coefficients = np.vstack([np.zeros((1, packaged.polynomial.columns)), packaged.polynomial.coefficients])
    column, size = CUBIC[cubic]
    center, half = 0.5 * (LOG_C[0] + LOG_C[1]), 0.5 * (LOG_C[1] - LOG_C[0])
    # size * ((T - c) / h)**3 in powers of T, highest first.
    coefficients[:, column] += size / half ** 3 * np.array([1.0, -3.0 * center, 3.0 * center ** 2, -center ** 3])
    return dataclasses.replace(packaged, polynomial=ArtPolynomial(coefficients), temperature_warn_range_c=chamber_c)


def _fit(tmp_path, cubic, *extra, name='fit'):
    """The written file and REPORT.json of ``calibrate fit`` (3 x 4) on a 14..54 degC log of the ``cubic`` gyro."""
    log = tmp_path / 'LOG.csv'
    if not log.exists():
        write_run(log, simulate_run(_gyro(cubic), SETTINGS))
    out, report = tmp_path / f'{name}.yaml', tmp_path / f'{name}.json'
    assert main(['fit', str(log), '--serial', SERIAL, '--rows', '3', '--columns', '4', '--out', str(out),
                 '--report', str(report), *extra]) == 0
    return load_calibration(out, expected_serial=SERIAL), json.loads(report.read_text())


def _second_run(calibration, cubic, chamber_c=LOG_C):
    """A second run of the ``cubic`` gyro over ``chamber_c``, read with ``calibration``'s scale factors."""
    return simulate_run(_gyro(cubic, chamber_c), same_gyro(SETTINGS, SETTINGS.seed + 100)).log(calibration)


def _field_dph(calibration, cubic):
    """Systematic rms with the bias on a second cold run of the gyro, as the node applies ``calibration``."""
    log = _second_run(calibration, cubic)
    return replay_field(log, calibration, 100, start=RunStart(powered_on_at_start=True)).systematic_rms_dps \
        * DEG_PER_H_PER_DPS


@pytest.mark.parametrize('cubic', sorted(CUBIC))
def test_a_file_far_better_on_the_log_is_written_though_the_baseline_was_never_calibrated_beyond_it(
        tmp_path, capsys, cubic):
    # Vetoed before: "beyond it the refit, held at the log's edge, is worse than the baseline by up to
    # 306 deg/h at 10 degC" (199 for the scale factor), over the packaged file's assumed 10..50 degC.
    written, report = _fit(tmp_path, cubic)
    section = report['baseline']
    packaged = load_packaged_calibration(SERIAL)
    # A cubic bias is the report's rate terms with another bias column (the loop's temperature term, T**3, on top):
    # the simpler file. A cubic scale factor needs the whole polynomial refitted.
    assert section['verdict'] == {'bias': 'baseline_bias_refitted', 'scale_factor': 'refit'}[cubic], \
        section['message']
    assert section['operating_range_c'] == list(LOG_C)   # the default: the log's envelope
    assert section['beyond_log'] is None and section['unknown_beyond_log'] is None
    # Held out on the log the written file beats the report's file several times over.
    assert 4.0 * section['refit_field_dph'] < section['baseline_field_dph']
    assert not np.array_equal(written.polynomial.coefficients, packaged.polynomial.coefficients)
    # And so it does on a second run of the gyro over the same range.
    assert 2.0 * _field_dph(written, cubic) < _field_dph(packaged, cubic)
    assert 'Operating range 14..54 degC' in capsys.readouterr().out   # REPORT.md, printed


def test_an_operating_range_beyond_an_uncalibrated_baseline_is_reported_as_unknown(tmp_path, capsys):
    written, report = _fit(tmp_path, 'bias', '--operating-range', '10', '54')
    section = report['baseline']
    assert section['verdict'] == 'baseline_bias_refitted', section['message']   # the simpler file: see above
    assert section['operating_range_c'] == [10.0, 54.0]
    assert section['beyond_log'] is None   # the baseline is calibrated nowhere: nothing beyond the log is judged
    unknown = section['unknown_beyond_log']
    assert unknown['ranges_c'] == [[10.0, 14.0]] and unknown['log_range_c'] == list(LOG_C)
    assert unknown['baseline_range_c'] is None
    # By how much the two disagree there, as information: the file continued by the baseline, by the correction
    # the log measured at 14 degC (the cube's 36 deg/h there, as fitted), not the hundreds of deg/h at 100 deg/s
    # that the baseline moves below it.
    assert 20.0 < unknown['disagree_dph'] < 80.0
    out, err = capsys.readouterr()
    assert 'Operating range 10..54 degC' in out and 'Unknown: no log covers 10..14 degC of the operating range' in out
    assert 'no log covers 10..14 degC' in err


def test_beyond_the_log_where_the_baseline_is_calibrated_the_written_file_continues_it(tmp_path, capsys):
    # The same gyro and log, its baseline calibrated over 0..60 degC, the robot running 5..54 degC. Held at
    # 14 degC the refit lost at 5..14 degC all the baseline moves there, and the verdict kept the baseline,
    # which errs by the whole cube. The file written now (the baseline's bias column refitted, with the cube
    # term on top) is continued from 14 degC by the baseline: there it moves as the baseline does.
    baseline = tmp_path / 'calibrated.yaml'
    write_calibration(baseline, dataclasses.replace(load_packaged_calibration(SERIAL), temperature_range_c=(0.0, 60.0),
                                                    temperature_warn_range_c=None))
    _, default = _fit(tmp_path, 'bias', '--baseline', str(baseline), name='default')
    # Asked nothing, the report says where else the two could be compared.
    assert default['baseline']['verdict'] == 'baseline_bias_refitted'
    assert 'the baseline was calibrated over 0..60 degC: give --operating-range' in default['baseline']['message']
    written, report = _fit(tmp_path, 'bias', '--baseline', str(baseline), '--operating-range', '5', '54', name='wide')
    section = report['baseline']
    assert section['verdict'] == 'baseline_bias_refitted', section['message']
    beyond = section['beyond_log']
    assert beyond['judged_c'] == [[5.0, 14.0]] and beyond['baseline_range_c'] == [0.0, 60.0]
    assert section['unknown_beyond_log'] is None   # all of 5..54 degC is logged or calibrated
    assert written.continuation is not None and written.continuation.temperature_range_c == (0.0, 60.0)
    assert 'where the baseline is calibrated (0..60 degC), the written file differs' in capsys.readouterr().out
    # On a run over 5..54 degC, below the log's 14 degC: the file held there errs three times what the
    # baseline does (107.6 against 34.0 deg/h rms); continued, as the baseline does (34.0).
    held = dataclasses.replace(written, continuation=None)
    continued_dph = _beyond_dph(written)
    assert continued_dph < _beyond_dph(load_calibration(baseline)) + 1.0
    assert 2.0 * continued_dph < _beyond_dph(held)


def _beyond_dph(calibration, wide=(5.0, 54.0)):
    """Rms error (deg/h) on a cold second run of the ``bias`` gyro over ``wide``, on its rows below the log's range."""
    log = _second_run(calibration, 'bias', wide)
    done = replay(log, calibration, 100, start=RunStart(powered_on_at_start=True))
    below = log.temp_c[done.applied.kept] < LOG_C[0]
    return float(np.sqrt(np.mean(done.error_dps[below] ** 2))) * DEG_PER_H_PER_DPS


def test_beyond_the_log_only_the_calibrated_part_of_the_operating_range_is_judged():
    packaged = load_packaged_calibration(SERIAL)
    rates = np.array([-100.0, 10.0, 100.0])
    refit = dataclasses.replace(packaged, temperature_range_c=(20.0, 32.0), temperature_warn_range_c=None)
    calibrated = dataclasses.replace(packaged, temperature_range_c=(15.0, 40.0), temperature_warn_range_c=None)
    # Operating 10..50: compared over 15..20 and 32..40 (calibrated), unknown 10..15 and 40..50.
    beyond = beyond_log(refit, calibrated, rates, (10.0, 50.0))
    assert beyond.judged_c == ((15.0, 20.0), (32.0, 40.0))
    temp = np.concatenate([np.arange(15.0, 20.5, 0.5), np.arange(32.0, 40.5, 0.5)])
    r, t = np.meshgrid(np.append(rates, 0.0), temp)
    moves = np.abs(packaged.polynomial.error(r, t) - packaged.polynomial.error(r, np.clip(t, 20.0, 32.0)))
    assert beyond.differ_dph == pytest.approx(moves.max() * DEG_PER_H_PER_DPS)
    unknown = unknown_beyond_log(refit, calibrated, rates, (10.0, 50.0))
    assert unknown.ranges_c == ((10.0, 15.0), (40.0, 50.0))
    temp = np.concatenate([np.arange(10.0, 15.5, 0.5), np.arange(40.0, 50.5, 0.5)])
    r, t = np.meshgrid(np.append(rates, 0.0), temp)
    # The baseline as the node applies it, clamped to its calibrated range; the refit at the log's edge.
    disagree = np.abs(packaged.polynomial.error(r, np.clip(t, 15.0, 40.0))
                      - packaged.polynomial.error(r, np.clip(t, 20.0, 32.0)))
    assert unknown.disagree_dph == pytest.approx(disagree.max() * DEG_PER_H_PER_DPS)
    # A baseline calibrated nowhere (the packaged file: only warned over 10..50): nothing judged, all unknown.
    assert beyond_log(refit, packaged, rates, (10.0, 50.0)) is None
    assert unknown_beyond_log(refit, packaged, rates, (10.0, 50.0)).ranges_c == ((10.0, 20.0), (32.0, 50.0))
    # An operating range the log covers: nothing beyond it.
    assert beyond_log(refit, calibrated, rates, (22.0, 30.0)) is None
    assert unknown_beyond_log(refit, calibrated, rates, (20.0, 32.0)) is None


@pytest.mark.parametrize('values, why', [
    (['40', '20'], 'LO < HI'), (['20', '20'], 'LO < HI'), (['nan', '40'], 'finite'), (['20', 'inf'], 'finite'),
    (['-100', '40'], '-60..130'), (['20', '300'], '-60..130')])
def test_a_bad_operating_range_is_refused_naming_the_option(tmp_path, capsys, values, why):
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(_gyro('bias'), dataclasses.replace(SETTINGS, hours=0.5)))
    assert main(['fit', str(log), '--serial', SERIAL, '--rows', '3', '--columns', '4', '--operating-range', *values,
                 '--out', str(tmp_path / 'C.yaml'), '--report', str(tmp_path / 'R.json')]) == 1
    err = capsys.readouterr().err
    assert '--operating-range' in err and why in err and 'Traceback' not in err
    assert not (tmp_path / 'C.yaml').exists() and not (tmp_path / 'R.json').exists()
