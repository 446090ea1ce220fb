"""launch/gyro.launch.py, without launch and launch_ros (not on PyPI): imported with stand-in modules.

The stand-ins record what the file builds; the test checks the arguments it declares and that
they reach gyro_node as the right parameters. Whether ros2 launch runs it needs a ROS install.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

import pytest

from art_gyro_calibration.ros.parameters import PARAMETERS

REPO = Path(__file__).resolve().parent.parent


class Recorded:
    """A stand-in for any launch class: keeps its arguments."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.args, self.kwargs = args, kwargs


def _module(name: str, **attrs: object) -> types.ModuleType:
    module = types.ModuleType(name)
    module.__dict__.update(attrs)
    return module


@pytest.fixture
def launch_file(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """The launch file, imported with stand-ins for launch and launch_ros."""
    kinds = {name: type(name, (Recorded,), {}) for name in (
        'LaunchDescription', 'DeclareLaunchArgument', 'OpaqueFunction', 'Node')}
    for name, attrs in {
        'launch': {'LaunchDescription': kinds['LaunchDescription']},
        'launch.actions': {'DeclareLaunchArgument': kinds['DeclareLaunchArgument'],
                           'OpaqueFunction': kinds['OpaqueFunction']},
        'launch_ros': {}, 'launch_ros.actions': {'Node': kinds['Node']},
    }.items():
        monkeypatch.setitem(sys.modules, name, _module(name, **attrs))
    spec = importlib.util.spec_from_file_location('gyro_launch', REPO / 'launch' / 'gyro.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _launch(launch_file: types.ModuleType, **given: str) -> Recorded:
    """The node ``ros2 launch ... name:=value`` starts: the opaque function run with those arguments."""
    description = launch_file.generate_launch_description()
    declared = {e.args[0]: e.kwargs['default_value'] for e in description.args[0]
                if type(e).__name__ == 'DeclareLaunchArgument'}
    assert set(given) <= set(declared)
    opaque, = [e for e in description.args[0] if type(e).__name__ == 'OpaqueFunction']
    context = types.SimpleNamespace(launch_configurations={**declared, **given})
    node, = opaque.kwargs['function'](context)
    assert (node.kwargs['package'], node.kwargs['executable'], node.kwargs['name']) == \
        ('art_gyro_calibration', 'gyro_node', 'gyro_node')
    return node


def test_launch_declares_its_arguments_all_empty_by_default(launch_file: types.ModuleType) -> None:
    """Nothing is passed that was not given: a params file's values are not overridden by launch defaults."""
    description = launch_file.generate_launch_description()
    declared = {e.args[0]: e.kwargs['default_value'] for e in description.args[0]
                if type(e).__name__ == 'DeclareLaunchArgument'}
    assert declared == dict.fromkeys(['serial_number', 'calibration_file', 'port', 'baud', 'protocol', 'namespace',
                                      'params_file'], '')


def test_launch_passes_the_arguments_given_as_parameters_of_their_types(launch_file: types.ModuleType) -> None:
    node = _launch(launch_file, serial_number='NAVC4058', port='/dev/gyro', baud='115200', protocol='ascii',
                   namespace='/robot')
    assert node.kwargs['namespace'] == '/robot'
    overrides, = node.kwargs['parameters']
    assert overrides == {'serial_number': 'NAVC4058', 'port': '/dev/gyro', 'baud': 115200, 'protocol': 'ascii'}
    assert set(overrides) <= set(PARAMETERS)   # only names the node knows
    assert _launch(launch_file, calibration_file='/tmp/cal.yaml').kwargs['parameters'] == \
        [{'calibration_file': '/tmp/cal.yaml'}]


@pytest.mark.parametrize('params_file', ['kvh_fog.params.yaml', 'NAVC4058.yaml'])
def test_a_params_file_that_names_the_gyro_is_enough_and_not_overridden(launch_file: types.ModuleType,
                                                                        params_file: str) -> None:
    """Another gyro's file without serial_number:= (it used to get NAVC3545 on top, and the node refused)."""
    path = str(REPO / 'config' / params_file)
    assert _launch(launch_file, params_file=path).kwargs['parameters'] == [path, {}]
    assert _launch(launch_file, params_file=path, port='/dev/kvh').kwargs['parameters'] == [path, {'port': '/dev/kvh'}]


@pytest.mark.parametrize('given, message', [
    ({}, 'launch argument serial_number is required'),
    ({'port': '/dev/ttyUSB1', 'baud': '9600'}, 'launch argument serial_number is required'),
    ({'params_file': str(REPO / 'config' / 'NAVC4058.yaml'), 'baud': 'fast'}, "launch argument baud:='fast' must be"),
    ({'params_file': '/nonexistent/params.yaml'}, 'launch argument params_file:=/nonexistent/params.yaml: cannot read'),
])
def test_a_missing_or_bad_argument_is_named(launch_file: types.ModuleType, given: dict, message: str) -> None:
    with pytest.raises(launch_file.LaunchArgumentError, match=message):
        _launch(launch_file, **given)


def test_a_params_file_without_a_serial_still_needs_one(launch_file: types.ModuleType, tmp_path: Path) -> None:
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    port: /dev/ttyUSB1\n')
    with pytest.raises(launch_file.LaunchArgumentError, match='serial_number is required'):
        _launch(launch_file, params_file=str(params))
    assert _launch(launch_file, params_file=str(params), serial_number='NAVC3545').kwargs['parameters'] == \
        [str(params), {'serial_number': 'NAVC3545'}]
