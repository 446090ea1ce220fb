"""Launch gyro_node for one gyro: ``ros2 launch art_gyro_calibration gyro.launch.py serial_number:=NAVC3545``.

Arguments (all optional but one: ``serial_number``, ``calibration_file`` or a ``params_file`` that sets
``serial_number`` must say which gyro it is, since a calibration belongs to one gyro and there is no
default to guess): ``serial_number``, ``calibration_file``, ``port``, ``baud``, ``protocol``,
``namespace``, ``params_file`` (a node params file such as config/gyro_node.params.yaml, or a
calibration file). An argument left empty is not passed: the params file's value, else the node's
default, holds (so ``params_file:=`` with ``baud: 921600`` is not overridden by a launch default).
"""

from __future__ import annotations

from typing import Any

import yaml
# ROS 2's launch and launch_ros are no pip wheels: without a ROS install (the venv), mypy finds no module (or this
# launch/ folder) in their place.
from launch import LaunchDescription   # type: ignore[attr-defined]
from launch.actions import DeclareLaunchArgument, OpaqueFunction   # type: ignore[import-not-found]
from launch_ros.actions import Node   # type: ignore[import-not-found]

# name: (description, the node parameter's type); every default is '' (not given).
ARGUMENTS = {
    'serial_number': ('KVH serial number such as NAVC3545: loads the packaged config/<serial_number>.yaml; '
                      'required unless calibration_file is given or params_file sets it', str),
    'calibration_file': ('a calibration file: a path, file:///path or package://<package>/<path>', str),
    'port': ('serial port of the gyro (node default /dev/ttyUSB0)', str),
    'baud': ('baud rate (node default 9600; check your unit)', int),
    'protocol': ('binary, ascii or kvh_fog (node default binary)', str),
    'namespace': ('namespace of the node and its topics (imu/data_raw, imu/is_calibrated, imu/static_bias, ...)',
                  None),
    'params_file': ('a node params file (gyro_node.params.yaml form) or a calibration file', None),
}
# What says which gyro it is: one of these, given as an argument or set by params_file.
WHICH_GYRO = ('serial_number', 'calibration_file')


class LaunchArgumentError(ValueError):
    """A launch argument missing or malformed: the message names it."""


def _params_file_sets(path: str) -> set[str]:
    """The parameter names a params file sets for any node (its ros__parameters, flattened one level deep)."""
    try:
        with open(path, encoding='utf-8') as stream:
            doc = yaml.safe_load(stream)
    except (OSError, yaml.YAMLError) as e:
        raise LaunchArgumentError(f'launch argument params_file:={path}: cannot read it: {e}') from None
    names: set[str] = set()
    if isinstance(doc, dict):
        for entry in doc.values():
            params = entry.get('ros__parameters') if isinstance(entry, dict) else None
            if isinstance(params, dict):
                names.update(params)
    return names


def node_parameters(given: dict[str, str]) -> list[Any]:
    """The gyro_node ``parameters`` for the launch arguments ``given`` (name: text, '' = not given)."""
    params_file = given.get('params_file', '')
    in_file = _params_file_sets(params_file) if params_file else set()
    if not any(given.get(name) for name in WHICH_GYRO) and not in_file.intersection(WHICH_GYRO):
        raise LaunchArgumentError(
            'launch argument serial_number is required: the KVH serial number of the gyro (such as '
            'serial_number:=NAVC3545), unless calibration_file:=<file> is given or params_file sets serial_number; '
            'no default is guessed, since another gyro\'s calibration would correct this one wrongly')
    overrides: dict[str, Any] = {}
    for name, (_, kind) in ARGUMENTS.items():
        text = given.get(name, '')
        if kind is None or not text:
            continue
        if kind is int:
            try:
                overrides[name] = int(text)
            except ValueError:
                raise LaunchArgumentError(f'launch argument {name}:={text!r} must be a whole number') from None
        else:
            overrides[name] = text
    return [params_file, overrides] if params_file else [overrides]


def _node(context: Any) -> list[Node]:
    """The node, built once the arguments are known (an argument not given is not passed)."""
    given = {name: str(context.launch_configurations.get(name, '')) for name in ARGUMENTS}
    return [Node(package='art_gyro_calibration', executable='gyro_node', name='gyro_node',
                 namespace=given['namespace'], output='screen', emulate_tty=True,
                 parameters=node_parameters(given))]


def generate_launch_description() -> LaunchDescription:
    """The arguments, and the node with the ones given."""
    args = [DeclareLaunchArgument(name, default_value='', description=description)
            for name, (description, _) in ARGUMENTS.items()]
    return LaunchDescription([*args, OpaqueFunction(function=_node)])
