"""CSV logs: both unit conventions, extra columns, and clear refusals."""

import io
import warnings
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.csv_writer import write_columns
from art_gyro_calibration.log import CutRowWarning, LogError, RawLogWriter, read_log, read_log_chunks


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
    ('t,rate_dps,temp_c\n0,1,2\n1,x,2\n', ":3: row 2, column rate_dps: 'x' is not a number"),
    ('t,rate_dps,temp_c\n0,1,2\n\n1,2,y\n', ":4: row 2, column temp_c: 'y' is not a number"),
    ('t,rate_dps,temp_c\n0,1,2\n1,1,2\n2,1\n', ':4: row 3: 2 values but 3 header names'),
    ('t,rate_dps,temp_c\n0,1\n', ':2: row 1: 2 values but 3 header names|:2: 2 values per row'),
    ('t,rate_dps,temp_c\n1,1,2\n0,1,2\n', ':3: row 2, column t: 0.0 after 1.0: time must be finite and non-decreasing'),
    ('t,rate_dps,temp_c\n0,nan,2\n', ':2: row 1, column rate_dps: nan is not a finite number'),
    ('t,gyro,temp_c\n0,1,2\n', 'needs columns rate_dps and temp_c'),
    ('time,rate_dps,temp_c\n0,1,2\n', 'no column t'),
    ('\ufeff"t";"rate_dps";"temp_c"\n0;1;2\n', 'no column t'),     # semicolons: not this CSV
])
def test_bad_logs(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    with pytest.raises(LogError, match=message) as info:
        read_log(path)
    assert str(info.value).startswith(str(path))


def test_bom_quoted_header_and_crlf(tmp_path: Path) -> None:
    """What spreadsheets and Windows loggers write: a byte order mark, quoted names, CRLF line ends."""
    path = tmp_path / 'excel.csv'
    path.write_bytes(b'\xef\xbb\xbf"t", "rate_dps",\'temp_c\',"supply_v"\r\n0.5,1.25,20,12\r\n1.5,-1,20.5,12.1\r\n')
    log = read_log(path)
    np.testing.assert_array_equal(log.t, [0.5, 1.5])
    np.testing.assert_array_equal(log.rate_dps, [1.25, -1.0])
    assert list(log.extras) == ['supply_v']


@pytest.mark.parametrize('data', [
    b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xd0\xff' * 100,        # a binary file with a first line
    b't,rate_dps,temp_c\n0,1,2\n' + bytes(range(128, 256)) * 50,   # text, then binary
    b'\xd0' * 200000,                                                # no line break at all
])
def test_binary_file_is_named(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / 'gyro.bin'
    path.write_bytes(data)
    with pytest.raises(LogError) as info:
        read_log(path)
    message = str(info.value)
    assert message.startswith(str(path)) and len(message) < 400, message
    assert 'codec' not in message or 'CSV' in message


def _log_text(n: int, t0: float, rate_hz: float) -> tuple[str, np.ndarray]:
    t = t0 + np.arange(n) / rate_hz
    rows = ''.join(f'{x:.6f},{k % 7 - 3},{500 + k % 3}\n' for k, x in enumerate(t.tolist()))
    return 't,raw_rate,raw_temp\n' + rows, t


def test_chunks_equal_the_whole_and_errors_name_the_line(tmp_path: Path) -> None:
    text, t = _log_text(1000, 1.7e9, 1000.0)
    path = tmp_path / 'log.csv'
    path.write_text(text.replace('\n', '\n\n', 3))   # blank lines do not count as rows
    whole = read_log(path, 0.00305, 0.05)
    chunks = list(read_log_chunks(path, 0.00305, 0.05, chunk_rows=37))
    assert len(chunks) > 10
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), whole.t)
    np.testing.assert_array_equal(np.concatenate([c.rate_dps for c in chunks]), whole.rate_dps)
    lines = text.splitlines(keepends=True)   # line i + 1 holds row i
    lines.insert(500, lines[499])              # a repeated time is fine: rows 500 and 501 share it
    bad = list(lines)
    bad[901] = bad[901].replace(',', ',x', 1)
    path.write_text(''.join(bad))
    with pytest.raises(LogError, match=r'log.csv:902: row 901, column raw_rate: .x-?\d. is not a number'):
        list(read_log_chunks(path, 0.00305, 0.05, chunk_rows=37))
    bad = list(lines)
    bad[901] = bad[899]                         # time going back is not
    path.write_text(''.join(bad))
    with pytest.raises(LogError, match=r'log.csv:902: row 901, column t: .* time must be finite and non-decreasing'):
        list(read_log_chunks(path, 0.00305, 0.05, chunk_rows=37))


def test_a_last_row_cut_mid_way_is_dropped_and_said(tmp_path: Path) -> None:
    """A full disk cut '500' to '50': the cut row is dropped and said, not read as a valid row."""
    path = tmp_path / 'cut.csv'
    path.write_text('t,raw_rate,raw_temp\n1.0,2,500\n2.0,3,500\n3.0,4,50', encoding='utf-8')
    with pytest.warns(CutRowWarning, match=r'cut.csv:4: the last row does not end its line \(cut by a kill or a '
                                           r"full disk\): dropped, '3.0,4,50' not read"):
        log = read_log(path, 0.00305, 0.05)
    assert log.t.tolist() == [1.0, 2.0] and log.temp_c.tolist() == [25.0, 25.0]
    path.write_text('t,raw_rate,raw_temp\n1.0,2,500\n2.0,3,500\n', encoding='utf-8')
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert len(read_log(path, 0.00305, 0.05)) == 2


def test_calibrate_says_which_row_it_dropped(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from art_gyro_calibration.analysis.cli import main
    log = tmp_path / 'cut.csv'
    log.write_text('t,rate_dps,temp_c\n' + ''.join(f'{i * 0.1:.1f},{0.01 * (i % 3)},25\n' for i in range(200))
                   + '20.0,0.0', encoding='utf-8')
    cal = Path(__file__).resolve().parents[1] / 'config' / 'NAVC3545.yaml'
    assert main(['apply', str(log), '--calibration', str(cal), '--out', str(tmp_path / 'o.csv')]) == 0
    err = capsys.readouterr().err
    assert f"calibrate: warning: {log}:202: the last row does not end its line" in err, err
    assert len((tmp_path / 'o.csv').read_text().splitlines()) == 201
