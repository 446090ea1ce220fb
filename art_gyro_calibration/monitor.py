"""``imu_echo``: print the compensated yaw rate the node publishes, in deg/s (a demo monitor)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import Float64


class ImuEcho(Node):
    """Subscribes to ``imu/data_raw`` and ``imu/temperature`` and prints every ``every``-th rate."""

    def __init__(self, every: int, count: int) -> None:
        super().__init__('imu_echo')
        self._every = every
        self._count = count
        self._received = 0
        self._temp_c = math.nan
        self.done = False
        self.create_subscription(Imu, 'imu/data_raw', self._on_imu, 10)
        self.create_subscription(Float64, 'imu/temperature', self._on_temperature, 10)

    def _on_temperature(self, msg: Float64) -> None:
        self._temp_c = msg.data

    def _on_imu(self, msg: Imu) -> None:
        self._received += 1
        if self._received % self._every == 0:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            rate = msg.angular_velocity.z
            print(f'{stamp:.3f} {msg.header.frame_id}: yaw rate {math.degrees(rate):+10.5f} deg/s '
                  f'({rate:+.7f} rad/s)  temperature {self._temp_c:6.2f} degC', flush=True)
        if self._count and self._received >= self._count:
            self.done = True


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry: print until Ctrl-C, or until ``--count`` messages."""
    args = rclpy.utilities.remove_ros_args(sys.argv if argv is None else ['imu_echo', *argv])
    parser = argparse.ArgumentParser(prog='imu_echo', description=__doc__.splitlines()[0])
    parser.add_argument('--every', type=int, default=1, help='print every N-th message (default 1)')
    parser.add_argument('--count', type=int, default=0, help='exit after N messages (default: never)')
    options = parser.parse_args(args[1:])
    rclpy.init(args=sys.argv if argv is None else ['imu_echo', *argv])
    node = ImuEcho(max(1, options.every), max(0, options.count))
    try:
        while rclpy.ok() and not node.done:
            rclpy.spin_once(node, timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
