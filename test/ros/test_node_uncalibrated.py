"""``publish_uncalibrated``: the node publishes what a calibration needs, and a bag of it is the raw log's equal.

The listener here records what it hears into a rosbag2 (MCAP, with ``rosbags``), as ``ros2
bag record`` would; ``calibrate apply`` on that bag gives what it gives on the node's own
raw log (``log_path``) of the same run.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from rosproc import domain_id, node_with_listener, wait_until  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

from art_gyro_calibration.analysis.cli import main  # noqa: E402
from art_gyro_calibration.calibration import load_packaged_calibration  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile  # noqa: E402
from art_gyro_calibration.log import read_log  # noqa: E402

BIAS_SAMPLES = 20


def test_uncalibrated_rate_beside_the_temperature_records_a_bag_for_calibrate(
        tmp_path: Path, loopback: None, capsys: pytest.CaptureFixture[str]) -> None:
    log_path = tmp_path / 'node.csv'
    output = tmp_path / 'node.log'
    fake = FakeGyro('NAVC3545', rate_hz=50.0, profile='0', seed=3)
    heard: list[tuple[str, int, bytes]] = []
    uncalibrated: list[Imu] = []
    lock = threading.Lock()

    def record(topic: str):
        def callback(message) -> None:
            with lock:
                heard.append((topic, time.time_ns(), serialize_message(message)))
                if topic == '/imu/uncalibrated':
                    uncalibrated.append(message)
        return callback
    try:
        with node_with_listener(domain_id(), output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                                '-p', 'baud:=115200', '-p', f'bias_samples:={BIAS_SAMPLES}',
                                '-p', f'log_path:={log_path}', '-p', 'publish_uncalibrated:=true') as (proc, listener):
            from std_msgs.msg import Float64
            listener.node.create_subscription(Imu, 'imu/uncalibrated', record('/imu/uncalibrated'), 100)
            listener.node.create_subscription(Float64, 'imu/temperature', record('/imu/temperature'), 100)
            wait_until(lambda: listener.history() and listener.node.count_publishers('imu/uncalibrated'),
                       'the node discovered with imu/uncalibrated', proc, output)
            time.sleep(1.0)
            fake.start()
            listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the startup static bias', proc, output)
            fake.simulator.profile = RateProfile.parse('0.6:30,0.6:-45')
            time.sleep(1.5)
            fake.stop()
            link = listener.wait_status('link', lambda s: s['connected'] == 'False', 'the fake gone', proc, output)
            published = int(link['published'])
            wait_until(lambda: listener.count() >= published and len(uncalibrated) >= published
                       and sum(t == '/imu/temperature' for t, _, _ in heard) >= published,
                       'every message published', proc, output)
            calibrated = listener.imu_since(0)
    finally:
        fake.stop()
    scale = load_packaged_calibration('NAVC3545').rate_scale_factor
    raw = np.loadtxt(log_path, delimiter=',', skiprows=1)
    assert len(uncalibrated) == len(calibrated) == len(raw) == published > 100
    # Only the scale factor: the raw log's counts times it, in rad/s, at the calibrated message's stamps.
    assert [m.header.stamp for m in uncalibrated] == [m.header.stamp for m in calibrated]
    assert np.array_equal([m.angular_velocity.z for m in uncalibrated], np.radians(raw[:, 1] * scale))
    assert uncalibrated[0].header.frame_id == 'imu_link'
    assert uncalibrated[0].angular_velocity_covariance[8] == calibrated[0].angular_velocity_covariance[8]
    assert np.ptp(np.degrees([m.angular_velocity.z for m in uncalibrated])) > 60   # it turned

    bag = tmp_path / 'bag'
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {'/imu/uncalibrated': writer.add_connection('/imu/uncalibrated', 'sensor_msgs/msg/Imu',
                                                                  typestore=store),
                       '/imu/temperature': writer.add_connection('/imu/temperature', 'std_msgs/msg/Float64',
                                                                 typestore=store)}
        for topic, stamp, data in sorted(heard, key=lambda h: h[1]):
            writer.write(connections[topic], stamp, data)
    capsys.readouterr()
    outs = []
    for source in (log_path, bag):
        out = tmp_path / f'{source.stem}.out.csv'
        assert main(['apply', str(source), '--calibration',
                     str(Path(__file__).resolve().parents[2] / 'config' / 'NAVC3545.yaml'), '--out', str(out),
                     '--bias-samples', str(BIAS_SAMPLES)]) == 0
        outs.append(read_log(out))
    from_log, from_bag = outs
    assert np.array_equal(from_bag.t, from_log.t)
    assert np.allclose(from_bag.extras['corrected_dps'], from_log.extras['corrected_dps'], rtol=0, atol=2e-9)
    assert math.isclose(float(np.ptp(from_bag.rate_dps)), float(np.ptp(from_log.rate_dps)), abs_tol=2e-9)


def test_no_uncalibrated_topic_by_default(tmp_path: Path, loopback: None) -> None:
    output = tmp_path / 'node.log'
    fake = FakeGyro('NAVC3545', rate_hz=20.0, profile='0', seed=4)
    try:
        with node_with_listener(domain_id(), output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                                '-p', 'baud:=115200') as (proc, listener):
            fake.start()
            listener.wait_imu(5, proc, output)
            assert listener.node.count_publishers('imu/data_raw') == 1
            assert listener.node.count_publishers('imu/uncalibrated') == 0
    finally:
        fake.stop()
