"""Overlapping Allan deviation of a rate: how much of what is left is random, and of which kind.

For a rate sampled at ``fs``, the Allan deviation at ``tau = m / fs`` is the spread of
the difference between consecutive ``tau``-averages. White rate noise (angle random
walk) falls as ``tau**-1/2``, bias instability is the flat floor, a rate random walk
rises as ``tau**1/2`` and a deterministic drift left in the data as ``tau**1``.

:class:`AllanAccumulator` takes a record chunk by chunk and holds its angle (the running
sum of the rate) in memory up to ``memory_samples`` and in an unnamed temporary file
beyond: a day at 1 kHz (86.4 million samples) is computed in a few tens of MiB. Every
overlapping difference is summed, as ``allantools.oadev`` sums them.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

Floats = NDArray[np.float64]
# Angle samples kept in memory before the store spills to a temporary file (32 MiB).
MEMORY_SAMPLES = 1 << 22
# Differences summed per block: a block small enough for the CPU cache at short taus,
# larger ones (fewer reads) at long taus, where each block's window is read from the store.
_SHORT_BLOCK = 1 << 16
_SHORT_MAX_M = 1 << 14
_LONG_BLOCK = 1 << 21
_WINDOW_MAX_M = 1 << 20


@dataclass(frozen=True)
class AllanDeviation:
    """Allan deviation ``adev`` (units of the rate) at averaging times ``tau_s``.

    ``terms`` is how many overlapping differences each value averages; the relative
    uncertainty of a value is about ``1 / sqrt(terms / m)`` (the independent ones).
    ``samples`` is the record's length (0 when pooled over runs of several lengths).
    """

    tau_s: NDArray[np.float64]
    adev: NDArray[np.float64]
    terms: NDArray[np.int_]
    samples: int = 0

    def at(self, tau_s: float) -> float:
        """Allan deviation at ``tau_s``, interpolated log-log between the computed taus."""
        if not self.tau_s[0] <= tau_s <= self.tau_s[-1]:
            raise ValueError(f'tau {tau_s} s is outside the computed {self.tau_s[0]}..{self.tau_s[-1]} s')
        return float(np.exp(np.interp(np.log(tau_s), np.log(self.tau_s), np.log(self.adev))))

    def degrees_of_freedom(self, sample_rate_hz: float) -> NDArray[np.float64]:
        """Equivalent degrees of freedom of each value, for white rate noise (the gyro's dominant one).

        The simple approximation of Howe, Allan and Barnes (1981), as NIST SP 1065 (5.2.4) gives it for
        the overlapping Allan variance and white FM noise: ``((3(N-1)/(2m) - 2(N-2)/N) 4m^2/(4m^2+5)``
        with N the record's angle points and m the averaging factor; at least 1. Over pooled runs, N is
        the length of one record with as many differences (``terms + 2m``).
        """
        m = np.rint(self.tau_s * sample_rate_hz)
        n = self.terms + 2.0 * m
        edf = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)
        return np.maximum(edf, 1.0)

    def confidence(self, sample_rate_hz: float, level: float = 0.683) -> tuple[Floats, Floats]:
        """Lower and upper bounds of each value at ``level``: the chi-squared interval of its variance."""
        from scipy.stats import chi2  # type: ignore[import-untyped]  # scipy ships no types
        edf = self.degrees_of_freedom(sample_rate_hz)
        low = self.adev * np.sqrt(edf / chi2.ppf(0.5 + level / 2.0, edf))
        high = self.adev * np.sqrt(edf / chi2.ppf(0.5 - level / 2.0, edf))
        return low, high


class _AngleStore:
    """The angle samples, appended chunk by chunk; in memory, then in an unnamed temporary file."""

    def __init__(self, memory_samples: int, directory: str | None) -> None:
        self._memory: list[NDArray[np.float64]] = []
        self._array: NDArray[np.float64] | None = None
        self._file: int | None = None
        self._limit = memory_samples
        self._directory = directory
        self.size = 0

    def append(self, values: NDArray[np.float64]) -> None:
        if self._file is None and self.size + len(values) > self._limit:
            handle, name = tempfile.mkstemp(prefix='.allan-', dir=self._directory)
            os.unlink(name)   # unnamed: gone with the process, whatever ends it
            self._file = handle
            for part in self._memory:
                os.write(handle, part.tobytes())
            self._memory = []
        if self._file is None:
            self._memory.append(values.copy())
        else:
            view = np.ascontiguousarray(values).data.cast('B')
            while view:
                view = view[os.write(self._file, view):]
        self.size += len(values)

    def read(self, start: int, count: int) -> NDArray[np.float64]:
        if self._file is None:
            if self._array is None or len(self._array) != self.size:
                self._array = np.concatenate(self._memory) if self._memory else np.empty(0)
                self._memory = [self._array]
            return self._array[start:start + count]
        out = np.empty(max(min(count, self.size - start), 0))
        view = out.data.cast('B')
        done = 0
        while done < len(view):
            got = os.preadv(self._file, [view[done:]], 8 * start + done)
            if not got:
                raise OSError(f'Allan deviation: temporary angle file ended at sample {start + done // 8}')
            done += got
        return out

    def close(self) -> None:
        if self._file is not None:
            os.close(self._file)
            self._file = None
        self._memory, self._array = [], None


@dataclass
class AllanSums:
    """Per averaging factor ``m``: the sum of squared second differences of the angle and their count."""

    m: list[int] = field(default_factory=list)
    squares: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)


class AllanAccumulator:
    """Overlapping Allan deviation of a rate given chunk by chunk, in bounded memory.

    The angle is the running sum of the rate less the first chunk's mean (a constant does not
    change the deviation; taking it out keeps the angle's rounding small, as ``allantools``
    takes the mean out). Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, memory_samples: int = MEMORY_SAMPLES, directory: str | None = None) -> None:
        self._store = _AngleStore(memory_samples, directory)
        self._offset: float | None = None
        self._angle = 0.0
        self.samples = 0

    def __enter__(self) -> AllanAccumulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the store (its temporary file)."""
        self._store.close()

    def add(self, rate: ArrayLike) -> None:
        """Append consecutive, equally spaced samples of the rate."""
        x = np.asarray(rate, dtype=float)
        if x.ndim != 1 or not np.all(np.isfinite(x)):
            raise ValueError(f'rate must be a 1-D array of finite numbers (samples {self.samples} on)')
        if not len(x):
            return
        if self._offset is None:
            self._offset = float(np.mean(x))
            self._store.append(np.zeros(1))
        angle = np.cumsum(np.concatenate(([self._angle], x - self._offset)))[1:]
        self._store.append(angle)
        self._angle = float(angle[-1])
        self.samples += len(x)

    def sums(self, min_clusters: int = 3) -> AllanSums:
        """Sums of squared second differences at m = 1, 2, 4, ... while ``m * min_clusters <= samples``."""
        out = AllanSums()
        points = self._store.size
        m = 1
        while m * min_clusters <= self.samples:
            out.m.append(m)
            m *= 2
        out.squares = [0.0] * len(out.m)
        out.counts = [max(points - 2 * k, 0) for k in out.m]
        short = [i for i, k in enumerate(out.m) if k <= _SHORT_MAX_M]
        window = [i for i, k in enumerate(out.m) if _SHORT_MAX_M < k <= _WINDOW_MAX_M]
        # The dot products are of cache-sized blocks: a multi-threaded BLAS spin-waits on them
        # (measured 3 ms against 0.2 ms a block on a loaded machine).
        from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]
        with threadpool_limits(limits=1, user_api='blas'):
            self._windowed(out, short, _SHORT_BLOCK)
            self._windowed(out, window, _LONG_BLOCK)
            for i in range(len(out.m)):
                if out.m[i] > _WINDOW_MAX_M:
                    self._three_reads(out, i)
        return out

    def _windowed(self, out: AllanSums, levels: list[int], block: int) -> None:
        """Levels whose differences a window of ``block + 2 max(m)`` angle points holds: one read per block."""
        if not levels:
            return
        reach = 2 * max(out.m[i] for i in levels)
        points = self._store.size
        a = np.empty(block)
        b = np.empty(block)
        for start in range(0, points - 2 * out.m[levels[0]], block):
            w = self._store.read(start, block + reach)
            for i in levels:
                m = out.m[i]
                n = min(block, points - 2 * m - start)
                if n <= 0:
                    continue
                d, twice = a[:n], b[:n]
                np.add(w[2 * m:2 * m + n], w[:n], out=d)
                np.multiply(w[m:m + n], 2.0, out=twice)
                d -= twice
                out.squares[i] += float(np.dot(d, d))

    def _three_reads(self, out: AllanSums, i: int) -> None:
        """A long tau: the three angle windows of each block read apart."""
        m, points = out.m[i], self._store.size
        for start in range(0, points - 2 * m, _LONG_BLOCK):
            n = min(_LONG_BLOCK, points - 2 * m - start)
            d = self._store.read(start + 2 * m, n) + self._store.read(start, n)
            d -= 2.0 * self._store.read(start + m, n)
            out.squares[i] += float(np.dot(d, d))

    def result(self, sample_rate_hz: float, min_clusters: int = 3) -> AllanDeviation:
        """The Allan deviation of everything added, the rate sampled at ``sample_rate_hz``."""
        if not sample_rate_hz > 0:
            raise ValueError(f'sample rate must be positive, got {sample_rate_hz}')
        if self.samples < 2 * min_clusters:
            raise ValueError(f'{self.samples} samples are too few for an Allan deviation')
        s = self.sums(min_clusters)
        return _deviation([s], sample_rate_hz, self.samples)


def _deviation(runs: Iterable[AllanSums], sample_rate_hz: float, samples: int) -> AllanDeviation:
    """Pool the runs' sums per m into the deviation (differences in units of rate x samples)."""
    squares: dict[int, float] = {}
    counts: dict[int, int] = {}
    for run in runs:
        for m, total, n in zip(run.m, run.squares, run.counts):
            if n > 0:
                squares[m] = squares.get(m, 0.0) + total
                counts[m] = counts.get(m, 0) + n
    ms = np.array(sorted(squares), dtype=float)
    adev = np.array([np.sqrt(squares[int(m)] / (2.0 * m * m * counts[int(m)])) for m in ms])
    return AllanDeviation(ms / sample_rate_hz, adev, np.array([counts[int(m)] for m in ms]), samples)


