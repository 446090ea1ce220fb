"""``ros.parameters``: the ``parked_bias.*`` parameters checked without a node, and the node refusing a bad one."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest

pytest.importorskip('rclpy')

from art_gyro_calibration.ros.parameters import PARAMETERS, ParameterError, check_settings  # noqa: E402
from rosproc import REPO, TIMEOUT_S  # noqa: E402


def defaults(**changes: Any) -> dict[str, Any]:
    return {**{name: entry[0] for name, entry in PARAMETERS.items()}, **changes}


def test_off_by_default_and_a_parked_source_is_required_when_enabled() -> None:
    settings = check_settings(defaults())
    assert not settings.parked_bias_enabled and not settings.parked_bias_gyro_stillness
    with pytest.raises(ParameterError, match='parameter parked_bias.topic must name the topic'):
        check_settings(defaults(**{'parked_bias.enabled': True}))
    with pytest.raises(ParameterError, match='parameter parked_bias.topic must name the topic'):
        check_settings(defaults(**{'parked_bias.enabled': True, 'parked_bias.topic': '  '}))
    alone = check_settings(defaults(**{'parked_bias.enabled': True, 'parked_bias.gyro_stillness': True}))
    assert not alone.parked.use_topic and alone.parked.gyro_stillness
    odometry = check_settings(defaults(**{'parked_bias.enabled': True, 'parked_bias.topic': 'odom',
                                          'parked_bias.type': 'odometry', 'parked_bias.min_interval_s': 30.0}))
    assert odometry.parked.use_topic and odometry.parked.min_interval_s == 30.0
    assert odometry.value('parked_bias.type') == 'odometry'


def test_each_constraint_names_the_parameter() -> None:
    for changes, message in (({'parked_bias.type': 'twist'}, r"parameter parked_bias.type must be one of bool, "
                                                             r"odometry, got 'twist'"),
                             ({'parked_bias.max_age_s': 0.0}, r'parameter parked_bias.max_age_s must be in '
                                                              r'0\.01\.\.3600, got 0\.0'),
                             ({'parked_bias.max_angular_dps': -1.0}, r'parameter parked_bias.max_angular_dps'),
                             ({'parked_bias.max_std_dps': float('nan')}, r'parameter parked_bias.max_std_dps'),
                             ({'parked_bias.min_interval_s': -1.0}, r'parameter parked_bias.min_interval_s')):
        with pytest.raises(ParameterError, match=message):
            check_settings(defaults(**changes))


def test_the_node_refuses_to_start_enabled_without_a_source() -> None:
    result = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.node', '--ros-args',
                             '-p', 'serial_number:=NAVC3545', '-p', 'port:=/nonexistent/gyro',
                             '-p', 'parked_bias.enabled:=true'],
                            cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert result.returncode == 1, result.stdout + result.stderr
    assert 'gyro_node: error: parameter parked_bias.topic must name the topic' in result.stderr, result.stderr
    assert 'Traceback' not in result.stderr


def test_help_lists_them_with_defaults_and_ranges() -> None:
    result = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.node', '--help'], cwd=REPO,
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert "parked_bias.enabled (bool, default False)" in result.stdout
    assert "parked_bias.type (str, default 'bool', one of bool, odometry)" in result.stdout
    assert 'parked_bias.max_angular_dps (float, default 0.02, 0..10)' in result.stdout
    assert 'parked_bias.min_interval_s (float, default 600.0, 0..604800)' in result.stdout
