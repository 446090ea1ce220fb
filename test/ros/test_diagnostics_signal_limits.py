"""gyro_node fed a supply voltage far beyond the range its term was fitted over: flagged, named, bounded.

24000 (millivolts sent as volts) on a 0.05 deg/s per V term published -1199 deg/s with the calibrated
covariance, and the signal's status read OK.
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
from art_gyro_calibration.model import ArtPolynomial  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402

COEFFICIENT = 0.05   # deg/s per volt
CALIBRATED_VARIANCE = 0.001 ** 2   # yaw_rate_stddev's default, squared
OK, ERROR = b'\x00', b'\x02'


def _calibration(path: Path) -> Path:
    """NAVC3545 with a supply term fitted over 23..25 V, its constant at 24 V in the polynomial."""
    cal = load_packaged_calibration('NAVC3545')
    coefficients = cal.polynomial.coefficients.copy()
    coefficients[-1, -1] -= COEFFICIENT * 24.0
    write_calibration(path, dataclasses.replace(cal, polynomial=ArtPolynomial(coefficients),
                                                terms=(Term('supply_v', 'power', (COEFFICIENT,), (1,)),),
                                                signal_ranges={'supply_v': (23.0, 25.0)}))
    return path


def test_a_voltage_beyond_the_fitted_range_is_flagged_named_and_applied_at_the_limit(
        tmp_path: Path, loopback: None) -> None:
    domain = domain_id()
    output = tmp_path / 'node.log'
    calibration = _calibration(tmp_path / 'supply.yaml')
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={calibration}',
                             '-p', f'port:={fake.path}', '-p', 'bias_samples:=20',
                             '-p', 'extra_signals.supply_v.topic:=supply') as (proc, listener)):
        voltage = [24.0]
        lock = threading.Lock()
        publisher = listener.node.create_publisher(Float64, 'supply', 10)

        def publish() -> None:
            with lock:
                publisher.publish(Float64(data=voltage[0]))
        listener.node.create_timer(0.05, publish)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the static bias', proc, output)
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == OK, 'a voltage', proc, output)
        assert status['limits'] == '22..26' and status['beyond_limits'] == '0', status

        with lock:
            voltage[0] = 24000.0   # millivolts sent as volts
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == ERROR, 'the flag', proc, output)
        assert status['message'].startswith(
            'supply_v 24000 is beyond 22..26 (the range it was fitted over, 23..25, and half that each side): applied '
            'as 26 on /supply: the rate is flagged uncorrected (covariance)'), status
        messages = listener.wait_imu(20, proc, output)[5:]
        assert {m.angular_velocity_covariance[8] for m in messages} == {UNCORRECTED_YAW_VARIANCE}
        rates = np.degrees([m.angular_velocity.z for m in messages])
        assert np.all(np.abs(rates - -2.0 * COEFFICIENT) < 0.05), rates   # the term at 26 V, not at 24000
        assert int(listener.status('extra signal supply_v')['beyond_limits']) > 0

        with lock:
            voltage[0] = 24.0
        wait_until(lambda: {m.angular_velocity_covariance[8] for m in listener.wait_imu(5, proc, output)}
                   == {CALIBRATED_VARIANCE}, 'the flag cleared', proc, output)
        listener.wait_status('extra signal supply_v', lambda s: s['level'] == OK, 'the status cleared', proc, output)
