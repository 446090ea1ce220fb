"""Several runs of one gyro fitted as one calibration: where each run's rows are, and how it began.

A lab gives several runs of the same gyro (cold starts at different chamber temperatures, a warm
restart). The fit takes their rows one after the other; each run keeps its own turn-on bias and
its own start (its causal signals restart at its first row, a warm-up counts from its power-on
if it had one). :class:`Run` says which rows are whose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


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
