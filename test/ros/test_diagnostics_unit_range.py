"""gyro_node whose correction goes beyond the unit's range: the rate published uncorrected, flagged, named.

A supply term within its limits (60 deg/s per V at 1.9 V, fitted over -1..1 V) published about -114 deg/s, beyond
an RD2100's +-99.94, with the calibrated covariance and the link OK.
"""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import domain_id, node_with_listener, wait_until  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402

CALIBRATED_VARIANCE = 0.001 ** 2   # yaw_rate_stddev's default, squared
OK, ERROR = b'\x00', b'\x02'


def test_a_corrected_rate_beyond_the_range_is_published_uncorrected_flagged_and_named(
        tmp_path: Path, loopback: None) -> None:
    domain = domain_id()
    output = tmp_path / 'node.log'
    calibration = tmp_path / 'supply.yaml'
    write_calibration(calibration, dataclasses.replace(load_packaged_calibration('NAVC3545'),
                                                       terms=(Term('supply_v', 'power', (60.0,), (1,)),),
                                                       signal_ranges={'supply_v': (-1.0, 1.0)}))
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={calibration}',
                             '-p', f'port:={fake.path}', '-p', 'bias_samples:=20',
                             '-p', 'extra_signals.supply_v.topic:=supply') as (proc, listener)):
        voltage = [0.0]
        lock = threading.Lock()
        publisher = listener.node.create_publisher(Float64, 'supply', 10)

        def publish() -> None:
            with lock:
                publisher.publish(Float64(data=voltage[0]))
        listener.node.create_timer(0.05, publish)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the static bias', proc, output)
        status = listener.wait_status('link', lambda s: s['level'] == OK, 'the link', proc, output)
        assert status['corrected_beyond_range'] == '0', status

        with lock:
            voltage[0] = 1.9   # within the limits -2..2: the term's 114 deg/s takes the rate beyond the range
        status = listener.wait_status('link', lambda s: s['level'] == ERROR, 'the flag', proc, output)
        assert "corrected rates since the last report beyond the unit's range +-99.9424 deg/s (the last -11" \
            in status['message'] and 'published uncorrected, flagged (covariance)' in status['message'], status
        messages = listener.wait_imu(20, proc, output)[5:]
        assert {m.angular_velocity_covariance[8] for m in messages} == {UNCORRECTED_YAW_VARIANCE}
        rates = np.degrees([m.angular_velocity.z for m in messages])
        assert np.all(np.abs(rates) < 1.0), rates   # the rate as measured, not -114 deg/s
        assert int(listener.status('link')['corrected_beyond_range']) > 0

        with lock:
            voltage[0] = 0.0
        wait_until(lambda: {m.angular_velocity_covariance[8] for m in listener.wait_imu(5, proc, output)}
                   == {CALIBRATED_VARIANCE}, 'the flag cleared', proc, output)
        listener.wait_status('link', lambda s: s['level'] == OK, 'the link cleared', proc, output)
