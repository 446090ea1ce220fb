"""Simulated rate-table runs: the profile, the truth side file, the switchable effects."""

import json
from dataclasses import replace

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.log import read_log
from art_gyro_calibration.analysis.simulate import (COIL_LAG_TAU_S, EFFECTS, WIDER_EFFECTS, SimulationSettings,
                                                    chamber_profile, lagged, same_gyro, simulate_run, truth_path,
                                                    warm_restart, write_run)
from art_gyro_calibration.signals import FIRST_ORDER_TAU_S, SignalFilters, compute_signals
from art_gyro_calibration.temperature_rate import FIRST_ORDER


@pytest.fixture(scope='module')
def calibration():
    return load_packaged_calibration('NAVC3545')


def test_profile_covers_rates_and_temperatures(calibration):
    run = simulate_run(calibration, SimulationSettings(hours=2.0, rate_hz=2.0, seed=3))
    ref = run.columns['ref_rate']
    assert set(np.unique(ref)) >= {0.0, 100.0, -100.0, 1.0, -1.0}
    temp = run.columns['raw_temp'] * calibration.temp_scale_factor
    low, high = calibration.expected_range_c
    assert temp.min() == pytest.approx(low, abs=0.1)
    assert temp.max() > high - 2.0
    # The gyro starts at rest long enough for a static bias.
    assert np.all(ref[:120] == 0.0)
    # The chamber ramps at a rate a chamber can do (1 degC/min, thermal lag on top).
    assert np.max(np.abs(np.diff(temp))) * 2.0 * 60.0 < 1.5 + 0.05 * 2 * 60


def test_each_step_is_whole_turns(calibration):
    settings = SimulationSettings(hours=1.0, rate_hz=50.0, seed=1)
    run = simulate_run(calibration, settings)
    ref = run.columns['ref_rate']
    change = np.flatnonzero(np.diff(ref) != 0) + 1
    for a, b in zip(change[:-1], change[1:]):
        if ref[a] != 0.0:
            turns = abs(ref[a]) * (b - a) / settings.rate_hz / 360.0
            assert turns == pytest.approx(round(turns), abs=0.02)


def test_effects_change_the_reading_and_are_recorded_only_in_the_truth(calibration, tmp_path):
    base = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=1.0, seed=5))
    for name in EFFECTS:
        run = simulate_run(calibration, SimulationSettings(hours=1.0, rate_hz=1.0, seed=5, effects=(name,)))
        assert not np.array_equal(run.columns['raw_rate'], base.columns['raw_rate'])
        assert list(run.truth['effects']) == [name]
    path = tmp_path / 'LOG.csv'
    side = write_run(path, run)
    assert side == truth_path(path) and side.name == 'LOG.truth.json'
    truth = json.loads(side.read_text())
    assert truth['serial_number'] == 'NAVC3545'
    log = read_log(path, calibration.rate_scale_factor, calibration.temp_scale_factor)
    assert set(log.extras) == {'supply_v'}
    counts = log.rate_dps / calibration.rate_scale_factor
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)  # quantised to counts


def test_unknown_effect_is_refused():
    with pytest.raises(ValueError, match='unknown effect'):
        SimulationSettings(effects=('magnetism',))


def _difference_dps(calibration, settings, **changes):
    """Reading with ``changes`` less the reading without, same seed (deg/s, within one count)."""
    base = simulate_run(calibration, settings)
    run = simulate_run(calibration, replace(settings, **changes))
    return run, (run.columns['raw_rate'] - base.columns['raw_rate']) * calibration.rate_scale_factor


def _size(difference, basis):
    """Least-squares size of ``basis`` in ``difference``."""
    return float(basis @ difference / (basis @ basis))


@pytest.mark.parametrize('effect', sorted(WIDER_EFFECTS))
def test_each_wider_effect_is_recovered_from_its_truth(calibration, effect):
    settings = SimulationSettings(hours=6.0, rate_hz=1.0, seed=2)
    run, diff = _difference_dps(calibration, settings, effects=(effect,))
    truth = run.truth['effects'][effect]
    c = run.columns
    signals = compute_signals(c['t'], c['ref_rate'], c['raw_temp'] * calibration.temp_scale_factor)
    low, high = calibration.expected_range_c
    u = (signals.temperature - 0.5 * (low + high)) / (0.5 * (high - low))
    poly = calibration.polynomial
    basis = {
        'coil_lag': poly.error(c['ref_rate'], lagged(signals.t, signals.temperature, COIL_LAG_TAU_S))
        - poly.error(c['ref_rate'], signals.temperature),
        'rate_t3': signals.rate * u ** 3,
        'rate_temperature_rate': signals.rate * signals.temperature_rate,
        'drift': signals.time,
        'shupe_true_rate': np.gradient(chamber_profile(c['t'], settings, (low, high)), c['t']),
    }[effect]
    want = truth['fraction'] if effect == 'coil_lag' else truth['coefficients'][0]
    assert want == WIDER_EFFECTS[effect]
    assert _size(diff, basis) == pytest.approx(want, rel=0.05)
    # The effect matters: well above a count over the run.
    assert np.sqrt(np.mean((want * basis) ** 2)) > 0.002


