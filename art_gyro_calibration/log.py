"""Gyro logs as CSV: what the rate table, ``calibrate record`` and the node write.

A log has a header row and one row per sample:

- ``t``: seconds (host time or table time),
- the rate and temperature as ``raw_rate``, ``raw_temp`` (counts) or ``rate_dps``, ``temp_c``,
- optional ``ref_rate``: the rate table's true rate in deg/s,
- any further numeric columns (supply voltage, a second temperature sensor, ...),
  which the residual tracer screens as candidate signals.
"""

from __future__ import annotations

import io
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

RAW_HEADER = ('t', 'raw_rate', 'raw_temp')
_KNOWN = {'t', 'raw_rate', 'raw_temp', 'rate_dps', 'temp_c', 'ref_rate'}


class LogError(ValueError):
    """A log that cannot be read, with where and why."""


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


def read_log(path: str | os.PathLike[str], rate_scale_factor: float | None = None,
             temp_scale_factor: float | None = None) -> GyroLog:
    """Read a CSV log; raw counts need the calibration's scale factors."""
    where = str(path)
    try:
        with open(path, encoding='utf-8') as f:
            header_line = f.readline()
            header = [h.strip() for h in header_line.strip().split(',')]
            if not header_line.strip() or len(set(header)) != len(header) or '' in header:
                raise LogError(f'{where}:1: header must name each column once, got {header_line.strip()!r}')
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore', UserWarning)  # an empty log is refused below
                    data = np.loadtxt(f, delimiter=',', dtype=float, ndmin=2)
            except ValueError as e:
                # numpy counts rows from 0 in one message and from 1 in another: find the row again.
                raise LogError(f'{where}: {_bad_row(path, header) or e}') from None
    except OSError as e:
        raise LogError(f'{where}: cannot read: {e.strerror}') from None
    if data.size == 0:
        raise LogError(f'{where}: no samples after the header')
    if data.shape[1] != len(header):
        raise LogError(f'{where}: {data.shape[1]} values per row but {len(header)} header names')
    cols = {name: data[:, i] for i, name in enumerate(header)}
    if 't' not in cols:
        raise LogError(f'{where}: no column t')
    t = cols['t']
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise LogError(f'{where}: column t must be finite and non-decreasing '
                       f'(first bad row {_first_bad_time(t) + 1})')
    if 'rate_dps' in cols and 'temp_c' in cols:
        rate, temp = cols['rate_dps'], cols['temp_c']
    elif 'raw_rate' in cols and 'raw_temp' in cols:
        if rate_scale_factor is None or temp_scale_factor is None:
            raise LogError(f'{where}: raw counts need a calibration for their scale factors')
        rate, temp = cols['raw_rate'] * rate_scale_factor, cols['raw_temp'] * temp_scale_factor
    else:
        raise LogError(f'{where}: needs columns rate_dps and temp_c, or raw_rate and raw_temp; '
                       f'has {", ".join(header)}')
    for name, values in (('rate', rate), ('temperature', temp)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogError(f'{where}: {name} is not a finite number at row {bad[0] + 1}')
    extras = {k: v for k, v in cols.items() if k not in _KNOWN}
    return GyroLog(t, rate, temp, cols.get('ref_rate'), extras)


def _bad_row(path: str | os.PathLike[str], header: list[str]) -> str:
    """The first data row ``np.loadtxt`` refuses, as ``row N: why`` (row 1 is the first after the header)."""
    with open(path, encoding='utf-8') as f:
        f.readline()
        row = 0
        for line in f:
            text = line.split('#', 1)[0].strip()
            if not text:
                continue   # loadtxt skips blank and comment lines
            row += 1
            fields = text.split(',')
            if len(fields) != len(header):
                return f'row {row}: {len(fields)} values but {len(header)} header names'
            for name, value in zip(header, fields):
                try:
                    float(value)
                except ValueError:
                    return f'row {row}: {name} is {value.strip()!r}, not a number'
    return ''


def _first_bad_time(t: NDArray[np.float64]) -> int:
    bad = ~np.isfinite(t)
    bad[1:] |= np.diff(t) < 0
    return int(np.flatnonzero(bad)[0])


def write_columns(path: str | os.PathLike[str], columns: Mapping[str, NDArray[np.float64]],
                  precision: int = 9) -> None:
    """Write equally long arrays as a CSV log with a header."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    buf = io.StringIO()
    np.savetxt(buf, data, delimiter=',', fmt=f'%.{precision}g', header=','.join(names), comments='')
    Path(path).write_text(buf.getvalue(), encoding='utf-8')


class RawLogWriter:
    """Appends ``t,raw_rate,raw_temp`` rows as frames arrive (``calibrate record``, the node)."""

    def __init__(self, stream: IO[str], flush_every: int = 100) -> None:
        self._stream = stream
        self._flush_every = flush_every
        self._pending = 0
        stream.write(','.join(RAW_HEADER) + '\n')

    def write(self, t: float, raw_rate: int, raw_temp: int) -> None:
        """Add one sample; flushed in batches so a crash loses at most ``flush_every`` rows."""
        if not math.isfinite(t):
            raise ValueError(f'log time must be finite, got {t!r}')
        self._stream.write(f'{t:.6f},{raw_rate},{raw_temp}\n')
        self._pending += 1
        if self._pending >= self._flush_every:
            self._stream.flush()
            self._pending = 0

    def close(self) -> None:
        """Flush and close the stream."""
        self._stream.flush()
        self._stream.close()
