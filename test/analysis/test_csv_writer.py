"""The CSV table writer: exact times at any epoch, fixed decimals, awkward values, chunks."""

import io
import math
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.csv_writer import CsvWriter, write_columns
from art_gyro_calibration.log import read_log


@pytest.mark.parametrize('t0', [0.0, 1.7e9, 4.1e9])
def test_time_is_kept_to_the_microsecond_at_any_epoch(tmp_path: Path, t0: float) -> None:
    """Epoch-second logs at 1 kHz: every written time reads back within half a microsecond."""
    rng = np.random.default_rng(1)
    t = t0 + np.cumsum(rng.uniform(0.0009, 0.0011, 5000))
    cols = {'t': t, 'rate_dps': rng.normal(0, 50, t.size), 'temp_c': rng.uniform(-40, 85, t.size)}
    path = tmp_path / 'out.csv'
    write_columns(path, cols)
    log = read_log(path)
    assert len(np.unique(log.t)) == t.size
    assert np.max(np.abs(log.t - t)) <= 0.5e-6 + 4 * np.spacing(t[-1])
    np.testing.assert_allclose(log.rate_dps, cols['rate_dps'], rtol=0, atol=0.5e-9 + 1e-13)
    text = path.read_text().splitlines()[1]
    assert text.split(',')[0] == f'{t[0]:.6f}'.rstrip('0').rstrip('.')


def test_writer_in_chunks_and_awkward_values(tmp_path: Path) -> None:
    x = np.array([0.0, -0.0, -1e-12, 0.1, -2.5, 1e-9, 123456.0, 1e15, math.nan, math.inf])
    buf = io.BytesIO()
    writer = CsvWriter(buf, ['t', 'v'])
    writer.write({'t': np.arange(4.0), 'v': x[:4]})     # formatted by numpy
    writer.write({'t': np.arange(4.0, 10.0), 'v': x[4:]})   # too large or not finite: by Python
    writer.write({'t': [], 'v': []})
    assert buf.getvalue().decode().split('\n') == [
        't,v', '0,0', '1,0', '2,0', '3,0.1', '4,-2.5', '5,0.000000001', '6,123456', '7,1000000000000000', '8,nan',
        '9,inf', '']