def allan_deviation(rate: ArrayLike, sample_rate_hz: float, run: ArrayLike | None = None,
                    min_clusters: int = 3) -> AllanDeviation:
    """Overlapping Allan deviation at octave-spaced ``tau`` (1, 2, 4, ... samples).

    ``run`` labels contiguous stretches of equally spaced samples (a log with gaps
    where the instrument moved): differences never span two runs, and each tau
    pools the differences of every run long enough for it. Taus go up to where
    the longest run still holds ``min_clusters`` non-overlapping averages.
    """
    x = np.asarray(rate, dtype=float)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError('rate must be a 1-D array of finite numbers')
    if not sample_rate_hz > 0:
        raise ValueError(f'sample rate must be positive, got {sample_rate_hz}')
    labels = np.zeros(len(x), dtype=int) if run is None else np.asarray(run)
    if labels.shape != x.shape:
        raise ValueError(f'run has shape {labels.shape}, rate has {x.shape}')
    starts = np.flatnonzero(np.concatenate(([True], labels[1:] != labels[:-1], [True])))
    longest = int(np.max(np.diff(starts))) if len(x) else 0
    if longest < 2 * min_clusters:
        raise ValueError(f'{longest} samples in the longest run are too few for an Allan deviation')
    sums = []
    for a, b in zip(starts[:-1], starts[1:]):
        with AllanAccumulator(memory_samples=b - a + 2) as acc:
            acc.add(x[a:b])
            s = acc.sums(1)
            # The taus are those of the longest run; a shorter run adds to those it is long enough for.
            keep = [i for i, m in enumerate(s.m) if m * min_clusters <= longest]
            sums.append(AllanSums([s.m[i] for i in keep], [s.squares[i] for i in keep], [s.counts[i] for i in keep]))
    return _deviation(sums, sample_rate_hz, len(x) if len(sums) == 1 else 0)
