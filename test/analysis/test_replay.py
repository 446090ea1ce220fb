"""Field replay: a calibration applied to another run as the node applies it, and the field errors."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.metrics import field_errors, heading_error_deg, steady_segments
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.replay import (_refit, field_score_dps, own_restarts, replay, replay_field, restart,
                                                  startup_check, validate, without_terms)
from art_gyro_calibration.analysis.runs import joined
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, warm_restart, write_run
from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration
from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.analysis.csv_writer import write_columns
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import FIRST_ORDER_TAU_S, POWER_ON_SIGNAL, SignalFilters
from art_gyro_calibration.static_bias import MotionError
from art_gyro_calibration.temperature_rate import FIRST_ORDER
from art_gyro_calibration.terms import Term

REPO = Path(__file__).resolve().parents[2]


def _table(hours: float = 1.5, rate_hz: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A still start (the static bias), then steps of +-10 deg/s and rests of 5 minutes each."""
    t = np.arange(int(hours * 3600 * rate_hz)) / rate_hz
    ref = np.where(t < 60.0, 0.0, np.array([10.0, 0.0, -10.0, 0.0])[((t - 60.0) // 300.0).astype(int) % 4])
    return t, ref


def test_field_errors_of_a_constant_bias():
    t, ref = _table()
    start = 100
    error = np.full(t.size, 1e-3)  # 3.6 deg/h
    fe = field_errors(t, error, steady_segments(t, ref), start)
    assert fe.mean_bias_dps == pytest.approx(1e-3)
    assert fe.to_dict()['mean_bias_dph'] == pytest.approx(3.6)
    assert fe.to_dict()['systematic_rms_dph'] == pytest.approx(3.6)
    assert fe.heading_10min_deg == pytest.approx(0.6)
    assert fe.heading_1h_deg == pytest.approx(3.6)


def test_field_errors_of_a_linear_drift():
    t, ref = _table()
    start = 100
    drift = 1e-6  # deg/s per s: 3.6 deg/h more every 1000 s
    error = drift * (t - t[start])
    fe = field_errors(t, error, steady_segments(t, ref, settle_s=0.0), start)
    assert fe.heading_10min_deg == pytest.approx(drift * 600.0 ** 2 / 2)
    assert fe.heading_1h_deg == pytest.approx(drift * 3600.0 ** 2 / 2)
    # Equal steady rows on each side of the middle of the log: the mean is the drift at the middle.
    rows = steady_segments(t, ref, settle_s=0.0).rows()
    rows = rows[rows >= start]
    assert fe.mean_bias_dps == pytest.approx(drift * (t[rows].mean() - t[start]))


def test_a_heading_beyond_the_log_is_unknown():
    t, ref = _table(hours=0.5)
    fe = field_errors(t, np.full(t.size, 1e-3), steady_segments(t, ref), 100)
    assert fe.heading_10min_deg == pytest.approx(0.6)
    assert np.isnan(fe.heading_1h_deg)
    assert fe.to_dict()['heading_1h_deg'] is None
    assert heading_error_deg(t, np.ones(t.size), 0, [0.0, 60.0]) == pytest.approx([0.0, 60.0])


@pytest.fixture(scope='module')
def calibration():
    return load_packaged_calibration('NAVC4058')


def _simulated(calibration, path, seed, effects, hours=4.0):
    run = simulate_run(calibration, SimulationSettings(hours=hours, rate_hz=2.0, seed=seed, effects=effects))
    write_run(path, run)
    return run.log(calibration)


def test_replay_is_the_node_on_a_cold_start(calibration):
    log = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=2.0, seed=1, effects=('shupe',))).log(
        calibration)
    extended = replace(calibration, terms=(Term('temperature_rate', 'power', (0.24,), (1,)),))
    done = replay(log, extended, 100)
    applied = apply_calibration(log, extended, 100)
    np.testing.assert_array_equal(done.applied.corrected_dps, applied.corrected_dps)
    np.testing.assert_array_equal(done.error_dps, applied.corrected_dps - log.ref_rate)
    want = field_errors(log.t, done.error_dps, steady_segments(log.t, log.ref_rate), 100)
    assert done.field.to_dict() == want.to_dict()
    # The report's calibration is the same file without its terms.
    assert without_terms(extended) == calibration


def test_replay_tells_the_node_how_the_run_started(calibration):
    log = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=2.0, seed=1, effects=('warmup',))).log(
        calibration)
    warm_up = replace(calibration, terms=(Term('time_since_power_on', 'exp_decay', (0.02,), (), 1200.0),))
    cold, unknown = RunStart(powered_on_at_start=True), RunStart()
    np.testing.assert_array_equal(replay(log, warm_up, 100, start=cold).applied.corrected_dps,
                                  apply_calibration(log, warm_up, 100, start=cold).corrected_dps)
    # Told of the power-on, the warm-up term removes the simulated one; left unknown, it is not applied.
    assert replay(log, warm_up, 100, start=cold).field.systematic_rms_dps \
        < 0.5 * replay(log, warm_up, 100, start=unknown).field.systematic_rms_dps
    np.testing.assert_array_equal(replay(log, warm_up, 100).applied.corrected_dps,
                                  replay(log, calibration, 100).applied.corrected_dps)


