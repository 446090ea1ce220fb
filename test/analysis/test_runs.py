"""Tests of analysis/runs.py: which run a row of a several-run fit belongs to."""

import numpy as np

from art_gyro_calibration.analysis.runs import Run, run_of_rows


def test_run_of_rows_names_the_run_each_row_is_in() -> None:
    runs = [Run('a.csv', 0, 3, True), Run('b.csv', 3, 2, True), Run('c.csv', 5, 4, False)]
    assert [run.stop for run in runs] == [3, 5, 9]
    assert run_of_rows(runs, np.arange(9)).tolist() == [0, 0, 0, 1, 1, 2, 2, 2, 2]
