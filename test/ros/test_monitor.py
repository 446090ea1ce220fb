"""``imu_echo`` as a user meets it: it says what to check when nothing arrives, rather than waiting in silence."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip('rclpy')

from rosproc import REPO, TIMEOUT_S, domain_id, node_env  # noqa: E402


def test_imu_echo_says_what_to_check_when_nothing_publishes() -> None:
    domain = domain_id()   # a domain with no gyro_node in it
    proc = subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--quiet-s', '1'],
                            env=node_env(domain), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        time.sleep(4.0)   # the hint is due after 1 s of silence; the process takes about a second to start
        assert proc.poll() is None, 'imu_echo exited instead of waiting'
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 0, err
    assert out == ''
    assert err.count('no message on /imu/data_raw after 1 s; still waiting') == 1, err
    assert f'ROS_DOMAIN_ID ({domain})' in err and 'namespace' in err
