"""``imu/is_calibrated`` and the covariance of an uncorrected rate, over real DDS from this process.

Until a static bias is in force the published rate is uncorrected: ``imu/is_calibrated`` (transient
local, so a late subscriber hears it too) is false and the yaw variance is
:data:`~art_gyro_calibration.ros.node.UNCORRECTED_YAW_VARIANCE`.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosproc import Listener, domain_id, node_with_listener, wait_until  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402

from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE  # noqa: E402

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
CORRECTED_VARIANCE = 0.001 ** 2   # yaw_rate_stddev's default, squared


class Flag:
    """The values of ``imu/is_calibrated`` a subscription of ``listener``'s node received, in order."""

    def __init__(self, listener: Listener) -> None:
        self._lock = threading.Lock()
        self.values: list[bool] = []
        listener.node.create_subscription(Bool, 'imu/is_calibrated', self._add, LATCHED)

    def _add(self, msg: Bool) -> None:
        with self._lock:
            self.values.append(msg.data)

    def received(self) -> list[bool]:
        """Every value so far."""
        with self._lock:
            return list(self.values)


def test_uncorrected_until_a_static_bias_is_in_force(tmp_path: Path, loopback: None) -> None:
    """The start-up bias refused (turning): false, a large variance, no "previous bias" claimed; then a bias: true."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    with (FakeGyro('NAVC3545', profile='30', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                             '-p', 'bias_samples:=10') as (proc, listener)):
        flag = Flag(listener)
        collecting = listener.wait_imu(3, proc, output)
        assert {m.angular_velocity_covariance[8] for m in collecting} == {UNCORRECTED_YAW_VARIANCE}
        refused = listener.wait_status('static bias', lambda s: s['state'] == 'refused', 'the refusal', proc, output)
        assert 'no bias applied' in refused['message']
        # A subscriber that joins late hears the state too (transient local).
        late = Flag(listener)
        wait_until(lambda: late.received() == [False], 'the late subscriber told false', proc, output)
        after = listener.wait_imu(5, proc, output)
        assert {m.angular_velocity_covariance[8] for m in after} == {UNCORRECTED_YAW_VARIANCE}
        log = output.read_text()
        assert 'static bias refused' in log and 'previous bias kept' not in log, log

        # Still: a bias is taken, and from then on the rate is corrected and said so.
        fake.simulator.profile = RateProfile.parse('0')
        wait_until(lambda: fake.last_sample and abs(fake.last_sample[0]) < 100, 'the fake still')
        response = listener.static_bias(proc, output)
        assert response.success, response.message
        wait_until(lambda: flag.received() == [False, True], 'is_calibrated true', proc, output)
        corrected = listener.wait_imu(5, proc, output)
        assert {m.angular_velocity_covariance[8] for m in corrected} == {CORRECTED_VARIANCE}
        # A refusal now keeps the bias in force, and says so.
        fake.simulator.profile = RateProfile.parse('30')
        wait_until(lambda: fake.last_sample and fake.last_sample[0] > 5000, 'the fake turning')
        response = listener.static_bias(proc, output)
        assert not response.success and 'previous bias kept' in response.message, response.message
        assert listener.wait_imu(3, proc, output)[-1].angular_velocity_covariance[8] == CORRECTED_VARIANCE
        assert flag.received() == [False, True]


def test_a_stop_during_the_start_up_bias_is_clean(tmp_path: Path, loopback: None) -> None:
    """SIGINT while the start-up bias collects: exit 0, no refusal, no error."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    with (FakeGyro('NAVC3545', profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                             '-p', 'bias_samples:=1000') as (proc, listener)):   # stopped by SIGINT: exit 0
        flag = Flag(listener)
        listener.wait_imu(3, proc, output)
        wait_until(lambda: flag.received() == [False], 'is_calibrated false', proc, output)
        listener.wait_status('static bias', lambda s: s['state'] == 'collecting', 'the start-up bias collecting',
                             proc, output)
    log = output.read_text()
    assert 'static bias: collecting 1000 samples' in log
    assert 'refused' not in log and 'ERROR' not in log and 'rosout' not in log, log
