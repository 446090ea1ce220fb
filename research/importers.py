"""Importers: a record of a still instrument from elsewhere, as the project's gyro logs.

A static thermal log is what a gyro reads while it lies still as its temperature
changes: its true rate is zero (the Earth's rotation aside), so everything it reads
is error. :func:`static_log` turns one gyro axis of such a record into a
:class:`~art_gyro_calibration.log.GyroLog` (rate in deg/s, temperature, a zero
reference rate, every other channel as an extra column for the residual tracer),
keeping only the samples where the instrument was still. Readers of particular
formats (:func:`read_cats_netcdf`, :func:`read_phone_netcdf`) only turn a file into a
:class:`StaticRecord`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter1d, uniform_filter1d  # type: ignore[import-untyped]  # scipy ships no types

from art_gyro_calibration.calibration import SIGNAL_PATTERN
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.analysis.csv_writer import write_columns
from art_gyro_calibration.signals import DERIVED_SIGNALS

DEG_PER_MRAD = 180.0 / (1000.0 * math.pi)
# Rate units a record may use, in deg/s.
DEG_PER_S = {'mrad/s': DEG_PER_MRAD, 'rad/s': 180.0 / math.pi, 'deg/s': 1.0}
CATS_VARIABLES = {'angular_velocity': 'gyro', 'acceleration': 'acc', 'magnetic_density': 'mag'}


class RecordError(ValueError):
    """A record that cannot be imported, with where and why."""


@dataclass(frozen=True)
class StaticRecord:
    """A record of an instrument meant to lie still: time, its temperature and named channels.

    Rate channels are in deg/s; the others keep their own units (they are only
    candidate signals for the tracer). A record without a temperature sensor has
    ``temp_c`` all NaN (:func:`static_log` then needs a stand-in, said out loud).
    """

    t: NDArray[np.float64]
    temp_c: NDArray[np.float64]
    channels: Mapping[str, NDArray[np.float64]]
    source: str = ''

    def __post_init__(self) -> None:
        where = self.source or 'record'
        n = len(self.t)
        if n < 2:
            raise RecordError(f'{where}: needs at least two samples, has {n}')
        if not np.all(np.isfinite(self.t)) or np.any(np.diff(self.t) <= 0):
            raise RecordError(f'{where}: time must be finite and increasing')
        for name, values in {'temperature': self.temp_c, **self.channels}.items():
            if len(values) != n:
                raise RecordError(f'{where}: channel {name!r} has {len(values)} samples, time has {n}')
        for name in self.channels:
            if not SIGNAL_PATTERN.match(name) or name in DERIVED_SIGNALS:
                raise RecordError(f'{where}: channel name {name!r} must be a plain identifier that is not '
                                  f'a derived signal ({", ".join(DERIVED_SIGNALS)})')

    def slice(self, index: slice | NDArray[np.bool_] | NDArray[np.int_]) -> StaticRecord:
        """Return the samples at ``index``."""
        return StaticRecord(self.t[index], self.temp_c[index],
                            {k: v[index] for k, v in self.channels.items()}, self.source)


def still_mask(t: NDArray[np.float64], channels: Sequence[NDArray[np.float64]], window_s: float = 60.0,
               factor: float = 3.0, margin_s: float = 300.0, min_still_s: float = 1800.0) -> NDArray[np.bool_]:
    """Find the samples taken while the instrument lay still, from its motion channels.

    A sample is moving when, over a centred window of ``window_s``, the standard
    deviation of any channel exceeds ``factor`` times that channel's median
    (the median window is still: the instrument lies still most of the time).
    Moving samples are widened by ``margin_s`` on each side (handling shakes the
    mount before and after), and still runs shorter than ``min_still_s`` dropped.
    Not causal: an importer sees the whole record.
    """
    dt = float(np.median(np.diff(t)))
    window = max(3, int(round(window_s / dt)) | 1)
    moving = np.zeros(len(t), dtype=bool)
    for x in channels:
        x = np.asarray(x, dtype=float)
        centred = x - np.median(x)  # the variance by E[x^2] - E[x]^2 loses digits on a large offset
        mean = uniform_filter1d(centred, window, mode='nearest')
        std = np.sqrt(np.maximum(uniform_filter1d(centred * centred, window, mode='nearest') - mean * mean, 0.0))
        moving |= std > factor * np.median(std)
    margin = int(round(margin_s / dt))
    if margin:
        moving = maximum_filter1d(moving.astype(np.uint8), 2 * margin + 1) > 0
    still = ~moving
    for start, stop in runs(still):
        if t[stop - 1] - t[start] < min_still_s:
            still[start:stop] = False
    return still


def runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Return the ``(start, stop)`` index pairs of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return [(int(a), int(b)) for a, b in edges.reshape(-1, 2)]


def segment_labels(t: NDArray[np.float64], gap_s: float) -> NDArray[np.int_]:
    """Label each sample with its still run's number: a new run starts after a gap longer than ``gap_s``."""
    labels = np.zeros(len(t), dtype=int)
    labels[1:] = np.cumsum(np.diff(t) > gap_s)
    return labels