def test_effect_sizes_scale_a_wider_effect(calibration):
    settings = SimulationSettings(hours=2.0, rate_hz=1.0, seed=2, effects=('rate_t3',))
    full = simulate_run(calibration, settings)
    quarter, diff = _difference_dps(calibration, settings, effect_sizes={'rate_t3': 0.25 * WIDER_EFFECTS['rate_t3']})
    _, whole = _difference_dps(calibration, replace(settings, effects=()), effects=('rate_t3',))
    assert full.truth['effects']['rate_t3']['coefficients'] == [WIDER_EFFECTS['rate_t3']]
    assert quarter.truth['effects']['rate_t3']['coefficients'] == [0.25 * WIDER_EFFECTS['rate_t3']]
    assert _size(diff, whole) == pytest.approx(-0.75, abs=0.03)  # a quarter of it is left


def test_bias_wander_and_rate_random_walk(calibration):
    settings = SimulationSettings(hours=24.0, rate_hz=0.5, seed=9)
    # Large beside the counts' quantisation (0.003 deg/s), short beside the run: its stationary spread.
    _, wander = _difference_dps(calibration, settings, wander_dps=0.02, wander_tau_s=120.0)
    assert np.std(wander) == pytest.approx(0.02, rel=0.1)
    _, walk = _difference_dps(calibration, settings, rate_random_walk_dph_rthr=30.0)
    # A random walk of 30 deg/h/sqrt(h) spreads by 30 * sqrt(hours) deg/h: the increments over an hour.
    rows = int(3600 * settings.rate_hz)
    steps = (walk[rows:] - walk[:-rows])[::rows] * 3600.0
    assert np.std(steps) == pytest.approx(30.0, rel=0.35)
    # Off by default, and then the run is the same as before they existed.
    assert SimulationSettings().wander_dps == 0.0 and SimulationSettings().rate_random_walk_dph_rthr == 0.0


def test_a_second_run_of_the_same_gyro(calibration):
    settings = SimulationSettings(hours=1.0, rate_hz=1.0, seed=3, effects=('shupe',))
    first, second = simulate_run(calibration, settings), simulate_run(calibration, same_gyro(settings, 4))
    assert first.truth['effects'] == second.truth['effects']
    assert first.truth['polynomial'] == second.truth['polynomial']
    assert first.truth['turn_on_bias_dps'] != second.truth['turn_on_bias_dps']


def test_a_warm_restart_is_a_slice_of_a_long_run_at_another_heading(calibration):
    settings = SimulationSettings(hours=1.0, rate_hz=2.0, seed=6, effects=('warmup',))
    warm = warm_restart(calibration, settings, 3 * 3600.0, heading_deg=90.0)
    c = warm.columns
    assert len(c['t']) == 2 * 3600
    assert 3 * 3600.0 <= warm.truth['start_s'] == c['t'][0] < 3 * 3600.0 + 600.0
    assert warm.truth['powered_on_at_start'] is False
    # The table rests for the static bias, after turning by 90 degrees from its whole turns.
    assert np.all(c['ref_rate'][:int(settings.initial_rest_s * settings.rate_hz)] == 0.0)
    assert warm.truth['heading_at_start_deg'] == 90.0
    # The same gyro as the long run it is cut from: its first samples are the long run's.
    long = simulate_run(calibration, replace(settings, hours=warm.truth['settings']['hours'],
                                             restarts_s=(3 * 3600.0,), restart_turn_deg=90.0))
    row = int(np.searchsorted(long.columns['t'], c['t'][0]))
    np.testing.assert_array_equal(long.columns['raw_rate'][row:row + 100], c['raw_rate'][:100])
    turn = long.columns['ref_rate'][row - 40:row]
    assert np.sum(turn) / settings.rate_hz == pytest.approx(90.0, abs=10.0 / settings.rate_hz)
    # Warm: the warm-up decayed hours ago.
    assert warm.truth['effects']['warmup']['time_constant_s'] * 5 < c['t'][0]


