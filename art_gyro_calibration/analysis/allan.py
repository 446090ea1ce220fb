"""Overlapping Allan deviation of a rate: how much of what is left is random, and of which kind.

For a rate sampled at ``fs``, the Allan deviation at ``tau = m / fs`` is the spread of
the difference between consecutive ``tau``-averages. White rate noise (angle random
walk) falls as ``tau**-1/2``, bias instability is the flat floor, a rate random walk
rises as ``tau**1/2`` and a deterministic drift left in the data as ``tau**1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class AllanDeviation:
    """Allan deviation ``adev`` (units of the rate) at averaging times ``tau_s``.

    ``terms`` is how many overlapping differences each value averages; the relative
    uncertainty of a value is about ``1 / sqrt(terms / m)`` (the independent ones).
    """

    tau_s: NDArray[np.float64]
    adev: NDArray[np.float64]
    terms: NDArray[np.int_]

    def at(self, tau_s: float) -> float:
        """Allan deviation at ``tau_s``, interpolated log-log between the computed taus."""
        if not self.tau_s[0] <= tau_s <= self.tau_s[-1]:
            raise ValueError(f'tau {tau_s} s is outside the computed {self.tau_s[0]}..{self.tau_s[-1]} s')
        return float(np.exp(np.interp(np.log(tau_s), np.log(self.tau_s), np.log(self.adev))))


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
    pieces = [x[a:b] for a, b in zip(starts[:-1], starts[1:])]
    longest = max(len(p) for p in pieces)
    if longest < 2 * min_clusters:
        raise ValueError(f'{longest} samples in the longest run are too few for an Allan deviation')
    # Angle (integral of rate) of each run, so each tau-average is a difference of two angles.
    angles = [np.concatenate(([0.0], np.cumsum(p))) / sample_rate_hz for p in pieces]
    taus, adevs, counts = [], [], []
    m = 1
    while m * min_clusters <= longest:
        total, n = 0.0, 0
        for theta in angles:
            if len(theta) > 2 * m:
                d = theta[2 * m:] - 2.0 * theta[m:-m] + theta[:-2 * m]
                total += float(d @ d)
                n += len(d)
        tau = m / sample_rate_hz
        taus.append(tau)
        adevs.append(np.sqrt(total / (2.0 * tau * tau * n)))
        counts.append(n)
        m *= 2
    return AllanDeviation(np.array(taus), np.array(adevs), np.array(counts))
