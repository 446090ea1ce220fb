"""``imu_echo``: print the compensated yaw rate the node publishes, in deg/s; or ask for a static bias.

For a machine with the package's venv but without the ``ros2`` command line tools. Recording the
node's topics into a bag needs ``rosbags`` (the "analysis" extra): ``calibrate record-topics``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # type: ignore[import-untyped]  # untyped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Imu  # type: ignore[import-untyped]  # ROS messages: untyped
from std_msgs.msg import Float64  # type: ignore[import-untyped]  # ROS messages: untyped
from std_srvs.srv import Trigger  # type: ignore[import-untyped]  # ROS messages: untyped


class ImuEcho(Node):
    """Subscribes to ``imu/data_raw`` and ``imu/temperature`` and prints every ``every``-th rate."""

    def __init__(self, every: int, count: int) -> None:
        super().__init__('imu_echo')
        self._every = every
        self._count = count
        self.received = 0
        self._temp_c = math.nan
        self.done = False
        self.create_subscription(Imu, 'imu/data_raw', self._on_imu, 10)
        self.create_subscription(Float64, 'imu/temperature', self._on_temperature, 10)

    def _on_temperature(self, msg: Float64) -> None:
        self._temp_c = msg.data

    def _on_imu(self, msg: Imu) -> None:
        self.received += 1
        if self.received % self._every == 0:
            rate = msg.angular_velocity.z
            # No temperature until one arrived (its subscription may connect after the Imu one).
            temperature = '' if math.isnan(self._temp_c) else f'  temperature {self._temp_c:6.2f} degC'
            stamp = stamp_text(msg.header.stamp.sec, msg.header.stamp.nanosec)
            print(f'{stamp} {msg.header.frame_id}: yaw rate {math.degrees(rate):+10.5f} deg/s '
                  f'({rate:+.7f} rad/s){temperature}', flush=True)
        if self._count and self.received >= self._count:
            self.done = True


def stamp_text(sec: int, nanosec: int) -> str:
    """A header stamp as ISO 8601 UTC to the microsecond (``2026-11-27T22:35:17.123456Z``), not an epoch float."""
    return time.strftime('%Y-%m-%dT%H:%M:%S', time.gmtime(sec)) + f'.{nanosec // 1000:06d}Z'


def call_static_bias(timeout_s: float) -> int:
    """Call ``imu/static_bias``, print the reply; 0 on success, 1 if refused or unanswered."""
    node = Node('imu_static_bias')
    try:
        client = node.create_client(Trigger, 'imu/static_bias')
        if not client.wait_for_service(timeout_sec=timeout_s):
            print(f'no service {node.resolve_service_name("imu/static_bias")} within {timeout_s} s', file=sys.stderr)
            return 1
        future = client.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
        if not future.done():   # type: ignore[no-untyped-call]  # rclpy's Future is unannotated
            print(f'no reply within {timeout_s} s', file=sys.stderr)
            return 1
        reply = future.result()   # type: ignore[no-untyped-call]
        print(reply.message, file=sys.stdout if reply.success else sys.stderr)
        return 0 if reply.success else 1
    finally:
        node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated


def wait_static_bias(timeout_s: float) -> int:
    """Wait for the first static bias a gyro_node reports on /diagnostics: 0 if applied, 1 if refused or none."""
    node = Node('imu_wait_static_bias')
    outcome: list[DiagnosticStatus] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            state = next((kv.value for kv in status.values if kv.key == 'state'), '')
            if status.name.endswith(': static bias') and state in ('ok', 'refused'):
                outcome.append(status)

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    try:
        deadline = time.monotonic() + timeout_s
        while rclpy.utilities.ok() and not outcome and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.5)
        if not outcome:
            print(f'no static bias reported on /diagnostics within {timeout_s} s', file=sys.stderr)
            return 1
        status = outcome[0]
        applied = status.level == DiagnosticStatus.OK
        print(f'{status.name}: {status.message}', file=sys.stdout if applied else sys.stderr)
        return 0 if applied else 1
    finally:
        node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated


def silence_hint(topic: str, waited_s: float) -> str:
    """What to check when nothing arrives: the usual causes are another domain, namespace or no node at all."""
    domain = os.environ.get('ROS_DOMAIN_ID', '') or '0 (unset)'
    return (f'imu_echo: no message on {topic} after {waited_s:g} s; still waiting. Check that gyro_node runs and '
            f'got frames (its console, /diagnostics), that it uses this ROS_DOMAIN_ID ({domain}) and namespace '
            '(remap with --ros-args -r __ns:=/robot), and ROS_AUTOMATIC_DISCOVERY_RANGE on both sides.')


def echo(every: int, count: int, quiet_s: float) -> int:
    """Print rates until Ctrl-C, or until ``count`` messages; say once what to check after ``quiet_s`` of silence."""
    node = ImuEcho(max(1, every), max(0, count))
    hint_at = time.monotonic() + quiet_s
    try:
        while rclpy.utilities.ok() and not node.done:
            rclpy.spin_once(node, timeout_sec=0.5)
            if hint_at and not node.received and time.monotonic() >= hint_at:
                print(silence_hint(node.resolve_topic_name('imu/data_raw'), quiet_s), file=sys.stderr, flush=True)
                hint_at = 0.0
    finally:
        node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry: print the rate (default) or call the static bias service (``--static-bias``)."""
    full = sys.argv if argv is None else ['imu_echo', *argv]
    parser = argparse.ArgumentParser(prog='imu_echo', description=__doc__.splitlines()[0])
    parser.add_argument('--every', type=int, default=1, help='print every N-th message (default 1)')
    parser.add_argument('--count', type=int, default=0, help='exit after N messages (default: never)')
    parser.add_argument('--static-bias', action='store_true',
                        help='instead: call imu/static_bias (keep the gyro still), print the reply and exit')
    parser.add_argument('--wait-static-bias', action='store_true',
                        help='instead: wait until a gyro_node reports its static bias (exit 0) or its refusal (exit 1)')
    parser.add_argument('--timeout', type=float, default=60.0,
                        help='--static-bias, --wait-static-bias: seconds to wait (default 60)')
    parser.add_argument('--quiet-s', type=float, default=5.0,
                        help='after this many seconds without a message, say once what to check '
                             '(default 5)')
    options = parser.parse_args(rclpy.utilities.remove_ros_args(full)[1:])
    rclpy.init(args=full)
    try:
        if options.static_bias:
            return call_static_bias(options.timeout)
        if options.wait_static_bias:
            return wait_static_bias(options.timeout)
        return echo(options.every, options.count, options.quiet_s)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        rclpy.utilities.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