def test_a_warm_restart_starts_the_node_later(calibration):
    log = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=2.0, seed=1)).log(calibration)
    # The table rests from 60 s to the first step; 30 s in, a restart still has 30 s of rest for its bias.
    warm = restart(log, 30.0)
    assert warm.t[0] == 30.0 and len(warm) == len(log) - 60
    done = replay(warm, calibration, 40)
    np.testing.assert_array_equal(done.applied.corrected_dps, apply_calibration(warm, calibration, 40).corrected_dps)
    # The bias is taken over the restarted run's first rows, not the log's.
    assert done.applied.bias.static_bias_drift_dps == pytest.approx(np.mean(log.rate_dps[60:100]))
    # A restart while the table turns is refused, as the node refuses it.
    turning = int(np.flatnonzero(log.ref_rate != 0.0)[0])
    with pytest.raises(MotionError, match='turning|moving'):
        replay(restart(log, log.t[turning] - log.t[0]), calibration, 40)
    with pytest.raises(ValueError, match='not within'):
        restart(log, 1e6)


def test_fit_validate_replays_and_a_supply_term_is_never_written(calibration, tmp_path):
    # The fitted run's supply voltage moves the gyro's reading. The second run's column reads another
    # rail, swinging by +-2 V, that does not reach the gyro: the supply term the loop finds makes it worse.
    _simulated(calibration, tmp_path / 'A.csv', 4, ('shupe', 'supply_voltage'))
    second = simulate_run(calibration, SimulationSettings(hours=2.0, rate_hz=2.0, seed=5, effects=('shupe',)))
    t = second.columns['t']
    write_columns(tmp_path / 'B.csv', {**second.columns, 'supply_v': 24.0 + 2.0 * np.sin(2 * np.pi * t / 1800.0)})
    out, report_path = tmp_path / 'CAL.yaml', tmp_path / 'REPORT.json'
    assert main(['fit', str(tmp_path / 'A.csv'), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--out', str(out), '--report', str(report_path), '--validate', str(tmp_path / 'B.csv')]) == 0
    report = json.loads(report_path.read_text())
    # The supply term is a finding, never written (the node has no supply_v): the
    # validation run has nothing of it to drop, and the Shupe term kept makes it better than the report's alone.
    assert 'temperature_rate' in {e['signal'] for e in report['effects']}
    assert 'supply_v' in {f['signal'] for f in report['findings_not_written']}
    validation = report['validation']
    assert validation['dropped'] == []
    written = [t.signal for t in load_calibration(out).terms]
    assert 'temperature_rate' in written and 'supply_v' not in written
    assert report['written'] == {'calibration': str(out), 'terms': written}
    [run] = validation['runs']
    assert run['source'] == str(tmp_path / 'B.csv')
    errors = run['calibrations']
    assert set(errors) == {'art', 'extended'}
    for e in errors.values():
        assert set(e) == {'mean_bias_dps', 'mean_bias_dph', 'systematic_rms_dps', 'systematic_rms_dph',
                          'heading_10min_deg', 'heading_1h_deg', 'bias_refused'}
        assert e['bias_refused'] is False
    assert errors['extended']['systematic_rms_dph'] < errors['art']['systematic_rms_dph']
    assert '## Field replay on other runs' in (tmp_path / 'REPORT.md').read_text()


def test_replay_command(calibration, tmp_path, capsys):
    log = tmp_path / 'B.csv'
    _simulated(calibration, log, 5, ('shupe',), hours=1.5)
    assert main(['replay', str(log), '--calibration', str(REPO / 'config' / 'NAVC4058.yaml')]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith('| run | calibration | mean bias (deg/h)')
    assert [row.split('|')[2].strip() for row in table[2:]] == ['art', 'extended']
    assert main(['replay', str(log), '--calibration', str(REPO / 'config' / 'NAVC4058.yaml'),
                 '--start-s', '300']) == 1
    assert 'turning' in capsys.readouterr().err


def test_own_restarts_begin_where_the_table_stands_still():
    t, ref = _table(hours=2.0)
    log = GyroLog(t, ref + 0.01, np.full(t.size, 25.0), ref)
    # A quarter and a half of the log fall in rests of 5 minutes (1560-1860 s, 3360-3660 s).
    restarts = own_restarts(log, 100)
    assert [start for start, _ in restarts] == [1800.0, 3600.0]
    for start, run in restarts:
        assert run.t[0] == start and np.all(run.ref_rate[:100] == 0.0) and len(run) == t.size - start * 10
    # 100 s of bias do not fit in what is left of those rests: the next rests, after a turn.
    assert [start for start, _ in own_restarts(log, 1000)] == [2160.0, 3960.0]
    # A run whose table never stands still long enough has no restart.
    assert own_restarts(log, 3001) == []


def _wandering_settings(hours, seed, effects=()):
    """A run as the loop study simulates it: 10 Hz, a slow bias wander (1 h) and a rate random walk."""
    return SimulationSettings(hours=hours, rate_hz=10.0, seed=seed, wander_dps=3e-4, wander_tau_s=3600.0,
                              rate_random_walk_dph_rthr=0.5, effects=effects)


def _wandering(calibration, hours, seed, effects=()):
    """:func:`_wandering_settings` simulated from power-on."""
    return simulate_run(calibration, _wandering_settings(hours, seed, effects))


def test_a_lag_fitted_to_noise_is_dropped_by_restarts_of_its_own_log(tmp_path):
    # Run 1397 of the loop study's null runs: no effect, but the loop fits a 90-minute coil lag to the
    # slow wander. From power-on it fits; a node restarted later starts its lag at the temperature of the
    # moment, and the term shifts the static bias (a warm restart lost 12.6 deg/h with it).
    truth = load_packaged_calibration('NAVC3545')
    run = _wandering(truth, 6.0, 1397)
    log = run.log(truth)
    result = close_loop(log, truth.polynomial.rows, truth.polynomial.columns,
                        LoopOptions(serial_number='NAVC3545', rate_scale_factor=truth.rate_scale_factor, seed=1397))
    assert [e.signal for e in result.effects] == ['temperature_lag']
    checked, check, names = startup_check(result, log)
    # The log began at power-on, at rest: the node started cold on it is judged too.
    assert names == ["from the log's power-on", 'restarted at 90 min', 'restarted at 182 min']
    [dropped] = check.dropped
    assert dropped.term.signal == 'temperature_lag'
    assert dropped.reason.startswith("the fitted log's cold start and restarts are better without it")
    assert checked.effects == () and checked.extended.terms == ()
    art, extended = (field_score_dps([run[name] for run in check.runs]) for name in ('art', 'extended'))
    assert extended > 2.0 * art
    # The check drops a term only when the restarts are better without it by more than the materiality (the
    # residual's Allan floor as calibrate allan fits it: 0.83 deg/h as the least measured value):
    # asked for more than the 9.8 deg/h it costs, the same replay keeps it.
    assert 'a drop needs more than 0.76 deg/h' in dropped.reason
    runs = [run for _, run in own_restarts(log)]
    assert validate(result, runs, kept_signals=(POWER_ON_SIGNAL,), margin_dps=9.0 / 3600.0).dropped
    assert not validate(result, runs, kept_signals=(POWER_ON_SIGNAL,), margin_dps=10.0 / 3600.0).dropped
    # calibrate fit reports the loop's term, and the check's drop, and writes the calibration without it.
    write_run(tmp_path / 'A.csv', run)
    out, report_path = tmp_path / 'CAL.yaml', tmp_path / 'REPORT.json'
    assert main(['fit', str(tmp_path / 'A.csv'), '--rows', '3', '--columns', '4', '--serial', 'NAVC3545',
                 '--seed', '1397', '--out', str(out), '--report', str(report_path)]) == 0
    report = json.loads(report_path.read_text())
    assert [e['signal'] for e in report['effects']] == ['temperature_lag']
    assert [d['signal'] for d in report['startup_check']['dropped']] == ['temperature_lag']
    # Asked again without the lag, the loop finds nothing better by more than chance on the log's starts.
    retraced = report['retraced']
    assert retraced['without'] == ['temperature_lag'] and retraced['kept'] == 'first'
    assert not retraced['second_dph'] + 0.5 < retraced['first_dph']
    assert load_calibration(out).terms == ()
    assert ("nothing (temperature_lag dropped: the fitted log's cold start and restarts were better without)"
            in out.read_text())
    assert 'Dropped from the written calibration' in (tmp_path / 'REPORT.md').read_text()
    # REPORT.json lists the loop's effects (the lag among them): what the file holds is said apart.
    assert json.loads(report_path.read_text())['written'] == {'calibration': str(out), 'terms': []}
    summary = (tmp_path / 'REPORT.md').read_text()
    # The packaged polynomial is the simulator's truth: the refit is not better held out, the baseline's is kept.
    assert f'Written: {out}, the baseline\'s polynomial with no term beyond it.' in summary


def test_one_physical_term_beats_the_correlated_terms_that_stand_in_for_it():
    # Shupe on the true temperature rate (0.6 deg/s per degC/s), the gyro heating itself 4 degC over 25 min
    # from power-on. On the first-order filter's rise from 0 at power-on (old files') the loop explained it with
    # a temperature rate of the wrong sign (-1.35), an 89 s coil lag of eight coefficients and a 30 s warm-up;
    # reading the rate at the start as the node's refinement does, it finds the one term on either filter.
    truth = load_packaged_calibration('NAVC3545')
    run = simulate_run(truth, SimulationSettings(hours=6.0, rate_hz=10.0, seed=2, effects=('shupe_true_rate',),
                                                 effect_sizes={'shupe_true_rate': 0.6}, ramp_c_per_min=0.5,
                                                 self_heating_c=4.0, self_heating_tau_s=1500.0))
    log = run.log(truth)
    options = LoopOptions(serial_number='NAVC3545', rate_scale_factor=truth.rate_scale_factor, seed=2)
    for filters in (SignalFilters(), SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER)):
        result = close_loop(log, 3, 4, replace(options, filters=filters))
        [term] = result.extended.terms
        assert term.signal == 'temperature_rate' and term.coefficients[0] == pytest.approx(0.6, abs=0.05)
    # Those three, fitted jointly, still fit the log about as well (the temperature rate now -0.39): the
    # start-up check writes the temperature rate alone, refitted, at its size.
    lag = Term('temperature_lag', 'power', (0.0,) * 8, (1, 2), 89.0, (0, 1, 2, 3))
    warm_up = Term(POWER_ON_SIGNAL, 'exp_decay', (0.0,), (), 30.0)
    stand_ins = replace(result, extended=_refit(result, [term, lag, warm_up]))
    assert stand_ins.extended.terms[0].coefficients[0] < 0.0
    checked, check, names = startup_check(stand_ins, log)
    assert names[0] == "from the log's power-on"
    [term] = checked.extended.terms
    assert term.signal == 'temperature_rate' and term.coefficients[0] == pytest.approx(0.6, abs=0.05)
    assert {d.term.signal for d in check.dropped} == {'temperature_lag', POWER_ON_SIGNAL}
    scores = {name: field_score_dps([r[name] for r in check.runs]) for name in ('art', 'extended', 'validated')}
    assert scores['validated'] < scores['extended']


def test_a_warm_up_the_cold_start_needs_is_kept_beside_the_temperature_rate():
    # Shupe (0.6 on the true temperature rate) and a 9 deg/h warm-up of 20 min, the gyro heating itself 2 degC
    # over 10 min: the loop finds both. Pooled over the cold start and two restarts (where a warm-up is not
    # applied) the temperature rate alone scored within the loop's materiality (2.37 deg/h, what the polynomial
    # alone left) and was written: a cold second run then carried 7.0 deg/h, against 2.6 with both terms.
    truth = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(hours=6.0, rate_hz=10.0, seed=320001, wander_dps=3e-4, wander_tau_s=3600.0,
                                  rate_random_walk_dph_rthr=0.5, effects=('shupe_true_rate', 'warmup'),
                                  effect_sizes={'shupe_true_rate': 0.6, 'warmup': 9.0 / 3600.0}, ramp_c_per_min=0.5,
                                  self_heating_c=2.0, self_heating_tau_s=600.0)
    log = simulate_run(truth, settings).log(truth)
    result = close_loop(log, 3, 4, LoopOptions(serial_number='NAVC3545', rate_scale_factor=truth.rate_scale_factor,
                                               seed=320001))
    assert [t.signal for t in result.extended.terms] == ['temperature_rate', POWER_ON_SIGNAL]
    checked, check, _ = startup_check(result, log)
    assert [t.signal for t in checked.extended.terms] == ['temperature_rate', POWER_ON_SIGNAL]
    assert check.dropped == ()
    # Weighed against the noise the terms leave (1.52 deg/h), the cold start's 2.49 deg/h tells them apart.
    assert result.residual_materiality_dph < result.materiality_dph


def _lab_protocol(truth, seed: int) -> list[tuple[str, GyroLog, bool]]:
    """Two cold starts (3 h) and a warm restart (2 h) of a Shupe gyro: (name, log, began at power-on) each.

    Shupe 1.0 on the true temperature rate, 4 degC of self-heating in 15 min, 0.3 degC/min ramps, 1.5 deg/h of wander.
    """
    def gyro(seed: int, hours: float) -> SimulationSettings:
        return SimulationSettings(hours=hours, rate_hz=10.0, seed=seed, wander_dps=1.5 / 3600.0, wander_tau_s=3600.0,
                                  rate_random_walk_dph_rthr=0.5, effects=('shupe_true_rate',),
                                  effect_sizes={'shupe_true_rate': 1.0}, ramp_c_per_min=0.3, self_heating_c=4.0,
                                  self_heating_tau_s=900.0)
    return [('cold1', simulate_run(truth, gyro(seed, 3.0)).log(truth), True),
            ('cold2', simulate_run(truth, gyro(seed + 1, 3.0)).log(truth), True),
            ('warm', warm_restart(truth, gyro(seed + 2, 2.0), 3 * 3600.0).log(truth), False)]


def test_a_warm_up_that_harms_the_cold_starts_is_dropped_though_the_restarts_outnumber_them():
    # A 30 s warm-up like those a loop once fitted beside the temperature rate to the filter's rise at power-on
    # (there 0.0036 deg/s): the node's refined static bias never sees that rise, so the warm-up moves the cold
    # starts' bias. Pooled with the warm start and the six restarts, where a warm-up is not applied, the runs are
    # better without it by less than the materiality.
    truth = load_packaged_calibration('NAVC3545')
    logs = _lab_protocol(truth, 5)
    log, fit_runs = joined(logs)
    result = close_loop(log, 3, 4, LoopOptions(serial_number='NAVC3545', rate_scale_factor=truth.rate_scale_factor,
                                               seed=5), fit_runs)
    warm_up = Term(POWER_ON_SIGNAL, 'exp_decay', (0.0018,), (), 30.0)
    others = tuple(t for t in result.extended.terms if t.signal != POWER_ON_SIGNAL)
    harmed = replace(result, extended=replace(result.extended, terms=(*others, warm_up)))
    runs = [(log, RunStart(powered_on_at_start=cold)) for _, log, cold in logs] + \
        [(later, RunStart()) for _, log, _ in logs for _, later in own_restarts(log, 100)]
    margin = result.materiality_dph / 3600.0
    check = validate(harmed, [log for log, _ in runs], start=[how for _, how in runs], margin_dps=margin)
    [drop] = check.dropped
    assert drop.term == warm_up and 'better without it on their cold starts' in drop.reason
    cold = [run for run, (_, how) in zip(check.runs, runs) if how.powered_on_at_start]
    assert len(cold) == 2 and len(check.runs) == 9
    assert field_score_dps([r['validated'] for r in cold]) + margin < field_score_dps([r['extended'] for r in cold])
    assert field_score_dps([r['extended'] for r in check.runs]) - margin < \
        field_score_dps([r['validated'] for r in check.runs])


def test_the_fit_reads_the_temperature_rate_at_a_run_s_start_as_the_node_s_refinement_does():
    # Fitted on the causal filter's rise from 0 over the first minute of each cold start, the Shupe error of the
    # self-heating there looked like a 30 s warm-up of 0.0036 deg/s, with a 90 s lag beside it and the temperature
    # rate at 0.77 for 1.0. The node's refined static bias takes the rate at its window from a polynomial over
    # the first 6 min, so the fit now reads that slope there.
    truth = load_packaged_calibration('NAVC3545')
    log, runs = joined(_lab_protocol(truth, 5))
    result = close_loop(log, 3, 4, LoopOptions(serial_number='NAVC3545', rate_scale_factor=truth.rate_scale_factor,
                                               seed=5), runs)
    assert all(abs(t.coefficients[0]) < 0.001 for t in result.extended.terms if t.signal == POWER_ON_SIGNAL)
    checked, _, _ = startup_check(result, log)
    [rate] = checked.extended.terms
    assert rate.signal == 'temperature_rate' and rate.coefficients[0] == pytest.approx(1.0, abs=0.05)


def test_a_start_up_check_keeps_what_the_restarts_are_better_with(calibration, tmp_path):
    # A Shupe effect found on a 2 h run: the restarts of the run are better with its term, which stays.
    run = simulate_run(calibration, SimulationSettings(hours=2.0, rate_hz=10.0, seed=4, effects=('shupe',)))
    write_run(tmp_path / 'A.csv', run)
    report_path = tmp_path / 'REPORT.json'
    assert main(['fit', str(tmp_path / 'A.csv'), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(report_path)]) == 0
    report = json.loads(report_path.read_text())
    assert [e['signal'] for e in report['effects']] == ['temperature_rate']
    check = report['startup_check']
    assert check['dropped'] == []
    assert [r['source'] for r in check['runs']] == ["from the log's power-on", 'restarted at 31 min',
                                                    'restarted at 60 min']
    for r in check['runs']:
        assert r['calibrations']['extended']['systematic_rms_dph'] < r['calibrations']['art']['systematic_rms_dph']
    assert [t.signal for t in load_calibration(tmp_path / 'CAL.yaml').terms] == ['temperature_rate']
    assert '## Start-up check: the fitted log run from its power-on and restarted warm' in \
        (tmp_path / 'REPORT.md').read_text()


def test_a_warm_up_is_never_judged_by_restarts(calibration):
    log = _wandering(calibration, 2.0, 3, ('warmup',)).log(calibration)
    result = close_loop(log, calibration.polynomial.rows, calibration.polynomial.columns,
                        LoopOptions(serial_number='NAVC4058', rate_scale_factor=calibration.rate_scale_factor, seed=3))
    assert POWER_ON_SIGNAL in [e.signal for e in result.effects]
    # Restarted, power-on unknown, the warm-up is not applied: with or without it the runs read the same.
    runs = [run for _, run in own_restarts(log, 100)]
    others = replace(result.extended, terms=tuple(t for t in result.extended.terms if t.signal != POWER_ON_SIGNAL))
    for run in runs:
        np.testing.assert_array_equal(replay(run, result.extended, 100).applied.corrected_dps,
                                      replay(run, others, 100).applied.corrected_dps)
    checked = validate(result, runs, kept_signals=(POWER_ON_SIGNAL,))
    assert POWER_ON_SIGNAL in [t.signal for t in checked.calibration.terms]
    assert POWER_ON_SIGNAL not in [d.term.signal for d in checked.dropped] and len(checked.runs) == 2


def test_a_warm_up_fitted_to_the_bias_of_a_null_run_is_not_written(tmp_path, capsys):
    # Run 5098 of the loop study's null runs: no effect, but the bias starts high and the loop fits a warm-up to
    # it. Fitted on top of the packaged polynomial (the refit is not better held out) it was 4.2 deg/h at
    # power-on and was written, and made a cold second run worse (6.19 against 3.30 deg/h). On the log it is not
    # better than the baseline by the materiality: not written.
    truth = load_packaged_calibration('NAVC3545')
    write_run(tmp_path / 'A.csv', _wandering(truth, 2.0, 5098))
    assert main(['fit', str(tmp_path / 'A.csv'), '--rows', '3', '--columns', '4', '--serial', 'NAVC3545', '--seed',
                 '5098', '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    assert load_calibration(tmp_path / 'CAL.yaml').terms == ()
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    assert report['baseline']['verdict'] == 'baseline' and 'warnings' not in report
    assert f'the terms {POWER_ON_SIGNAL} fitted on top of it did not make it better by the materiality' \
        in report['baseline']['message']
    assert 'warning: the warm-up' not in capsys.readouterr().err


def test_fit_warns_of_a_warm_up_no_cold_run_judged(tmp_path, capsys):
    # A warm-up of the gyro (calibrate simulate's), fitted on one log from power-on: neither the log nor its
    # restarts can tell it from the bias wandering at the start of that run. calibrate fit says so, in stderr
    # and in the report, until a cold run judges it.
    truth = load_packaged_calibration('NAVC3545')
    write_run(tmp_path / 'A.csv', _wandering(truth, 2.0, 1, ('warmup',)))
    write_run(tmp_path / 'COLD.csv', _wandering(truth, 2.0, 1_000_001, ('warmup',)))
    args = ['fit', str(tmp_path / 'A.csv'), '--rows', '3', '--columns', '4', '--serial', 'NAVC3545', '--seed', '1',
            '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]
    assert main(args) == 0
    assert [t.signal for t in load_calibration(tmp_path / 'CAL.yaml').terms] == [POWER_ON_SIGNAL]
    [warning] = json.loads((tmp_path / 'REPORT.json').read_text())['warnings']
    assert warning.startswith("the warm-up term (70.8 deg/h at power-on; the log's bias instability is 2.86 deg/h) "
                              'was judged on this log alone')
    assert f'calibrate fit: warning: {warning}' in capsys.readouterr().err
    assert f'**Warning:** {warning}.' in (tmp_path / 'REPORT.md').read_text()
    # Judged on another cold run of the gyro, it makes that run better and is kept; judged, it is no longer warned of.
    assert main([*args, '--force', '--validate', str(tmp_path / 'COLD.csv'), '--validate-powered-on-at-start']) == 0
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    assert 'warnings' not in report and report['validation']['dropped'] == []
    assert [t.signal for t in load_calibration(tmp_path / 'CAL.yaml').terms] == [POWER_ON_SIGNAL]
    assert 'warning: the warm-up' not in capsys.readouterr().err
    # A warm run (a node restarted 3 h after power-on) does not judge it (the warm-up is not applied there).
    warm = warm_restart(truth, _wandering_settings(2.0, 1_000_002, ('warmup',)), 3 * 3600.0)
    write_run(tmp_path / 'WARM.csv', warm)
    assert main([*args, '--force', '--validate', str(tmp_path / 'WARM.csv')]) == 0
    assert json.loads((tmp_path / 'REPORT.json').read_text())['warnings'] == [warning]


def test_a_calibration_the_node_refuses_the_static_bias_with_scores_worst(calibration):
    log = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=2.0, seed=1)).log(calibration)
    # A term of 0.03 deg/s per degC (0.3 deg/s at 10 degC): the still gyro seems to turn, the node refuses the bias.
    wild = replace(calibration, terms=(Term('temperature', 'power', (0.03,), (1,)),))
    with pytest.raises(MotionError):
        replay(log, wild, 100)
    refused = replay_field(log, wild, 100)
    assert refused.bias_refused and refused.to_dict()['bias_refused'] is True
    assert not replay_field(log, calibration, 100).bias_refused
    assert field_score_dps([refused]) == np.inf


def test_a_gyro_too_noisy_for_the_nodes_motion_check_is_measured_not_refused(calibration):
    # 3 deg/sqrt(h) at 10 Hz: 0.16 deg/s per sample, past the node's default 0.05 deg/s spread (a MEMS gyro).
    run = simulate_run(calibration, SimulationSettings(hours=2.0, rate_hz=10.0, seed=2, arw_deg_rthr=3.0,
                                                       effects=('shupe',)))
    log = run.log(calibration)
    result = close_loop(log, calibration.polynomial.rows, calibration.polynomial.columns,
                        LoopOptions(serial_number='NAVC4058', rate_scale_factor=calibration.rate_scale_factor, seed=2))
    assert result.effects
    runs = [r for _, r in own_restarts(log, 100)]
    # --validate refuses such a run, naming it; the start-up check measures it with the checks off.
    with pytest.raises(MotionError, match=r'run 1 of 2: with the report\'s calibration alone: rate spread'):
        validate(result, runs)
    lenient = validate(result, runs, strict=False)
    assert not any(e.bias_refused for run in lenient.runs for e in run.values())
    checked, check, names = startup_check(result, log)
    assert check is not None and len(check.runs) == len(names) == 3
