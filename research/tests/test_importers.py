"""Importers on records built here: a still gyro handled twice, and a CATS-like NetCDF-4 file."""

import math

import numpy as np
import pytest

from art_gyro_calibration.log import read_log
from importers import (DEG_PER_MRAD, RecordError, StaticRecord, read_cats_netcdf, read_phone_netcdf, runs,
                       segment_labels, static_log, still_mask, write_static_log)

HOUR = 3600.0


def _handled_record(seed=0):
    """Six hours at 1 Hz, still but for two 5-minute handlings; bias follows temperature."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 6 * HOUR)
    temp = 15.0 + 8.0 * np.sin(2 * np.pi * t / (6 * HOUR))
    gx = 0.5 + 0.02 * (temp - 15.0) + rng.normal(0.0, 0.05, t.size)
    gy = rng.normal(0.0, 0.05, t.size)
    acc_z = -9.81 + rng.normal(0.0, 0.02, t.size)
    moving = np.zeros(t.size, dtype=bool)
    for start in (2 * HOUR, 4 * HOUR):
        moving[int(start):int(start + 300)] = True
    gx[moving] += rng.normal(0.0, 20.0, moving.sum())
    acc_z[moving] += rng.normal(0.0, 3.0, moving.sum())
    record = StaticRecord(t, temp, {'gyro_x': gx, 'gyro_y': gy, 'acc_z': acc_z}, 'synthetic')
    return record, moving


def test_still_mask_finds_the_still_runs_and_drops_the_handling():
    record, moving = _handled_record()
    still = still_mask(record.t, [record.channels['gyro_x'], record.channels['acc_z']],
                       window_s=60.0, margin_s=120.0, min_still_s=1800.0)
    assert not np.any(still & moving)
    found = runs(still)
    assert len(found) == 3
    # Each handling costs itself, the half window and the margin on both sides, no more.
    lost = np.count_nonzero(~still) - np.count_nonzero(moving)
    assert 0 < lost <= 2 * 2 * (120 + 31)
    # A still stretch shorter than min_still_s is dropped.
    assert len(runs(still_mask(record.t, [record.channels['gyro_x']], min_still_s=2.5 * HOUR))) == 0


def test_static_log_takes_one_axis_with_zero_reference_and_the_rest_as_extras(tmp_path):
    record, moving = _handled_record()
    still = ~moving
    log = static_log(record, 'gyro_x', still)
    assert len(log) == still.sum()
    assert np.array_equal(log.rate_dps, record.channels['gyro_x'][still])
    assert np.array_equal(log.ref_rate, np.zeros(len(log)))
    assert sorted(log.extras) == ['acc_z', 'gyro_y']
    assert list(np.unique(segment_labels(log.t, gap_s=10.0))) == [0, 1, 2]
    path = tmp_path / 'static.csv'
    write_static_log(path, log)
    back = read_log(path)
    assert np.allclose(back.rate_dps, log.rate_dps, rtol=1e-8)
    assert np.allclose(back.temp_c, log.temp_c, rtol=1e-8)
    assert np.array_equal(back.ref_rate, log.ref_rate)
    assert sorted(back.extras) == ['acc_z', 'gyro_y']
    assert path.read_text().splitlines()[0] == 't,rate_dps,temp_c,ref_rate,gyro_y,acc_z'


def test_refusals_say_what():
    record, _ = _handled_record()
    with pytest.raises(RecordError, match="no channel 'gyro_q'"):
        static_log(record, 'gyro_q')
    with pytest.raises(RecordError, match='no still samples'):
        static_log(record, 'gyro_x', np.zeros(len(record.t), dtype=bool))
    with pytest.raises(RecordError, match='increasing'):
        StaticRecord(np.array([0.0, 2.0, 1.0]), np.zeros(3), {})
    with pytest.raises(RecordError, match="'acc' has 2 samples"):
        StaticRecord(np.arange(3.0), np.zeros(3), {'acc': np.zeros(2)})
    with pytest.raises(RecordError, match="'temperature_rate'"):
        StaticRecord(np.arange(3.0), np.zeros(3), {'temperature_rate': np.zeros(3)})
    bad = record.channels['gyro_x'].copy()
    bad[7] = np.nan
    with pytest.raises(RecordError, match='rate is not a finite number at still sample 7'):
        static_log(StaticRecord(record.t, record.temp_c, {'gyro_x': bad}), 'gyro_x')


def _write_cats(path, n=100, units=b'mrad/s'):
    import h5py
    rng = np.random.default_rng(4)
    with h5py.File(path, 'w') as f:
        f['timestamp_utc'] = np.arange(n, dtype=np.int64)
        f['temperature'] = np.linspace(5.0, 25.0, n)
        f['depth'] = np.full(n, 4.5)
        for name in ('angular_velocity', 'acceleration', 'magnetic_density'):
            f[name] = rng.normal(size=(n, 3))
        f['angular_velocity'].attrs['units'] = units
    with h5py.File(path, 'r') as f:
        return f['angular_velocity'][...]


def test_read_cats_netcdf_converts_mrad_per_s_and_names_channels(tmp_path):
    path = tmp_path / 'cats.nc'
    omega = _write_cats(path)
    record = read_cats_netcdf(path)
    assert sorted(record.channels) == sorted(
        [f'{p}_{a}' for p in ('gyro', 'acc', 'mag') for a in 'xyz'] + ['depth'])
    assert np.allclose(record.channels['gyro_y'], omega[:, 1] * 180.0 / (1000.0 * math.pi))
    assert DEG_PER_MRAD == pytest.approx(0.0572958, rel=1e-6)
    assert record.t[-1] == 99.0 and record.temp_c[0] == 5.0
    log = static_log(record, 'gyro_z')
    assert 'gyro_z' not in log.extras and 'gyro_x' in log.extras


def test_read_cats_netcdf_refuses_other_files(tmp_path):
    path = tmp_path / 'cats.nc'
    _write_cats(path, units=b'rpm')
    with pytest.raises(RecordError, match="in 'rpm', expected one of mrad/s, rad/s, deg/s"):
        read_cats_netcdf(path)
    text = tmp_path / 'not.nc'
    text.write_text('t,rate\n')
    with pytest.raises(RecordError, match='cannot read as NetCDF-4/HDF5'):
        read_cats_netcdf(text)


def _write_phone(path, n=50, hz=10, kinds=(b'output',) * 3 + (b'measured',) * 3, step=1):
    import h5py
    rng = np.random.default_rng(5)
    omega = rng.normal(size=(n, 6))
    with h5py.File(path, 'w') as f:
        f['timestamp'] = np.arange(0, n * step, step, dtype=np.int64)
        f['gyroscope_type'] = np.array(kinds, dtype=object)
        f['angular_velocity'] = omega
        f['angular_velocity'].attrs['units'] = b'rad/s'
        if hz:
            f['angular_velocity'].attrs['sampling_rate'] = np.array([hz])
        f['acceleration'] = rng.normal(size=(n, 3))
        f['magnetic_density'] = rng.normal(size=(n, 6))
    return omega


def test_read_phone_netcdf_takes_both_gyro_streams_and_counts_time(tmp_path):
    path = tmp_path / 'phone.nc'
    omega = _write_phone(path)
    record = read_phone_netcdf(path)
    assert np.allclose(record.t, np.arange(50) / 10.0)
    assert np.all(np.isnan(record.temp_c))  # a phone logs no temperature
    assert np.allclose(record.channels['gyro_z'], np.degrees(omega[:, 2]))
    assert np.allclose(record.channels['gyro_measured_x'], np.degrees(omega[:, 3]))
    assert {'acc_x', 'mag_z'} <= set(record.channels) and 'mag_measured_x' not in record.channels


@pytest.mark.parametrize('change, message', [
    (dict(kinds=(b'measured',) * 3 + (b'output',) * 3), 'three output then three measured'),
    (dict(hz=0), 'no positive sampling_rate'),
    (dict(step=2), 'does not count samples one by one'),
])
def test_read_phone_netcdf_refuses_what_it_cannot_read(tmp_path, change, message):
    path = tmp_path / 'phone.nc'
    _write_phone(path, **change)
    with pytest.raises(RecordError, match=message):
        read_phone_netcdf(path)


def test_a_record_without_temperature_needs_a_stand_in_said_out_loud():
    t = np.arange(100.0)
    record = StaticRecord(t, np.full(100, np.nan), {'gyro_x': np.full(100, 0.3)}, 'phone')
    with pytest.raises(RecordError, match='temperature is not a finite number at still sample 0'):
        static_log(record, 'gyro_x')
    log = static_log(record, 'gyro_x', temperature_c=20.0)
    assert np.all(log.temp_c == 20.0) and np.all(log.rate_dps == 0.3)
    warm = StaticRecord(t, np.full(100, 25.0), {'gyro_x': np.zeros(100)}, 'tag')
    with pytest.raises(RecordError, match='has a temperature; a stand-in of 20.0 degC would replace it'):
        static_log(warm, 'gyro_x', temperature_c=20.0)
