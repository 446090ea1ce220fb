"""The measured-data loop on a real record (fetched like the reproduction command) and its helpers offline."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

# The study is a script beside the package, not part of what a robot installs.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'studies'))
import measured_data as measured  # noqa: E402
from art_gyro_calibration.analysis.importers import (StaticRecord, read_cats_netcdf, static_log,  # noqa: E402
                                                     still_mask, write_static_log)
from art_gyro_calibration.analysis.loop import RATE_SIGNALS  # noqa: E402
from art_gyro_calibration.log import GyroLog, read_log  # noqa: E402

HOUR = 3600.0
DATA_DIR = Path(__file__).resolve().parent.parent / 'data'  # gitignored download cache


@pytest.fixture(scope='module')
def record_slice():
    """Hours 10 to 22 of the record: one orientation, warming from 5 to 16 degC."""
    try:
        path = measured.fetch_cats_record(DATA_DIR)
    except measured.DataUnavailable as e:
        pytest.skip(f'the measured record cannot be downloaded here: {e}')
    record = read_cats_netcdf(path)
    return record.slice((record.t >= 10 * HOUR) & (record.t < 22 * HOUR))


def test_import_of_the_real_record(record_slice, tmp_path):
    record = record_slice
    still = still_mask(record.t, [record.channels[c] for c in measured.MOTION_CHANNELS])
    assert still.all()  # nobody touched the tag in these hours
    log = static_log(record, 'gyro_x', still)
    # A MEMS gyro's turn-on bias: about 2 deg/s on x, read as 37 mrad/s in the file.
    assert 1.9 < np.median(log.rate_dps) < 2.2
    assert np.median(log.rate_dps) == pytest.approx(np.median(record.channels['gyro_x']))
    assert np.all(log.ref_rate == 0.0)
    assert 4.5 < log.temp_c.min() < log.temp_c.max() < 17.0
    assert {'gyro_y', 'gyro_z', 'acc_z', 'mag_x', 'depth'} <= set(log.extras)
    labels, names = measured.orientation_labels(log)
    assert names == ('acc_z down',) and np.all(labels == 0)
    path = tmp_path / 'gyro_x.csv'
    write_static_log(path, log.slice(slice(0, 2000)))
    back = read_log(path)
    assert np.allclose(back.rate_dps, log.rate_dps[:2000], rtol=1e-8)


def test_the_loop_on_the_real_record(record_slice, tmp_path):
    still = np.ones(len(record_slice.t), dtype=bool)
    results = []
    for axis in measured.AXES:
        log = static_log(record_slice, f'gyro_{axis}', still)
        results.append(measured.run_axis(log, log.t > 19 * HOUR, 'last 3 h', axis))
    y = results[1]
    assert (y.loop.art.polynomial.rows, y.loop.art.polynomial.columns) == (measured.ROWS, measured.COLUMNS)
    screened = {c.signal for r in results for found in r.loop.rounds for c in found.candidates}
    assert not screened & set(RATE_SIGNALS)  # a still gyro's rate is its error
    assert {'temperature', 'gyro_x', 'acc_z', 'depth'} <= screened
    # y follows temperature strongly: the polynomial fitted on 9 h must halve the held-out systematic error.
    assert y.summaries['art'].block_rms_dps < 0.6 * y.summaries['uncalibrated'].block_rms_dps
    for r in results:
        assert r.materiality == r.loop.materiality_dph > 0
        for stage in measured.STAGES:
            assert len(r.errors[stage]) == np.count_nonzero(r.held) > 2.9 * HOUR
            # White noise at 1 s of a MEMS gyro resampled to 1 Hz: about 0.1 deg/s.
            assert 0.05 < r.allan[stage].adev[0] < 0.2
    figures = {'record': 'record.png', 'allan': ['allan.png'],
               'temperature': measured.plot_temperature(results, tmp_path / 'temperature.png').name}
    for r in results:
        figures[r.axis] = [measured.plot_axis(r, tmp_path / f'{r.axis}.png').name]
    measured.plot_allan(results, tmp_path / 'allan.png')
    text = measured.markdown(record_slice, still, ('acc_z down',), [results], figures)
    assert '| last 3 h | ART polynomial (temperature powers) |' in text
    assert f'{y.summaries["art"].block_rms_dps:.4f}' in text
    written = ('x.png', 'y.png', 'z.png', 'allan.png', 'temperature.png')
    assert all((tmp_path / f).stat().st_size > 10_000 for f in written)


def test_fetch_says_why_it_cannot(tmp_path, monkeypatch):
    monkeypatch.setattr(measured.sys, 'executable', str(tmp_path / 'no-python'))
    with pytest.raises(measured.DataUnavailable, match='cannot run'):
        measured.fetch_cats_record(tmp_path / 'cache')


def _still_log(hours: float, down: tuple[int, ...]) -> GyroLog:
    """A still log at 1 Hz, one orientation per part (axis index that points down), parts 10 min apart."""
    parts = []
    for k, axis in enumerate(down):
        t = k * (hours + 1 / 6) * HOUR + np.arange(0.0, hours * HOUR)
        g = np.zeros((len(t), 3))
        g[:, axis] = -9.81
        parts.append((t, g))
    t = np.concatenate([p[0] for p in parts])
    g = np.concatenate([p[1] for p in parts])
    return GyroLog(t, np.zeros(len(t)), np.full(len(t), 20.0), np.zeros(len(t)),
                   {'acc_x': g[:, 0], 'acc_y': g[:, 1], 'acc_z': g[:, 2]})


def test_orientation_labels_count_orientations_in_order():
    labels, names = measured.orientation_labels(_still_log(1.0, (2, 0, 0, 1)))
    assert names == ('acc_z down', 'acc_x down', 'acc_y down')
    assert list(np.unique(labels, return_index=True)[0]) == [0, 1, 2]
    assert np.count_nonzero(labels == 1) == 2 * 3600


def test_block_means_stay_within_runs():
    log = _still_log(1.0, (2, 2))
    values = np.where(log.t < 1.1 * HOUR, 1.0, 3.0)
    tm, vm = measured.block_means(log.t, values, block_s=600.0)
    assert len(tm) == 12  # six 10-minute blocks per hour-long run, none across the gap
    assert np.all(vm[:6] == 1.0) and np.all(vm[6:] == 3.0)
    summary = measured.summarize(log.t, values - 2.0)
    assert summary.block_rms_dps == pytest.approx(1.0)
    assert summary.block_std_dps == pytest.approx(1.0)
    assert summary.mean_dps == pytest.approx(0.0)
    assert math.isclose(summary.rms_dps, 1.0)


def test_static_record_of_a_log_round_trips_through_the_importer():
    log = _still_log(0.5, (2,))
    record = StaticRecord(log.t, log.temp_c, {'gyro_z': log.rate_dps + 0.5, **log.extras})
    back = static_log(record, 'gyro_z')
    assert np.all(back.rate_dps == 0.5) and np.all(back.ref_rate == 0.0)
