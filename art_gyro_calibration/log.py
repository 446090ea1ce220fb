"""Gyro logs as CSV: what the rate table, ``calibrate record`` and the node write.

A log has a header row and one row per sample:

- ``t``: seconds (host time or table time),
- the rate and temperature as ``raw_rate``, ``raw_temp`` (counts) or ``rate_dps``, ``temp_c``,
- optional ``ref_rate``: the rate table's true rate in deg/s,
- any further numeric columns (supply voltage, a second temperature sensor, ...),
  which the residual tracer screens as candidate signals.
"""

from __future__ import annotations

import itertools
import math
import os
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import IO

import numpy as np
from numpy.typing import NDArray

RAW_HEADER = ('t', 'raw_rate', 'raw_temp')
_KNOWN = {'t', 'raw_rate', 'raw_temp', 'rate_dps', 'temp_c', 'ref_rate'}


class LogError(ValueError):
    """A log that cannot be read, with where and why."""


class CutRowWarning(UserWarning):
    """The log's last row does not end its line (cut by a kill or a full disk): it was dropped, not read."""


@dataclass(frozen=True)
class GyroLog:
    """One log, in physical units: deg/s and degC."""

    t: NDArray[np.float64]
    rate_dps: NDArray[np.float64]
    temp_c: NDArray[np.float64]
    ref_rate: NDArray[np.float64] | None = None
    extras: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    def slice(self, index: slice | NDArray[np.bool_] | NDArray[np.int_]) -> GyroLog:
        """The samples at ``index``."""
        return GyroLog(self.t[index], self.rate_dps[index], self.temp_c[index],
                       None if self.ref_rate is None else self.ref_rate[index],
                       {k: v[index] for k, v in self.extras.items()})


# Rows of text parsed at a time by :func:`read_log_chunks` (and compensated at a time by ``calibrate apply``):
# a few MB of text, so memory stays bounded and numpy stays fast.
READ_CHUNK_ROWS = 1 << 16
# A header longer than this is not a log's (a binary file without line breaks).
_MAX_HEADER_CHARS = 1 << 16


def read_log(path: str | os.PathLike[str], rate_scale_factor: float | None = None,
             temp_scale_factor: float | None = None) -> GyroLog:
    """Read a CSV log; raw counts need the calibration's scale factors.

    The columns are made once, as long as the file has lines, and filled chunk by chunk:
    the peak is the log's columns and one chunk, not the chunks and their join.
    """
    chunks = read_log_chunks(path, rate_scale_factor, temp_scale_factor)
    first = next(chunks)
    capacity = max(_count_lines(path) if os.path.isfile(path) else 0, len(first))
    names = ['t', 'rate_dps', 'temp_c', *(() if first.ref_rate is None else ('ref_rate',))]
    columns = {name: np.empty(capacity) for name in names}
    extras = {name: np.empty(capacity) for name in first.extras}
    rows = 0
    for chunk in itertools.chain([first], chunks):
        stop = rows + len(chunk)
        if stop > capacity:   # the file grew while being read
            capacity = max(2 * capacity, stop)
            columns = {k: _grown(v, rows, capacity) for k, v in columns.items()}
            extras = {k: _grown(v, rows, capacity) for k, v in extras.items()}
        for name, column in columns.items():
            column[rows:stop] = getattr(chunk, name)
        for name, column in extras.items():
            column[rows:stop] = chunk.extras[name]
        rows = stop
    return GyroLog(columns['t'][:rows], columns['rate_dps'][:rows], columns['temp_c'][:rows],
                   columns['ref_rate'][:rows] if 'ref_rate' in columns else None,
                   {k: v[:rows] for k, v in extras.items()})


def _count_lines(path: str | os.PathLike[str]) -> int:
    """Line breaks in the file, plus one: at least its rows."""
    count = 1
    with open(path, 'rb') as f:
        while block := f.read(1 << 24):
            count += block.count(b'\n')
    return count


def _grown(column: NDArray[np.float64], rows: int, capacity: int) -> NDArray[np.float64]:
    """``column``'s first ``rows`` values in a column of ``capacity``."""
    out = np.empty(capacity)
    out[:rows] = column[:rows]
    return out


def concatenate(chunks: list[GyroLog]) -> GyroLog:
    """One log of consecutive chunks of it; ``chunks`` is emptied.

    Each chunk is copied into the joined columns and let go, first to last: the joined
    columns fill as the chunks are freed, so the peak stays near the log's size, not twice it.
    """
    if len(chunks) == 1:
        return chunks.pop()
    first = chunks[0]
    total = sum(len(c) for c in chunks)
    names = ['t', 'rate_dps', 'temp_c', *(() if first.ref_rate is None else ('ref_rate',))]
    columns = {name: np.empty(total, dtype=getattr(first, name).dtype) for name in names}
    extras = {k: np.empty(total, dtype=v.dtype) for k, v in first.extras.items()}
    chunks.reverse()
    at = 0
    while chunks:
        chunk = chunks.pop()
        stop = at + len(chunk)
        for name, column in columns.items():
            column[at:stop] = getattr(chunk, name)
        for name, column in extras.items():
            column[at:stop] = chunk.extras[name]
        at = stop
    return GyroLog(columns['t'], columns['rate_dps'], columns['temp_c'], columns.get('ref_rate'), extras)