def test_self_heating_warms_the_gyro_above_the_chamber_from_power_on(calibration, tmp_path):
    dt_c, tau = 4.0, 600.0
    settings = SimulationSettings(hours=1.0, rate_hz=10.0, seed=7, self_heating_c=dt_c, self_heating_tau_s=tau)
    run = simulate_run(calibration, settings)
    t = run.columns['t']
    low, high = calibration.expected_range_c
    # The chamber's top set point is lowered by the self-heating: the warm gyro stays in the calibrated range.
    chamber = chamber_profile(t, settings, (low, high - dt_c))
    above = run.columns['raw_temp'] * calibration.temp_scale_factor - chamber
    quantum = calibration.temp_scale_factor / 2 + 1e-9
    for time_s, want in ((0.0, 0.0), (tau, dt_c * (1 - np.exp(-1.0))), (3 * tau, dt_c * (1 - np.exp(-3.0)))):
        row = int(np.searchsorted(t, time_s))
        assert above[row] == pytest.approx(want, abs=quantum)
    assert run.truth['self_heating'] == {'c': dt_c, 'time_constant_s': tau, 'chamber_range_c': [low, high - dt_c]}
    # Off by default, and then the run (log and truth) is what it was before the option existed.
    default = SimulationSettings(hours=0.2, rate_hz=2.0, seed=7)
    assert default.self_heating_c == 0.0
    plain = simulate_run(calibration, default)
    assert 'self_heating' not in plain.truth and 'self_heating_c' not in plain.truth['settings']
    other_tau = simulate_run(calibration, replace(default, self_heating_tau_s=60.0))
    for k, v in plain.columns.items():
        np.testing.assert_array_equal(v, other_tau.columns[k])


@pytest.mark.parametrize('changes, message', [({'self_heating_c': -1.0}, 'self_heating_c'),
                                              ({'self_heating_c': float('nan')}, 'self_heating_c'),
                                              ({'self_heating_tau_s': 0.0}, 'self_heating_tau_s')])
def test_a_bad_self_heating_is_refused(changes, message):
    with pytest.raises(ValueError, match=message):
        SimulationSettings(**changes)


def test_self_heating_as_wide_as_the_range_is_refused(calibration):
    low, high = calibration.expected_range_c
    with pytest.raises(ValueError, match='self_heating_c'):
        simulate_run(calibration, SimulationSettings(hours=0.1, self_heating_c=high - low))


def test_shupe_on_the_true_temperature_rate(calibration):
    # Large, so that a count (0.003 deg/s) is small beside it.
    k, dt_c, tau, lag = 24.0, 5.0, 600.0, 300.0
    settings = SimulationSettings(hours=1.5, rate_hz=10.0, seed=8, self_heating_c=dt_c, self_heating_tau_s=tau,
                                  thermal_lag_s=lag)
    run, diff = _difference_dps(calibration, settings, effects=('shupe_true_rate',),
                                effect_sizes={'shupe_true_rate': k})
    assert run.truth['effects']['shupe_true_rate']['coefficients'] == [k]
    assert run.truth['effects']['shupe_true_rate']['signal'] == 'true temperature rate'
    t = run.columns['t']
    # The chamber holds at the bottom for hold_s, then ramps at ramp_c_per_min, seen through the lag.
    ramp = settings.ramp_c_per_min / 60.0
    for time_s in (60.0, 300.0, 800.0, settings.hold_s + 600.0, settings.hold_s + 1500.0):
        row = int(np.searchsorted(t, time_s))
        chamber_rate = 0.0 if time_s < settings.hold_s else ramp * -np.expm1(-(time_s - settings.hold_s) / lag)
        want = k * (chamber_rate + dt_c / tau * np.exp(-time_s / tau))
        # Within a count and a half of the gyro's error in the polynomial's rate slope (ppm).
        assert diff[row] == pytest.approx(want, abs=2 * calibration.rate_scale_factor + 0.01 * abs(want))
    # Not a filtered rate: at the ramp's start the true rate leads the first-order filter's (old files').
    signals = compute_signals(t, run.columns['ref_rate'], run.columns['raw_temp'] * calibration.temp_scale_factor,
                              filters=SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER))
    row = int(np.searchsorted(t, settings.hold_s + 120.0))
    assert diff[row] > 1.5 * k * signals.temperature_rate[row]
