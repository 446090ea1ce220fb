"""The parked bias end to end: a node on a fake gyro that turns, stops and creeps, told it is parked by a topic."""

from __future__ import annotations

import math
import re
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip('rclpy')
nav_msgs = pytest.importorskip('nav_msgs.msg')

from rosproc import Listener, domain_id, node_with_listener  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402

from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile  # noqa: E402

RATE_HZ = 50
# 2 s windows: at 50 Hz the fake's noise (0.011 deg/s a sample) leaves the gyro-stillness bound near 0.009 deg/s.
NODE_ARGS = ('-p', 'serial_number:=NAVC3545', '-p', 'bias_samples:=100', '-p', 'parked_bias.enabled:=true',
             '-p', 'parked_bias.settle_s:=0.5', '-p', 'parked_bias.min_interval_s:=3600.0')
CREEPS_DPS = (0.05, 0.1, 0.5)


class Robot:
    """What the robot publishes at 20 Hz from the listener's node: a Bool ``parked``, or odometry ``odom``."""

    def __init__(self, listener: Listener, odometry: bool) -> None:
        self._lock = threading.Lock()
        self._value: Any = False if not odometry else 0.0   # parked, or the odometry's yaw rate (deg/s)
        self._odometry = odometry
        self._pub = listener.node.create_publisher(nav_msgs.Odometry if odometry else Bool,
                                                   'odom' if odometry else 'parked', 10)
        listener.node.create_timer(0.05, self._publish)

    def set(self, value: Any) -> None:
        """Parked (bool), or the odometry's yaw rate (deg/s); None: silent."""
        with self._lock:
            self._value = value

    def _publish(self) -> None:
        with self._lock:
            value = self._value
        if value is None:   # silent
            return
        if self._odometry:
            message = nav_msgs.Odometry()
            message.twist.twist.angular.z = math.radians(value)
            self._pub.publish(message)
        else:
            self._pub.publish(Bool(data=value))


def parked_biases(output: Path) -> list[float]:
    """The StaticBiasDrift of each parked bias the node logged."""
    return [float(v) for v in re.findall(r'parked bias: StaticBiasDrift=(-?[0-9.]+) deg/s', output.read_text())]


def drive(fake: FakeGyro, rate_dps: float) -> None:
    """The fake gyro's true rate from now."""
    fake.simulator.profile = RateProfile.parse(str(rate_dps))


@contextmanager
def parked_node(tmp_path: Path, seed: int, *ros_args: str
                ) -> Iterator[tuple[FakeGyro, subprocess.Popen[bytes], Listener, Path]]:
    """A still fake gyro at RATE_HZ and ``gyro_node`` on it with NODE_ARGS and ``ros_args``, and its output file."""
    output = tmp_path / 'node.log'
    with (FakeGyro('NAVC3545', rate_hz=RATE_HZ, profile='0', temperature=25.0, seed=seed) as fake,
          node_with_listener(domain_id(), output, *NODE_ARGS, '-p', f'port:={fake.path}', *ros_args)
          as (proc, listener)):
        yield fake, proc, listener, output


def wait_parked(listener: Listener, proc: subprocess.Popen[bytes], output: Path, key: str, value: str,
                what: str) -> dict[str, Any]:
    return listener.wait_status('parked bias', lambda s: s[key] == value, what, proc, output)


def test_a_bool_and_the_gyro_stillness_take_a_bias_at_a_stop_and_none_while_creeping(
        tmp_path: Path, loopback: None) -> None:
    with parked_node(tmp_path, 11, '-p', 'parked_bias.topic:=parked', '-p', 'parked_bias.gyro_stillness:=true') \
            as (fake, proc, listener, output):
        robot = Robot(listener, odometry=False)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the start-up bias', proc, output)
        # The robot turns, then stops and parks: a parked bias.
        drive(fake, 30.0)
        time.sleep(1.0)
        drive(fake, 0.0)
        robot.set(True)
        status = wait_parked(listener, proc, output, 'updates', '1', 'a parked bias')
        assert status['refused'] == '0', status
        assert len(parked_biases(output)) == 1, output.read_text()
        # It creeps while the Bool says parked: the gyro's stillness refuses each (the mean check).
        for n, creep in enumerate(CREEPS_DPS, 1):
            robot.set(False)
            drive(fake, creep)
            time.sleep(0.3)
            robot.set(True)
            status = wait_parked(listener, proc, output, 'refused_mean', str(n), f'the creep at {creep} refused')
            assert status['updates'] == '1', status
        refusals = re.findall(r'parked bias refused, previous bias kept: (mean compensated rate .*)',
                              output.read_text())
        assert len(refusals) == len(CREEPS_DPS), output.read_text()
        # Still again: taken.
        robot.set(False)
        drive(fake, 0.0)
        time.sleep(0.3)
        robot.set(True)
        wait_parked(listener, proc, output, 'updates', '2', 'a parked bias after the creeps')
        assert len(parked_biases(output)) == 2


def test_odometry_reporting_a_creep_is_not_parked(tmp_path: Path, loopback: None) -> None:
    with parked_node(tmp_path, 12, '-p', 'parked_bias.topic:=odom', '-p', 'parked_bias.type:=odometry') \
            as (fake, proc, listener, output):
        robot = Robot(listener, odometry=True)
        robot.set(30.0)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the start-up bias', proc, output)
        for creep in CREEPS_DPS:   # over settle_s and a window each: never parked, no collection
            drive(fake, creep)
            robot.set(creep)
            time.sleep(3.0)
            status = wait_parked(listener, proc, output, 'parked', 'False', 'the odometry creeping')
            assert (status['updates'], status['state'], status['refused']) == ('0', 'waiting', '0'), status
        assert 'parked bias: collecting' not in output.read_text()
        drive(fake, 0.0)
        robot.set(0.0)
        wait_parked(listener, proc, output, 'updates', '1', 'a parked bias once the odometry stops')
        assert len(parked_biases(output)) == 1


def test_a_collection_is_aborted_when_the_robot_moves_or_its_topic_falls_silent(
        tmp_path: Path, loopback: None) -> None:
    # 8 s collections: the test sees "collecting" up to a diagnostics period late, and on a loaded machine a 2 s
    # collection could end before the topic's silence (1 s) aborts it.
    with parked_node(tmp_path, 13, '-p', 'parked_bias.topic:=parked', '-p', 'bias_samples:=400') \
            as (fake, proc, listener, output):
        robot = Robot(listener, odometry=False)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the start-up bias', proc, output)
        for n, (stop, reason) in enumerate(((False, 'moved'), (None, 'stale')), 1):
            robot.set(True)
            wait_parked(listener, proc, output, 'state', 'collecting', 'a parked collection')
            robot.set(stop)
            status = wait_parked(listener, proc, output, f'refused_{reason}', '1', f'the collection aborted: {reason}')
            assert (status['updates'], status['refused']) == ('0', str(n)), status
            assert status['last_refusal'].startswith(f'{reason}: '), status
        static = listener.status('static bias')
        assert static is not None and static['state'] == 'ok', static   # the start-up bias kept, no service refusal