def read_log_chunks(path: str | os.PathLike[str], rate_scale_factor: float | None = None,
                    temp_scale_factor: float | None = None, chunk_rows: int = READ_CHUNK_ROWS) -> Iterator[GyroLog]:
    """Read a CSV log in chunks of about ``chunk_rows`` rows, each checked as :func:`read_log` checks the whole.

    Memory stays bounded whatever the log's length. A UTF-8 byte order mark, quoted
    header names and CRLF line ends are accepted; anything refused raises :class:`LogError`
    naming the file, the line, the row (1 = the first after the header) and the column.
    """
    where = str(path)
    try:
        with open(path, encoding='utf-8-sig') as f:
            header = _header(f, where)
            convert = _converter(header, where, rate_scale_factor, temp_scale_factor)
            rows = 0        # data rows before this chunk
            lines_read = 1  # lines before this chunk (the header)
            last_t = -math.inf
            hint = max(1, chunk_rows) * 8 * (len(header) + 1)   # readlines() counts characters
            while True:
                try:
                    lines = f.readlines(hint)
                except UnicodeDecodeError as e:
                    raise LogError(f'{where}: not UTF-8 text after line {lines_read} (row {rows}): '
                                   f'{e.reason} at byte 0x{e.object[e.start]:02x}; is this a CSV log?') from None
                if not lines:
                    break
                if not lines[-1].endswith('\n') and lines[-1].split('#', 1)[0].strip():
                    # Only the file's last line can lack its end: a row cut mid-way ('500' written as '50')
                    # would read as a value. Dropped, and said.
                    warnings.warn(CutRowWarning(f'{where}:{lines_read + len(lines)}: the last row does not end its '
                                                f'line (cut by a kill or a full disk): dropped, '
                                                f'{_shown(lines[-1].strip())} not read'))
                    lines.pop()
                    if not lines:
                        break
                data = _parse(lines, header, where, lines_read, rows)
                if data.shape[0]:
                    chunk = convert(data, last_t, lines, lines_read, rows)
                    last_t = float(chunk.t[-1])
                    rows += data.shape[0]
                    yield chunk
                lines_read += len(lines)
    except OSError as e:
        raise LogError(f'{where}: cannot read: {e.strerror}') from None
    if not rows:
        raise LogError(f'{where}: no samples after the header')


def _header(f: IO[str], where: str) -> list[str]:
    """Column names of the header line; quotes around a name are dropped."""
    try:
        line = f.readline(_MAX_HEADER_CHARS)
    except UnicodeDecodeError as e:
        raise LogError(f'{where}:1: header is not UTF-8 text ({e.reason} at byte 0x{e.object[e.start]:02x}); '
                       'is this a CSV log?') from None
    if len(line) >= _MAX_HEADER_CHARS and not line.endswith('\n'):
        raise LogError(f'{where}:1: no line break in the first {_MAX_HEADER_CHARS} characters; is this a CSV log?')
    header = [_unquote(h.strip()) for h in line.strip().split(',')]
    if not line.strip() or len(set(header)) != len(header) or '' in header:
        raise LogError(f'{where}:1: header must name each column once, got {_shown(line.strip())}')
    return header


def _unquote(name: str) -> str:
    return name[1:-1].strip() if len(name) >= 2 and name[0] == name[-1] and name[0] in '"\'' else name


def _shown(text: str, limit: int = 120) -> str:
    """``text`` for an error message, cut to a readable length."""
    return repr(text) if len(text) <= limit else f'{text[:limit]!r}... ({len(text)} characters)'


def _converter(header: list[str], where: str, rate_scale_factor: float | None,
               temp_scale_factor: float | None) -> Callable[..., GyroLog]:
    """The function turning a chunk's columns into a checked :class:`GyroLog` in deg/s and degC."""
    index = {name: i for i, name in enumerate(header)}
    if 't' not in index:
        raise LogError(f'{where}:1: no column t (columns: {_shown(", ".join(header))})')
    if 'rate_dps' in index and 'temp_c' in index:
        rate_col, temp_col, rate_scale, temp_scale = index['rate_dps'], index['temp_c'], None, None
    elif 'raw_rate' in index and 'raw_temp' in index:
        if rate_scale_factor is None or temp_scale_factor is None:
            raise LogError(f'{where}: raw counts need a calibration for their scale factors')
        rate_col, temp_col = index['raw_rate'], index['raw_temp']
        rate_scale, temp_scale = rate_scale_factor, temp_scale_factor
    else:
        raise LogError(f'{where}:1: needs columns rate_dps and temp_c, or raw_rate and raw_temp; '
                       f'has {_shown(", ".join(header))}')
    extras = [name for name in header if name not in _KNOWN]

    def convert(data: NDArray[np.float64], last_t: float, lines: list[str], first_line: int,
                rows: int) -> GyroLog:
        def refuse(k: int, column: str, why: str) -> LogError:
            return LogError(f'{where}:{_line_of(lines, k) + first_line + 1}: row {rows + k + 1}, column {column}: '
                            f'{why}')

        t = data[:, index['t']]
        bad = ~np.isfinite(t)
        bad[1:] |= t[1:] < t[:-1]
        bad[0] |= t[0] < last_t
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise refuse(k, 't', f'{float(t[k])!r} after {float(t[k - 1] if k else last_t)!r}: '
                                 'time must be finite and non-decreasing')
        rate, temp = data[:, rate_col], data[:, temp_col]
        if rate_scale is not None and temp_scale is not None:
            rate, temp = rate * rate_scale, temp * temp_scale
        for column, values in ((header[rate_col], rate), (header[temp_col], temp)):
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise refuse(int(bad[0]), column, f'{float(values[bad[0]])!r} is not a finite number')
        return GyroLog(t, rate, temp, data[:, index['ref_rate']] if 'ref_rate' in index else None,
                       {name: data[:, index[name]] for name in extras})
    return convert