def static_log(record: StaticRecord, rate_channel: str, still: NDArray[np.bool_] | None = None,
               temperature_c: float | None = None) -> GyroLog:
    """Make one gyro axis of a still record a log: ``rate_channel`` is the rate, the reference is zero.

    Every other channel becomes an extra column; only the samples in ``still``
    (default: all) are kept, so the log may have gaps where the instrument moved. A
    record without temperature (all NaN) is refused unless ``temperature_c`` stands in
    for it (a constant: the fit can then use no temperature power); a record with one
    refuses a stand-in.
    """
    where = record.source or 'record'
    if rate_channel not in record.channels:
        raise RecordError(f'{where}: no channel {rate_channel!r}; has {", ".join(record.channels)}')
    keep = np.ones(len(record.t), dtype=bool) if still is None else np.asarray(still, dtype=bool)
    if keep.shape != record.t.shape:
        raise RecordError(f'{where}: still mask has {keep.shape} samples, record has {record.t.shape}')
    if not keep.any():
        raise RecordError(f'{where}: no still samples')
    temp = record.temp_c[keep]
    if temperature_c is not None:
        if not np.all(np.isnan(record.temp_c)):
            raise RecordError(f'{where}: has a temperature; a stand-in of {temperature_c} degC would replace it')
        temp = np.full(int(keep.sum()), float(temperature_c))
    rate = record.channels[rate_channel][keep]
    for name, values in (('rate', rate), ('temperature', temp)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise RecordError(f'{where}: {name} is not a finite number at still sample {bad[0]}')
    extras = {k: v[keep] for k, v in record.channels.items() if k != rate_channel}
    return GyroLog(record.t[keep], rate, temp, np.zeros(int(keep.sum())), extras)


def write_static_log(path: str | os.PathLike[str], log: GyroLog) -> None:
    """Write a log in the project's CSV format (``t, rate_dps, temp_c, ref_rate``, then the extras)."""
    columns = {'t': log.t, 'rate_dps': log.rate_dps, 'temp_c': log.temp_c}
    if log.ref_rate is not None:
        columns['ref_rate'] = log.ref_rate
    write_columns(path, {**columns, **log.extras})


def _attr(variable: Any, name: str) -> str:
    """A NetCDF attribute as text ('' if absent)."""
    value = variable.attrs.get(name, b'')
    return value.decode() if isinstance(value, bytes) else str(value)


def _open_netcdf(path: str | os.PathLike[str], variables: Sequence[str]) -> Any:
    """Open a NetCDF-4 file with h5py, refusing one that lacks any of ``variables``."""
    import h5py  # type: ignore[import-untyped]  # only these readers need it; h5py ships no types

    where = str(path)
    try:
        f = h5py.File(path, 'r')
    except OSError as e:
        raise RecordError(f'{where}: cannot read as NetCDF-4/HDF5: {e}') from None
    missing = [v for v in variables if v not in f]
    if missing:
        f.close()
        raise RecordError(f'{where}: not the record expected, missing variables {missing}')
    return f


def _gyro_scale(f: Any, where: str) -> float:
    """deg/s per unit of the file's ``angular_velocity``."""
    units = _attr(f['angular_velocity'], 'units')
    if units not in DEG_PER_S:
        raise RecordError(f'{where}: angular_velocity in {units!r}, expected one of {", ".join(DEG_PER_S)}')
    return DEG_PER_S[units]


def _triads(f: Any, where: str, streams: Mapping[str, int]) -> dict[str, NDArray[np.float64]]:
    """``gyro_x/y/z`` (deg/s), ``acc_x/y/z``, ``mag_x/y/z``: the first x, y, z of each variable's ``streams``."""
    channels: dict[str, NDArray[np.float64]] = {}
    for variable, prefix in CATS_VARIABLES.items():
        values = np.asarray(f[variable][...], dtype=float)
        columns = 3 * streams.get(variable, 1)
        if values.ndim != 2 or values.shape[1] != columns:
            raise RecordError(f'{where}: {variable} has shape {values.shape}, expected (n, {columns})')
        if prefix == 'gyro':
            values = values * _gyro_scale(f, where)
        channels.update({f'{prefix}_{axis}': values[:, i] for i, axis in enumerate('xyz')})
    return channels


def read_cats_netcdf(path: str | os.PathLike[str]) -> StaticRecord:
    """Read a CATS tag's record as scikit-diveMove stores it (NetCDF-4, with h5py).

    ``angular_velocity`` (mrad/s) becomes ``gyro_x/y/z`` in deg/s, ``acceleration``
    ``acc_x/y/z`` (m/s^2), ``magnetic_density`` ``mag_x/y/z`` (uT), ``depth`` stays
    (m H2O, a pressure sensor); ``timestamp_utc`` (seconds) is the time.
    """
    where = str(path)
    with _open_netcdf(path, ('timestamp_utc', 'temperature', *CATS_VARIABLES)) as f:
        channels = _triads(f, where, {})
        if 'depth' in f:
            channels['depth'] = np.asarray(f['depth'][...], dtype=float)
        t = np.asarray(f['timestamp_utc'][...], dtype=float)
        temp = np.asarray(f['temperature'][...], dtype=float)
    return StaticRecord(t, temp, channels, where)


def read_phone_netcdf(path: str | os.PathLike[str]) -> StaticRecord:
    """Read a phone's IMU record as scikit-diveMove stores it (``samsung_galaxy_s5.nc``, NetCDF-4).

    Its gyro and magnetometer have two streams each, three ``output`` columns then
    three ``measured`` ones (``gyroscope_type``): the output streams become
    ``gyro_x/y/z`` (deg/s) and ``mag_x/y/z``, the measured gyro stream
    ``gyro_measured_x/y/z``. ``timestamp`` counts samples at the variables'
    ``sampling_rate`` (Hz), which gives the time. A phone logs no temperature: ``temp_c`` is NaN.
    """
    where = str(path)
    with _open_netcdf(path, ('timestamp', 'gyroscope_type', *CATS_VARIABLES)) as f:
        kinds = [k.decode() if isinstance(k, bytes) else str(k) for k in f['gyroscope_type'][...]]
        if kinds != ['output'] * 3 + ['measured'] * 3:
            raise RecordError(f'{where}: gyroscope_type is {kinds}, expected three output then three measured')
        rate = f['angular_velocity'].attrs.get('sampling_rate', np.zeros(0))
        hz = float(np.ravel(rate)[0]) if np.size(rate) == 1 else 0.0
        if not hz > 0.0:
            raise RecordError(f'{where}: angular_velocity has no positive sampling_rate attribute')
        count = np.asarray(f['timestamp'][...], dtype=float)
        channels = _triads(f, where, {'angular_velocity': 2, 'magnetic_density': 2})
        measured = np.asarray(f['angular_velocity'][:, 3:], dtype=float) * _gyro_scale(f, where)
    if not np.array_equal(np.diff(count), np.ones(len(count) - 1)):
        raise RecordError(f'{where}: timestamp does not count samples one by one')
    channels.update({f'gyro_measured_{axis}': measured[:, i] for i, axis in enumerate('xyz')})
    return StaticRecord(count / hz, np.full(len(count), np.nan), channels, where)
