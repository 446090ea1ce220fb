"""``analysis.streaming``: ``calibrate apply`` chunk by chunk equals the whole log compensated at once."""

import dataclasses
import io

import numpy as np

from test_cli import _raw_log

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.streaming import OUTPUT_COLUMNS, apply_to_csv
from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration
from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.log import read_log
from art_gyro_calibration.terms import Term


def test_apply_streams_chunks_equal_to_the_whole_log(tmp_path, capsys):
    """Chunked apply (the static bias spanning chunks, implausible rows dropped) equals the in-memory path."""
    _raw_log(tmp_path / 'log.csv', 5000, bad_temp_rows=(3, 150, 151, 4000))
    cal = dataclasses.replace(load_packaged_calibration('NAVC4058'), terms=(
        Term('temperature_rate', 'power', (2.0,), (1,)), Term('time_since_power_on', 'exp_decay', (0.05,), (), 2.0),
        Term('rate_change', 'power', (0.002,), (1,))))
    write_calibration(tmp_path / 'CAL.yaml', cal)
    log = read_log(tmp_path / 'log.csv', cal.rate_scale_factor, cal.temp_scale_factor)
    whole = apply_calibration(log, cal, 250, start=RunStart(powered_on_at_start=True))
    assert np.count_nonzero(~whole.kept) == 4 and len(whole.corrected_dps) == 4996
    with open(tmp_path / 'chunked.csv', 'wb') as out:
        done = apply_to_csv(tmp_path / 'log.csv', cal, 250, out, chunk_rows=97, start=RunStart(True))
    assert (done.rows, done.dropped, done.bias) == (5000, 4, whole.bias)
    data = np.loadtxt(tmp_path / 'chunked.csv', delimiter=',', skiprows=1)
    np.testing.assert_allclose(data[:, 0], log.t[whole.kept], rtol=0, atol=0.5e-6 + np.spacing(log.t[-1]))
    np.testing.assert_allclose(data[:, 3], whole.comp_dps, rtol=0, atol=0.5e-9 + 1e-12)
    np.testing.assert_allclose(data[:, 4], whole.corrected_dps, rtol=0, atol=0.5e-9 + 1e-12)
    assert main(['apply', str(tmp_path / 'log.csv'), '--calibration', str(tmp_path / 'CAL.yaml'),
                 '--out', str(tmp_path / 'cli.csv'), '--bias-samples', '250', '--powered-on-at-start']) == 0
    assert (tmp_path / 'cli.csv').read_bytes() == (tmp_path / 'chunked.csv').read_bytes()
    assert '4996 of 5000 rows; 4 dropped as the node drops them' in capsys.readouterr().out


def test_the_output_is_the_same_whatever_the_chunk_size(tmp_path):
    """One row per chunk, chunks smaller than the bias window, one chunk for the whole log: the same bytes."""
    _raw_log(tmp_path / 'log.csv', 1200, bad_temp_rows=(0, 5, 700))
    cal = load_packaged_calibration('NAVC4058')
    written = {}
    for chunk_rows in (1, 33, 100_000):
        out = io.BytesIO()
        done = apply_to_csv(tmp_path / 'log.csv', cal, 100, out, chunk_rows=chunk_rows)
        assert (done.rows, done.dropped) == (1200, 3)
        written[chunk_rows] = out.getvalue()
    assert written[1] == written[33] == written[100_000]
    lines = written[1].decode().splitlines()
    assert lines[0] == ','.join(OUTPUT_COLUMNS) and len(lines) == 1 + 1197


def test_rows_outside_the_calibrated_range_are_counted_over_every_chunk(tmp_path):
    _raw_log(tmp_path / 'log.csv', 1000)   # 20.00 degC rising by 0.05 degC every 500 rows
    cal = dataclasses.replace(load_packaged_calibration('NAVC4058'), temperature_warn_range_c=(0.0, 20.02))
    done = apply_to_csv(tmp_path / 'log.csv', cal, 100, io.BytesIO(), chunk_rows=64)
    assert done.outside_range == 500
