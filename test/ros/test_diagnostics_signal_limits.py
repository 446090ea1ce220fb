"""gyro_node fed a supply voltage far beyond the range its term was fitted over: flagged, named, bounded.

24000 (millivolts sent as volts) on a 0.05 deg/s per V term published -1199 deg/s with the calibrated
covariance, and the signal's status read OK.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import node_fed_supply, wait_until  # noqa: E402

from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration  # noqa: E402
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
    calibration = _calibration(tmp_path / 'supply.yaml')
    with node_fed_supply(tmp_path, calibration, 24.0) as (proc, listener, output, set_voltage):
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == OK, 'a voltage', proc, output)
        assert status['limits'] == '22..26' and status['beyond_limits'] == '0', status

        set_voltage(24000.0)   # millivolts sent as volts
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == ERROR, 'the flag', proc, output)
        assert status['message'].startswith(
            'supply_v 24000 is beyond 22..26 (the range it was fitted over, 23..25, and half that each side): applied '
            'as 26 on /supply: the rate is flagged uncorrected (covariance)'), status
        messages = listener.wait_imu(20, proc, output)[5:]
        assert {m.angular_velocity_covariance[8] for m in messages} == {UNCORRECTED_YAW_VARIANCE}
        rates = np.degrees([m.angular_velocity.z for m in messages])
        assert np.all(np.abs(rates - -2.0 * COEFFICIENT) < 0.05), rates   # the term at 26 V, not at 24000
        assert int(listener.status('extra signal supply_v')['beyond_limits']) > 0

        set_voltage(24.0)
        wait_until(lambda: {m.angular_velocity_covariance[8] for m in listener.wait_imu(5, proc, output)}
                   == {CALIBRATED_VARIANCE}, 'the flag cleared', proc, output)
        listener.wait_status('extra signal supply_v', lambda s: s['level'] == OK, 'the status cleared', proc, output)
