"""Several runs of one gyro fitted as one calibration: where each run's rows are, and how it began.

A lab gives several runs of the same gyro (cold starts at different chamber temperatures, a warm
restart). The fit takes their rows one after the other; each run keeps its own turn-on bias and
its own start (its causal signals restart at its first row, a warm-up counts from its power-on
if it had one). :class:`Run` says which rows are whose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.log import GyroLog, LogError, concatenate


@dataclass(frozen=True)
class Run:
    """One run among the rows of a fit: ``rows`` rows from ``first_row``.

    ``name``: the log as the user gave it. ``powered_on_at_start``: the run began at the gyro's
    power-on (a cold start); False for a warm restart.
    """

    name: str
    first_row: int
    rows: int
    powered_on_at_start: bool

    @property
    def stop(self) -> int:
        """The row after the run's last."""
        return self.first_row + self.rows


def run_of_rows(runs: Sequence[Run], rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """The index in ``runs`` of the run each of ``rows`` (rows of the fit) belongs to."""
    starts = np.array([run.first_row for run in runs], dtype=np.int64)
    return np.asarray(np.searchsorted(starts, rows, side='right') - 1, dtype=np.int64)


# A several-run fit lays its runs end to end on one clock (each log has its own, and two may overlap), each
# beginning this long after the one before ended: no bin, steady segment or block of time spans two runs.
RUN_GAP_S = 3600.0


def joined(logs: Sequence[tuple[str, GyroLog, bool]]) -> tuple[GyroLog, tuple[Run, ...]]:
    """Logs of one gyro, (name, log, began at power-on) each, as one log of their rows and the runs in it.

    Each log's clock is shifted to begin :data:`RUN_GAP_S` after the one before ended. The
    logs must have the same columns (a ``ref_rate``, the same extra columns): refused naming
    the log that differs.
    """
    if not logs:
        raise ValueError('a fit needs at least one log')
    first_name, first, _ = logs[0]
    runs: list[Run] = []
    parts: list[GyroLog] = []
    row, end = 0, -np.inf
    for name, log, cold in logs:
        if not len(log):
            raise LogError(f'{name}: no rows to fit')
        if (log.ref_rate is None) != (first.ref_rate is None) or sorted(log.extras) != sorted(first.extras):
            raise LogError(f'{name}: its columns ({_columns(log)}) differ from {first_name}\'s ({_columns(first)}): '
                           'the runs of one fit need the same columns')
        shift = 0.0 if not runs else end + RUN_GAP_S - float(log.t[0])
        parts.append(replace(log, t=log.t + shift) if shift else log)
        end = float(log.t[-1]) + shift
        runs.append(Run(name, row, len(log), cold))
        row += len(log)
    return concatenate(parts), tuple(runs)


def _columns(log: GyroLog) -> str:
    return ', '.join(['t', 'rate', 'temperature', *(('ref_rate',) if log.ref_rate is not None else ()),
                      *sorted(log.extras)])


def run_starts(runs: Sequence[Run]) -> tuple[tuple[int, bool], ...]:
    """:attr:`Signals.run_starts` of ``runs``: () for one run (the signals' ``powered_on_at_start`` says how)."""
    return tuple((run.first_row, run.powered_on_at_start) for run in runs) if len(runs) > 1 else ()
