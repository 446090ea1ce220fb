"""Tests of analysis/runs.py: which run a row of a several-run fit belongs to."""

import numpy as np
import pytest

from art_gyro_calibration.analysis.runs import RUN_GAP_S, Run, joined, run_of_rows, run_starts
from art_gyro_calibration.log import GyroLog, LogError


def test_run_of_rows_names_the_run_each_row_is_in() -> None:
    runs = [Run('a.csv', 0, 3, True), Run('b.csv', 3, 2, True), Run('c.csv', 5, 4, False)]
    assert [run.stop for run in runs] == [3, 5, 9]
    assert run_of_rows(runs, np.arange(9)).tolist() == [0, 0, 0, 1, 1, 2, 2, 2, 2]


def _log(t0: float, n: int, extras: tuple[str, ...] = ()) -> GyroLog:
    t = t0 + np.arange(n, dtype=float)
    return GyroLog(t, np.zeros(n), np.full(n, 20.0), np.zeros(n), {name: np.ones(n) for name in extras})


def test_joined_runs_lie_end_to_end_on_one_clock() -> None:
    """Each log keeps its rows and its own steps of time; the second begins RUN_GAP_S after the first ended."""
    log, runs = joined([('a.csv', _log(100.0, 5), True), ('b.csv', _log(0.0, 3), False)])   # b's clock overlaps a's
    assert runs == (Run('a.csv', 0, 5, True), Run('b.csv', 5, 3, False))
    assert log.t.tolist() == [100.0, 101.0, 102.0, 103.0, 104.0, *(104.0 + RUN_GAP_S + k for k in range(3))]
    assert run_starts(runs) == ((0, True), (5, False)) and run_starts(runs[:1]) == ()


def test_runs_with_other_columns_are_refused_naming_the_log() -> None:
    with pytest.raises(LogError, match='b.csv: its columns .*supply_v'):
        joined([('a.csv', _log(0.0, 5), True), ('b.csv', _log(0.0, 5, ('supply_v',)), True)])
