"""``calibrate record-topics``: the running node's topics into a rosbag2 without ros2cli, read by ``calibrate``."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('rclpy')

from rosproc import REPO, TIMEOUT_S, domain_id, node_env, start_node, stop_node, wait_until  # noqa: E402

from art_gyro_calibration.analysis.bags import read_bag  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro  # noqa: E402


def test_the_node_is_recorded_into_a_bag_calibrate_reads(tmp_path: Path) -> None:
    domain = domain_id()
    output = tmp_path / 'node.log'
    bag = tmp_path / 'BAG'
    with FakeGyro('NAVC3545', rate_hz=50.0, profile='20', temperature=30.0, seed=3) as fake:
        node = start_node(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                          '-p', 'baud:=115200', '-p', 'publish_uncalibrated:=true', '-p', 'bias_samples:=20')
        try:
            recorder = subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration', 'record-topics',
                                         str(bag), '--duration', '20'], env=node_env(domain), cwd=REPO,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                wait_until(bag.exists, 'the first message recorded', node, output)
                time.sleep(2.0)
            finally:
                recorder.send_signal(signal.SIGINT)   # a stop as asked: the bag is finished
                out, err = recorder.communicate(timeout=TIMEOUT_S)
        finally:
            stop_node(node, signal.SIGINT, output)
    assert recorder.returncode == 0, err
    written = int(re.match(rf'{re.escape(str(bag))}: (\d+) messages of /imu/uncalibrated', out)[1])
    log = read_bag(bag)
    assert len(log) == written > 50
    assert np.median(log.rate_dps) == pytest.approx(20.0, abs=1.0)
    assert np.median(log.temp_c) == pytest.approx(30.0, abs=0.2)


def test_without_a_node_nothing_is_written_and_it_says_so(tmp_path: Path) -> None:
    bag = tmp_path / 'BAG'
    proc = subprocess.run([sys.executable, '-m', 'art_gyro_calibration', 'record-topics', str(bag),
                           '--duration', '2', '--quiet-s', '1'], env=node_env(domain_id()), cwd=REPO,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 1
    assert 'publish_uncalibrated:=true' in proc.stderr and f'{bag} not written' in proc.stderr
    assert not bag.exists()


def test_a_stop_while_it_waits_for_messages_still_says_what_it_wrote(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C while spin_once waits ends it with rclpy's ExternalShutdownException, not KeyboardInterrupt.

    It was caught outside the loop, after the bag was closed but before the summary: the bag whole,
    exit 0, and nothing said (CI, under load: the test above found no count).
    """
    from rclpy.executors import ExternalShutdownException

    from art_gyro_calibration.analysis import record_topics as module
    calls = []

    def spin_once(node, timeout_sec: float = 0.0) -> None:
        calls.append(timeout_sec)
        if len(calls) == 1:   # one message on each topic, as received (not decoded), then the stop
            for subscription in node.subscriptions:
                subscription.callback(b'\x00\x01\x00\x00')
            return
        raise ExternalShutdownException()

    monkeypatch.setattr(module.rclpy, 'spin_once', spin_once)
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain_id()))
    bag = tmp_path / 'BAG'
    assert module.record_topics(str(bag), '/', 20.0, 5.0) == 0
    assert capsys.readouterr().out == f'{bag}: 1 messages of /imu/uncalibrated and the temperature\n'
    assert (bag / 'metadata.yaml').exists()
