"""``calibrate apply`` on rows whose corrected rate is beyond the unit's range: written uncorrected, counted, said.

They were written as corrected (-114 deg/s from a 0.01 deg/s row, beyond an RD2100's +-99.94), exit 0, not a word.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration
from art_gyro_calibration.terms import Term


def test_rows_corrected_beyond_the_range_are_written_uncorrected_and_counted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 60 deg/s per V on the supply's departure from nominal, fitted over -1..1 V: 1.9 V (within the limits -2..2)
    # makes a correction of 114 deg/s.
    cal = dataclasses.replace(load_packaged_calibration('NAVC3545'),
                              terms=(Term('supply_v', 'power', (60.0,), (1,)),),
                              signal_ranges={'supply_v': (-1.0, 1.0)})
    write_calibration(tmp_path / 'cal.yaml', cal)
    beyond = (150, 160, 270)
    rows = ['t,rate_dps,temp_c,supply_v'] + [f'{i / 10},0.01,25,{1.9 if i in beyond else 0}' for i in range(300)]
    (tmp_path / 'log.csv').write_text('\n'.join(rows) + '\n')
    assert main(['apply', str(tmp_path / 'log.csv'), '--calibration', str(tmp_path / 'cal.yaml'),
                 '--out', str(tmp_path / 'out.csv'), '--bias-samples', '20']) == 0
    err = capsys.readouterr().err
    assert ("3 rows whose corrected rate is beyond the unit's range +-99.9424 deg/s: written uncorrected (the log's "
            "rate), as the node publishes them flagged uncorrected") in err, err
    out = np.loadtxt(tmp_path / 'out.csv', delimiter=',', skiprows=1)
    np.testing.assert_array_equal(out[list(beyond), 4], 0.01)
    assert np.abs(out[:, 4]).max() < 1.0
