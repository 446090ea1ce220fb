"""CSV logs: both unit conventions, extra columns, and clear refusals."""

import io
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.log import LogError, RawLogWriter, read_log, write_columns


def test_raw_counts_and_extras(tmp_path: Path) -> None:
    buf = io.StringIO()
    writer = RawLogWriter(buf, flush_every=1)
    writer.write(0.0, 100, 500)
    writer.write(0.1, -200, 501)
    path = tmp_path / 'raw.csv'
    path.write_text(buf.getvalue())
    log = read_log(path, 0.00305, 0.05)
    np.testing.assert_allclose(log.rate_dps, [0.305, -0.61])
    np.testing.assert_allclose(log.temp_c, [25.0, 25.05])
    assert log.ref_rate is None and dict(log.extras) == {}
    with pytest.raises(LogError, match='raw counts need a calibration'):
        read_log(path)


def test_physical_units_round_trip(tmp_path: Path) -> None:
    path = tmp_path / 'log.csv'
    cols = {'t': np.arange(4.0), 'rate_dps': np.array([0.0, 1.5, -2.0, 3.0]), 'temp_c': np.full(4, 21.0),
            'ref_rate': np.array([0.0, 1.5, -2.0, 3.0]), 'supply_v': np.array([12.0, 12.1, 11.9, 12.0])}
    write_columns(path, cols)
    log = read_log(path)
    np.testing.assert_array_equal(log.ref_rate, cols['ref_rate'])
    assert list(log.extras) == ['supply_v']
    part = log.slice(slice(1, 3))
    assert len(part) == 2 and part.extras['supply_v'].tolist() == [12.1, 11.9]


@pytest.mark.parametrize('text, message', [
    ('', 'header must name each column once'),
    ('t,t\n1,2\n', 'header must name each column once'),
    ('t,rate_dps,temp_c\n', 'no samples'),
    ('t,rate_dps,temp_c\n0,1,2\n1,x,2\n', "row 2: rate_dps is 'x', not a number"),
    ('t,rate_dps,temp_c\n0,1,2\n\n1,2,y\n', "row 2: temp_c is 'y', not a number"),
    ('t,rate_dps,temp_c\n0,1,2\n1,1,2\n2,1\n', 'row 3: 2 values but 3 header names'),
    ('t,rate_dps,temp_c\n0,1\n', 'values per row|row 1: 2 values but 3 header names'),
    ('t,rate_dps,temp_c\n1,1,2\n0,1,2\n', 'non-decreasing .first bad row 2'),
    ('t,rate_dps,temp_c\n0,nan,2\n', 'rate is not a finite number at row 1'),
    ('t,gyro,temp_c\n0,1,2\n', 'needs columns rate_dps and temp_c'),
    ('time,rate_dps,temp_c\n0,1,2\n', 'no column t'),
])
def test_bad_logs(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    with pytest.raises(LogError, match=message) as info:
        read_log(path)
    assert str(info.value).startswith(str(path))
