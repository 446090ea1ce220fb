"""``ros.parameters``: the node's parameters checked without a node: constraints, types, params files, extra signals."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip('rclpy')

from art_gyro_calibration.calibration import load_packaged_calibration  # noqa: E402
from art_gyro_calibration.ros.parameters import (PARAMETERS, ExtraSignal, ParameterError,  # noqa: E402
                                                 check_kvh_fog_calibration, check_settings, descriptor,
                                                 describe_constraint, extra_signal_name, extra_signal_settings,
                                                 params_file_values, params_files)
from art_gyro_calibration.terms import Term  # noqa: E402


def defaults(**changes: Any) -> dict[str, Any]:
    return {**{name: entry[0] for name, entry in PARAMETERS.items()}, **changes}


def test_the_defaults_pass_and_each_constraint_names_the_parameter_and_the_allowed_values() -> None:
    settings = check_settings(defaults())
    assert (settings.port, settings.baud, settings.protocol) == ('/dev/ttyUSB0', 9600, 'binary')
    for changes, message in (({'baud': 9601}, r'parameter baud must be one of 1200, 2400, .*got 9601'),
                             ({'protocol': 'nmea'}, r"parameter protocol must be one of binary, ascii, kvh_fog, "
                                                    r"got 'nmea'"),
                             ({'bias_samples': 1}, r'parameter bias_samples must be in 2\.\.1000000, got 1'),
                             ({'yaw_rate_stddev': float('nan')}, r'parameter yaw_rate_stddev must be in 1e-07\.\.1'),
                             ({'port': ' '}, 'parameter port must not be empty'),
                             ({'frame_id': ''}, 'parameter frame_id must not be empty')):
        with pytest.raises(ParameterError, match=message):
            check_settings(defaults(**changes))


def test_descriptors_carry_the_ranges_ros2_param_describe_shows() -> None:
    samples = descriptor('bias_samples')
    assert samples.read_only and [(r.from_value, r.to_value) for r in samples.integer_range] == [(2, 1_000_000)]
    stddev = descriptor('yaw_rate_stddev')
    assert [(r.from_value, r.to_value) for r in stddev.floating_point_range] == [(1e-7, 1.0)]
    protocol = descriptor('protocol')
    assert protocol.additional_constraints == 'one of binary, ascii, kvh_fog' and not protocol.integer_range
    assert describe_constraint('port') == '' and describe_constraint('extra_signals.supply_v.max_age_s') == \
        '0.01..86400'


def test_extra_signal_names() -> None:
    assert extra_signal_name('extra_signals.supply_v.topic') == ('supply_v', 'topic')
    assert extra_signal_name('extra_signals.supply_v.colour') is None
    assert extra_signal_name('extra_signals.supply_v') is None
    assert extra_signal_name('port') is None


def _with_supply_term() -> Any:
    return dataclasses.replace(load_packaged_calibration('NAVC4058'),
                               terms=(Term('supply_v', 'power', (0.001,), (1,)),))


def test_extra_signal_settings_in_the_terms_order_unused_ones_apart_and_each_bad_value_named() -> None:
    calibration = _with_supply_term()
    needed, unused = extra_signal_settings(
        {'extra_signals.supply_v.topic': 'battery', 'extra_signals.supply_v.max_age_s': 2,
         'extra_signals.humidity.topic': 'humidity', 'port': '/dev/ttyUSB0'}, calibration, 'CAL.yaml')
    assert needed == (ExtraSignal('supply_v', 'battery', 'float64', 2.0),)
    assert unused == (ExtraSignal('humidity', 'humidity', 'float64', 5.0),)
    for values, message in (
            ({'extra_signals.temperature.topic': 't'}, 'temperature is derived from the gyro'),
            ({'extra_signals.supply_v.type': 'battery_state'}, 'parameter extra_signals.supply_v.topic'),
            ({'extra_signals.supply_v.topic': 'b', 'extra_signals.supply_v.type': 'int8'},
             "parameter extra_signals.supply_v.type must be one of .*got 'int8'"),
            ({'extra_signals.supply_v.topic': 'b', 'extra_signals.supply_v.max_age_s': 0.0},
             r'parameter extra_signals.supply_v.max_age_s must be in 0.01..86400, got 0.0'),
            ({'extra_signals.supply_v.topic': 7}, r'parameter extra_signals.supply_v.topic must be a string, got 7'),
            ({'extra_signals.supply_v.topic': 'b', 'extra_signals.supply_v.max_age_s': True},
             'must be a number, got True')):
        with pytest.raises(ParameterError, match=message):
            extra_signal_settings(values, calibration, 'CAL.yaml')


def test_a_kvh_fog_calibration_needs_unit_scale_factors() -> None:
    check_kvh_fog_calibration(dataclasses.replace(load_packaged_calibration('NAVC4058'), rate_scale_factor=1.0,
                                                  temp_scale_factor=1.0), 'CAL.yaml')
    with pytest.raises(ParameterError, match='from CAL.yaml has rate_scale_factor .* both must be 1.0'):
        check_kvh_fog_calibration(load_packaged_calibration('NAVC4058'), 'CAL.yaml')


def test_params_files_are_only_those_among_the_ros_arguments() -> None:
    argv = ['gyro_node', '--params-file', 'not_ros.yaml', '--ros-args', '--params-file', 'a.yaml', '-p', 'x:=1',
            '--params-file', 'b.yaml', '--', '--params-file', 'c.yaml', '--ros-args', '--params-file']
    assert params_files(argv) == ['a.yaml', 'b.yaml']


def test_params_file_values_take_the_entries_that_match_the_node(tmp_path: Path) -> None:
    path = tmp_path / 'params.yaml'
    path.write_text('/**:\n  ros__parameters:\n    port: /dev/ttyUSB1\n    extra_signals:\n      supply_v:\n'
                    '        topic: battery\n'
                    '/robot/*:\n  ros__parameters:\n    baud: 115200\n'
                    'other_node:\n  ros__parameters:\n    baud: 4800\n')
    assert params_file_values([str(path)], '/robot/gyro_node') == {str(path): {
        'port': '/dev/ttyUSB1', 'extra_signals.supply_v.topic': 'battery', 'baud': 115200}}
    assert params_file_values([str(path)], '/gyro_node') == {str(path): {
        'port': '/dev/ttyUSB1', 'extra_signals.supply_v.topic': 'battery'}}
