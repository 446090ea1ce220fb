"""imu/static_bias keeps its promise: every call gets a reply, joined or refused at once past MAX_WAITING_CALLS.

3000 simultaneous calls from one client (its response queue KEEP_ALL, as the README advises) got 1118
replies: the service's queues kept the last 1000 requests and replies, and the rest vanished unanswered.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import REPO, TIMEOUT_S, domain_id, node_env, node_with_listener  # noqa: E402
from test_bias_service import ADVISED_QUEUE, CLIENT  # noqa: E402

from art_gyro_calibration.fake_gyro import FakeGyro  # noqa: E402
from art_gyro_calibration.ros.bias_service import MAX_WAITING_CALLS  # noqa: E402


@pytest.mark.parametrize('calls', [MAX_WAITING_CALLS + 144, 3000])
def test_every_call_is_answered_and_those_past_the_limit_refused_at_once(
        tmp_path: Path, loopback: None, calls: int) -> None:
    """One client's simultaneous calls: MAX_WAITING_CALLS join the collection, the others are refused before it ends."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    samples = 500   # 10 s at 50 Hz: the refusals come while it runs
    with (FakeGyro('NAVC3545', rate_hz=50, profile='0', seed=9) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                             '-p', 'baud:=115200', '-p', 'static_bias_on_startup:=false',
                             '-p', f'bias_samples:={samples}') as (proc, listener)):
        listener.wait_status('link', lambda s: s['level'] == b'\x00', 'the link OK', proc, output)
        client = subprocess.Popen([sys.executable, '-c', CLIENT, '0', str(calls), ADVISED_QUEUE],
                                  env=node_env(domain), cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        try:
            assert client.stdout.readline() == 'ready\n', client.stderr.read()
            client.stdin.write('go\n')
            client.stdin.flush()
            out, err = client.communicate(timeout=TIMEOUT_S * 3)
            assert client.returncode == 0, err
        finally:   # a failure or an interrupt must not leave the caller running
            if client.poll() is None:
                client.kill()
                client.communicate()
        replies = [json.loads(line) for line in out.splitlines()]
        assert len(replies) == calls and replies.count(None) == 0, \
            f'{replies.count(None)} of {len(replies)} calls got no reply'
        joined = [r for r in replies if r[0]]
        refused = [r for r in replies if not r[0]]
        assert len(joined) == MAX_WAITING_CALLS and all(r == joined[0] for r in joined), joined[:3]
        assert f'over {samples} samples' in joined[0][1]
        assert len(refused) == calls - MAX_WAITING_CALLS
        assert all(r[1] == f'refused: {MAX_WAITING_CALLS} calls already wait for the running collection (the most '
                   'the node keeps); call again when it ends' for r in refused), refused[:3]
        bias = listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the bias', proc, output)
        assert bias['samples'] == str(samples)
