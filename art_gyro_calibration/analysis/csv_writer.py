"""CSV tables written fast: simulated runs, ``calibrate apply``'s output, the benchmarks' logs.

:class:`CsvWriter` writes a log chunk by chunk and :func:`write_columns` a whole one, in the
columns :func:`art_gyro_calibration.log.read_log` reads back. The node and ``calibrate record``
write rows one by one as frames arrive (:class:`art_gyro_calibration.log.RawLogWriter`): this
table-driven formatter serves the offline tools alone.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping, Sequence
from typing import IO

import numpy as np
from numpy.typing import ArrayLike, NDArray

# Decimals written: ``t`` to the microsecond at any epoch, the rest to 1e-9 of its unit.
TIME_DECIMALS = 6
VALUE_DECIMALS = 9


def write_columns(path: str | os.PathLike[str], columns: Mapping[str, NDArray[np.float64]],
                  precision: int = VALUE_DECIMALS) -> None:
    """Write equally long arrays as a CSV log with a header.

    ``t`` is written to the microsecond, the other columns to ``precision`` decimals.
    """
    with open(path, 'wb') as stream:
        writer = CsvWriter(stream, list(columns), precision)
        writer.write(columns)


class CsvWriter:
    """Writes a CSV log chunk by chunk: ``t`` to the microsecond at any epoch, other columns to fixed decimals.

    Numbers are formatted by :func:`format_fixed` with numpy (millions of rows a second),
    trailing zeros dropped.
    """

    def __init__(self, stream: IO[bytes], names: Sequence[str], decimals: int = VALUE_DECIMALS) -> None:
        self._stream = stream
        self.names = tuple(names)
        self._decimals = tuple(TIME_DECIMALS if n == 't' else decimals for n in self.names)
        stream.write((','.join(self.names) + '\n').encode())

    def write(self, columns: Mapping[str, ArrayLike]) -> None:
        """Append the rows of equally long arrays, one per name."""
        values = [np.asarray(columns[n], dtype=float) for n in self.names]
        rows = len(values[0])
        if not rows:
            return
        units: list[NDArray[np.uint32]] = []
        for v, d in zip(values, self._decimals):
            units += format_fixed(v, d)
            units.append(np.full(rows, _COMMA))
        units[-1] = np.full(rows, _NEWLINE)
        text = np.stack(units, axis=1).view(np.uint8).ravel()   # row after row
        self._stream.write(text[text != 0].tobytes())


def _as_units(texts: Sequence[str]) -> NDArray[np.uint32]:
    """Each text (at most 4 ASCII characters) as one 4-byte unit, padded with zero bytes."""
    return np.frombuffer(b''.join(t.encode().ljust(4, b'\0') for t in texts), np.uint32).copy()


_ZERO, _POINT, _MINUS, _COMMA, _NEWLINE = _as_units(['\0\0\0' '0', '.', '-', ',', '\n'])


@functools.cache
def _digit_tables() -> tuple[NDArray[np.uint32], NDArray[np.uint32], NDArray[np.uint32]]:
    """Four digits per unit: all of them, without leading zeros, without trailing zeros (built on first use)."""
    return (_as_units([f'{i:04d}' for i in range(10000)]),
            _as_units([f'{i:4d}'.replace(' ', '\0') if i else '' for i in range(10000)]),
            _as_units([f'{i:04d}'.rstrip('0') for i in range(10000)]))


def format_fixed(x: NDArray[np.float64], decimals: int) -> list[NDArray[np.uint32]]:
    """``x`` as ``%.{decimals}f`` without trailing zeros (nor a ``.`` for whole numbers).

    The text of ``x[i]`` is row ``i`` of the returned columns of 4-byte units read in
    order, less its zero bytes. Digits come four at a time from tables (a value too large
    for int64 fixed point, or not finite, is formatted by Python instead).
    """
    scale = 10 ** decimals
    a = np.abs(x)
    if not np.all(a < 2.0 ** 62 / scale):
        text = [_fixed(v, decimals).encode() for v in x.tolist()]
        width = -(-max(map(len, text)) // 4) * 4
        matrix = np.frombuffer(b''.join(t.ljust(width, b'\0') for t in text), np.uint32).reshape(len(text), -1)
        return list(matrix.T)
    digits, leading, trailing = _digit_tables()
    whole = np.floor(a)
    frac = np.rint((a - whole) * scale).astype(np.int64)   # a - floor(a) is exact
    whole = whole.astype(np.int64)
    carry = frac >= scale
    whole[carry] += 1
    frac[carry] -= scale
    units = [np.where((x < 0) & ((whole > 0) | (frac > 0)), _MINUS, 0).astype(np.uint32)]
    groups = []                                  # four digits each, least significant first
    for _ in range(max(1, -(-len(str(int(whole.max(initial=0)))) // 4))):
        whole, group = np.divmod(whole, 10000)
        groups.append(group)
    above = np.ones(len(x), bool)                # every group above this one is zero
    for i, group in enumerate(reversed(groups)):
        lead = leading[group]
        if i == len(groups) - 1:
            lead = np.where(group == 0, _ZERO, lead)   # the units digit is always written
        units.append(np.where(above, lead, digits[group]))
        above &= group == 0
    fraction_groups = -(-decimals // 4)
    if fraction_groups:
        frac *= 10 ** (4 * fraction_groups - decimals)
        units.append(np.where(frac != 0, _POINT, 0).astype(np.uint32))
        tail = []
        below = np.ones(len(x), bool)            # every group below this one is zero
        for _ in range(fraction_groups):
            frac, group = np.divmod(frac, 10000)
            tail.append(np.where(below, trailing[group], digits[group]))
            below &= group == 0
        units += reversed(tail)
    return units


def _fixed(value: float, decimals: int) -> str:
    """One value as :func:`format_fixed` spells it."""
    if not math.isfinite(value):
        return repr(value)
    text = f'{value + 0.0:.{decimals}f}'
    text = text.rstrip('0').rstrip('.') if '.' in text else text
    return '0' if text == '-0' else text
