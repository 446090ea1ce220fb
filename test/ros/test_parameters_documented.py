"""Every parameter the README's tables and ``gyro_node --help`` name is taken by the node and has its effect.

``qos_overrides./imu/data_raw.publisher.durability`` was documented and refused ("unknown parameter").
The names come from the README itself, so a name documented later is checked too (it needs a sample value here).
A row for each extra signal (``extra_signals.<signal>.topic``) is checked as ``supply_v``'s.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip('rclpy')

from rcl_interfaces.srv import GetParameters  # noqa: E402
from rclpy.parameter import parameter_value_to_python  # noqa: E402
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy  # noqa: E402
from rosproc import REPO, TIMEOUT_S, domain_id, node_with_listener, wait_until  # noqa: E402

from art_gyro_calibration.ros.parameters import EXTRA_SIGNAL_FIELDS, KVH_FOG_PARAMETERS, PARAMETERS  # noqa: E402

QOS = 'qos_overrides./imu/data_raw.publisher.'
# A valid value for every documented name, other than its default where it has one (so its effect shows).
SAMPLES: dict[str, Any] = {
    'port': '/nonexistent/gyro', 'baud': 115200, 'protocol': 'binary', 'serial_number': 'NAVC3545',
    'calibration_file': str(REPO / 'config' / 'NAVC3545.yaml'), 'frame_id': 'gyro_test', 'bias_samples': 50,
    'static_bias_on_startup': False, 'static_bias_max_mean_dps': 0.2, 'static_bias_max_std_dps': 0.1,
    'yaw_rate_stddev': 0.002, 'powered_on_at_start': True, 'log_path': 'TMP',   # the test's directory
    'publish_uncalibrated': True, 'guard_look_ahead': True,
    'parked_bias.enabled': True, 'parked_bias.topic': 'odom', 'parked_bias.type': 'odometry',
    'parked_bias.max_age_s': 2.0, 'parked_bias.max_linear_mps': 0.02, 'parked_bias.max_angular_dps': 0.05,
    'parked_bias.gyro_stillness': True, 'parked_bias.max_std_dps': 0.03, 'parked_bias.settle_s': 2.0,
    'parked_bias.min_interval_s': 60.0,
    'kvh_fog.message_format': 'B', 'kvh_fog.yaw_axis': '-z', 'kvh_fog.rotation': 'rate', 'kvh_fog.angle_units': 'deg',
    'kvh_fog.output_rate_hz': 500.0, 'kvh_fog.temperature_units': 'F', 'kvh_fog.forward_axis': '+x',
    'kvh_fog.timestamp_source': 'unit_clock', 'kvh_fog.rate_stddev': 0.002, 'kvh_fog.acceleration_stddev': 0.1,
    QOS + 'reliability': 'best_effort', QOS + 'history': 'keep_last', QOS + 'depth': 5,
    QOS + 'durability': 'transient_local',
    # NAVC3545 has no supply term: declared with these values, not subscribed (a console warning).
    'extra_signals.supply_v.topic': 'power/battery', 'extra_signals.supply_v.type': 'battery_state',
    'extra_signals.supply_v.max_age_s': 2.0,
}
EXTRA = 'extra_signals.supply_v.'   # what a README row of extra_signals.<signal>.* stands for


def readme_parameters() -> set[str]:
    """The names in the first column of the README's parameter tables (headed ``| name |``).

    A ``.*`` row stands for each policy its meaning lists.
    """
    names, in_table = set(), False
    for line in (REPO / 'README.md').read_text(encoding='utf-8').splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if not line.startswith('|'):
            in_table = False
            continue
        if not in_table:   # a table's header row
            in_table = cells[0] == 'name'
            continue
        if set(cells[0]) <= {'-'}:
            continue
        if cells[0].endswith('.*'):
            prefix = cells[0][:-1].replace('/<ns>', '')
            names.update(prefix + p for p in re.findall(r'`(\w+)`', cells[-1]) if p in ('reliability', 'history',
                                                                                        'depth', 'durability'))
        else:
            names.add(cells[0].replace('extra_signals.<signal>.', EXTRA))
    return names


def help_parameters() -> set[str]:
    """The names ``gyro_node --help`` lists: each parameter, and the QoS policies it names."""
    result = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.node', '--help'], cwd=REPO,
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    names = set(re.findall(r'^  ([a-z_.]+) \(', result.stdout, re.M))
    qos = re.search(r'qos_overrides\./<namespace>/imu/data_raw\.publisher\.\{([a-z,]+)\}', result.stdout)
    assert qos, result.stdout
    return names | {QOS + p for p in qos.group(1).split(',')}


def test_the_readme_and_help_name_every_parameter_and_only_those() -> None:
    documented = readme_parameters()
    assert documented == (set(PARAMETERS) | set(KVH_FOG_PARAMETERS) | {n for n in SAMPLES if n.startswith(QOS)}
                          | {EXTRA + field for field in EXTRA_SIGNAL_FIELDS})
    assert help_parameters() <= documented and set(PARAMETERS) <= help_parameters()


def test_every_documented_parameter_is_taken_and_has_its_effect(tmp_path: Path, loopback: None) -> None:
    names = readme_parameters() | help_parameters()
    assert names <= set(SAMPLES), f'a documented parameter without a sample value here: {names - set(SAMPLES)}'
    output = tmp_path / 'node.log'
    samples = {**SAMPLES, 'log_path': str(tmp_path)}
    args = [a for name in sorted(names) for a in ('-p', f'{name}:={samples[name]}')]
    with node_with_listener(domain_id(), output, *args) as (proc, listener):
        wait_until(lambda: 'calibration loaded' in output.read_text(), 'the node started', proc, output)
        # The Imu publisher has the QoS the overrides asked for (discovery tells reliability and durability;
        # history and depth it does not carry, their parameters are read below).
        publishers = wait_until(lambda: listener.node.get_publishers_info_by_topic('/imu/data_raw'),
                                'the Imu publisher', proc, output)
        qos = publishers[0].qos_profile
        assert (qos.reliability, qos.durability) == (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.TRANSIENT_LOCAL)
        # Every other parameter holds the value given.
        client = listener.node.create_client(GetParameters, '/gyro_node/get_parameters')
        wait_until(client.service_is_ready, 'the parameter service', proc, output)
        asked = sorted(names)
        future = client.call_async(GetParameters.Request(names=asked))
        wait_until(future.done, 'the parameters', proc, output)
        values = dict(zip(asked, (parameter_value_to_python(v) for v in future.result().values)))
        assert values == {name: samples[name] for name in asked}
        assert proc.poll() is None
