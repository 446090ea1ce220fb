"""``calibrate record-topics``: the running node's topics into a rosbag2 that ``calibrate`` reads, without ros2cli.

The node's ``imu/uncalibrated`` (with ``publish_uncalibrated:=true``) and ``imu/temperature``
are written as received (CDR, not decoded) into an MCAP bag, as ``ros2 bag record`` would. It
needs rclpy (a machine that runs the node) and ``rosbags`` (the "analysis" extra); the robot's
runtime has the first only, so this lives with the calibration tool, not in ``imu_echo``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Imu  # type: ignore[import-untyped]  # ROS messages: untyped
from std_msgs.msg import Float64  # type: ignore[import-untyped]  # ROS messages: untyped

from art_gyro_calibration.analysis.bags import BagTopics, BagWriter


def _silence_hint(topic: str, waited_s: float) -> str:
    """What to check when nothing arrives: another domain or namespace, or no node publishing it."""
    domain = os.environ.get('ROS_DOMAIN_ID', '') or '0 (unset)'
    return (f'calibrate record-topics: no message on {topic} after {waited_s:g} s; still waiting. Check that '
            f'gyro_node runs with publish_uncalibrated:=true, that it uses this ROS_DOMAIN_ID ({domain}) and the '
            'namespace given with --namespace, and ROS_AUTOMATIC_DISCOVERY_RANGE on both sides.')


def record_topics(out: str, namespace: str, duration_s: float | None, quiet_s: float) -> int:
    """Record the node's topics into the bag ``out`` until Ctrl-C or ``duration_s``; 1 if nothing came."""
    if Path(out).exists():
        print(f'calibrate record-topics: {out}: exists; a bag is never replaced: name another', file=sys.stderr)
        return 1
    rclpy.init(args=[])
    try:
        return _record(out, namespace, duration_s, quiet_s)
    finally:
        rclpy.utilities.try_shutdown()


def _record(out: str, namespace: str, duration_s: float | None, quiet_s: float) -> int:
    node = Node('imu_record', namespace=namespace)
    rate_topic = node.resolve_topic_name(BagTopics.rate)
    topics = (BagTopics.rate, BagTopics.temperature)
    # Created at the first message, in the node's namespace; messages written as received.
    writer: list[BagWriter] = []

    def on_message(topic: str) -> Callable[[bytes], None]:
        def write(raw: bytes) -> None:
            if not writer:
                writer.append(BagWriter(out, namespace=node.get_namespace()))
            writer[0].write_cdr(topic, time.time_ns(), raw)
        return write
    for topic, kind in zip(topics, (Imu, Float64)):
        node.create_subscription(kind, topic, on_message(topic), 100, raw=True)
    end = math.inf if duration_s is None else time.monotonic() + duration_s
    hint_at = time.monotonic() + quiet_s
    try:
        while rclpy.utilities.ok() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=min(0.5, max(0.0, end - time.monotonic())))
            if hint_at and not writer and time.monotonic() >= hint_at:
                print(_silence_hint(rate_topic, quiet_s), file=sys.stderr, flush=True)
                hint_at = 0.0
    except (KeyboardInterrupt, ExternalShutdownException):   # the latter: Ctrl-C while spin_once waits
        pass   # a stop as asked: the bag is finished below
    finally:
        node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated
        if writer:
            writer[0].close()
    if not writer:
        print(f'calibrate record-topics: nothing received; {out} not written', file=sys.stderr)
        return 1
    print(f'{out}: {writer[0].count} messages of {rate_topic} and the temperature')
    return 0
