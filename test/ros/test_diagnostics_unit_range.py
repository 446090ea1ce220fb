"""gyro_node whose correction goes beyond the unit's range: the rate published uncorrected, flagged, named.

A supply term within its limits (60 deg/s per V at 1.9 V, fitted over -1..1 V) published about -114 deg/s, beyond
an RD2100's +-99.94, with the calibrated covariance and the link OK.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import node_fed_supply, wait_until  # noqa: E402

from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402

CALIBRATED_VARIANCE = 0.001 ** 2   # yaw_rate_stddev's default, squared
OK, ERROR = b'\x00', b'\x02'


def test_a_corrected_rate_beyond_the_range_is_published_uncorrected_flagged_and_named(
        tmp_path: Path, loopback: None) -> None:
    calibration = tmp_path / 'supply.yaml'
    write_calibration(calibration, dataclasses.replace(load_packaged_calibration('NAVC3545'),
                                                       terms=(Term('supply_v', 'power', (60.0,), (1,)),),
                                                       signal_ranges={'supply_v': (-1.0, 1.0)}))
    with node_fed_supply(tmp_path, calibration, 0.0) as (proc, listener, output, set_voltage):
        status = listener.wait_status('link', lambda s: s['level'] == OK, 'the link', proc, output)
        assert status['corrected_beyond_range'] == '0', status

        set_voltage(1.9)   # within the limits -2..2: the term's 114 deg/s takes the rate beyond the range
        status = listener.wait_status('link', lambda s: s['level'] == ERROR, 'the flag', proc, output)
        assert "corrected rates since the last report beyond the unit's range +-99.9424 deg/s (the last -11" \
            in status['message'] and 'published uncorrected, flagged (covariance)' in status['message'], status
        messages = listener.wait_imu(20, proc, output)[5:]
        assert {m.angular_velocity_covariance[8] for m in messages} == {UNCORRECTED_YAW_VARIANCE}
        rates = np.degrees([m.angular_velocity.z for m in messages])
        assert np.all(np.abs(rates) < 1.0), rates   # the rate as measured, not -114 deg/s
        assert int(listener.status('link')['corrected_beyond_range']) > 0

        set_voltage(0.0)
        wait_until(lambda: {m.angular_velocity_covariance[8] for m in listener.wait_imu(5, proc, output)}
                   == {CALIBRATED_VARIANCE}, 'the flag cleared', proc, output)
        listener.wait_status('link', lambda s: s['level'] == OK, 'the link cleared', proc, output)
