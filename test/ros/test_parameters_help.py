"""``gyro_node --help`` names every protocol and every topic the node publishes, without raw RST."""

import re
from pathlib import Path

from art_gyro_calibration.protocols import PROTOCOLS
from art_gyro_calibration.ros import node
from art_gyro_calibration.ros.parameters import IMU_TOPIC, usage

ROS = Path(node.__file__).parent


def test_help_names_every_protocol_in_the_protocol_description() -> None:
    text = usage(node.__doc__.splitlines()[0])
    line = text[text.index('  protocol ('):]
    description = line.splitlines()[1]
    assert all(protocol in description for protocol in PROTOCOLS), description


def test_help_names_every_topic_the_node_publishes_and_no_rst() -> None:
    source = ''.join(p.read_text(encoding='utf-8') for p in ROS.glob('*.py') if p.name != 'monitor.py')
    topics = set(re.findall(r"create_publisher\(\w+, '([^']+)'", source)) | {IMU_TOPIC}
    assert {'imu/is_calibrated', 'imu/uncalibrated', '/diagnostics'} <= topics
    text = usage(node.__doc__.splitlines()[0])
    assert all(topic in text[text.index('topics out:'):] for topic in topics), topics
    assert '``' not in text
