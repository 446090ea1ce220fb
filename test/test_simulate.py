"""Simulated rate-table runs: the profile, the truth side file, the switchable effects."""

import json

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.log import read_log
from art_gyro_calibration.analysis.simulate import EFFECTS, SimulationSettings, simulate_run, truth_path, write_run


@pytest.fixture(scope='module')
def calibration():
    return load_packaged_calibration('NAVC3545')


def test_profile_covers_rates_and_temperatures(calibration):
    run = simulate_run(calibration, SimulationSettings(hours=2.0, rate_hz=2.0, seed=3))
    ref = run.columns['ref_rate']
    assert set(np.unique(ref)) >= {0.0, 100.0, -100.0, 1.0, -1.0}
    temp = run.columns['raw_temp'] * calibration.temp_scale_factor
    low, high = calibration.temperature_range_c
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