def _data_lines(lines: list[str]) -> Iterator[tuple[int, str]]:
    """(index in ``lines``, text) of each line holding a row: ``np.loadtxt`` skips blank and ``#`` lines."""
    for i, line in enumerate(lines):
        text = line.split('#', 1)[0].strip()
        if text:
            yield i, text


def _line_of(lines: list[str], k: int) -> int:
    """Index in ``lines`` of the ``k``-th row (0-based)."""
    for n, (i, _) in enumerate(_data_lines(lines)):
        if n == k:
            return i
    raise IndexError(k)


def _parse(lines: list[str], header: list[str], where: str, first_line: int, rows: int) -> NDArray[np.float64]:
    """The rows of ``lines`` as an array (rows x columns); a bad value is named by line, row and column."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', UserWarning)  # lines without rows: the caller counts rows
            data = np.loadtxt(lines, delimiter=',', dtype=float, ndmin=2)
    except ValueError as e:
        # numpy names neither the file nor the column: find the row again.
        for n, (i, text) in enumerate(_data_lines(lines)):
            at = f'{where}:{first_line + i + 1}: row {rows + n + 1}'
            fields = text.split(',')
            if len(fields) != len(header):
                raise LogError(f'{at}: {len(fields)} values but {len(header)} header names') from None
            for name, value in zip(header, fields):
                try:
                    float(value)
                except ValueError:
                    raise LogError(f'{at}, column {name}: {_shown(value.strip())} is not a number') from None
        raise LogError(f'{where}: after line {first_line}: {e}') from None
    if data.size and data.shape[1] != len(header):
        raise LogError(f'{where}:{first_line + 1}: {data.shape[1]} values per row but {len(header)} header names')
    return data


class RawLogWriter:
    """Appends ``t,raw_rate,raw_temp`` rows as frames arrive (``calibrate record``, the node)."""

    def __init__(self, stream: IO[str], flush_every: int = 100, header: bool = True) -> None:
        self._stream = stream
        self._flush_every = flush_every
        self._pending = 0
        self._flushed_size = 0   # the file's size after the last flush that succeeded
        self._lengths: list[int] = []   # of the rows written since
        if header:   # not when a log is continued
            stream.write(','.join(RAW_HEADER) + '\n')

    def unwritten(self) -> int:
        """After a write or flush failed (a full disk): how many rows since the last flush are not on disk whole.

        The file's growth since the last flush, in whole rows (a full disk takes part of a flush);
        without a file (a stream in memory), every row since the last flush.
        """
        landed = 0
        try:
            grown = os.fstat(self._stream.fileno()).st_size - self._flushed_size
        except (OSError, ValueError, AttributeError):
            grown = 0
        for length in itertools.accumulate(self._lengths):   # the rows since the flush, in bytes (ASCII)
            if length > grown:
                break
            landed += 1
        return max(self._pending - landed, 0)

    def flush(self) -> None:
        """Write what is buffered to the file now."""
        self._stream.flush()
        self._pending = 0
        self._lengths.clear()
        try:
            self._flushed_size = os.fstat(self._stream.fileno()).st_size
        except (OSError, ValueError, AttributeError):
            pass

    def write(self, t: float, raw_rate: float, raw_temp: float) -> None:
        """Add one sample; flushed in batches so a crash loses at most ``flush_every`` rows."""
        if not math.isfinite(t):
            raise ValueError(f'log time must be finite, got {t!r}')
        # repr: the shortest text that reads back as this very float, so offline tools see the node's times.
        row = f'{t!r},{raw_rate},{raw_temp}\n'
        self._pending += 1   # first: a write or flush that fails counts this row among the unflushed
        self._lengths.append(len(row))
        self._stream.write(row)
        if self._pending >= self._flush_every:
            self.flush()

    def close(self) -> None:
        """Flush and close the stream."""
        self._stream.flush()
        self._stream.close()
