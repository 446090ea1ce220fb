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
def description(monkeypatch: pytest.MonkeyPatch) -> Recorded:
    kinds = {name: type(name, (Recorded,), {}) for name in (
        'LaunchDescription', 'DeclareLaunchArgument', 'IfCondition', 'UnlessCondition', 'LaunchConfiguration',
        'PythonExpression', 'Node')}
    for name, attrs in {
        'launch': {'LaunchDescription': kinds['LaunchDescription']},
        'launch.actions': {'DeclareLaunchArgument': kinds['DeclareLaunchArgument']},
        'launch.conditions': {'IfCondition': kinds['IfCondition'], 'UnlessCondition': kinds['UnlessCondition']},
        'launch.substitutions': {'LaunchConfiguration': kinds['LaunchConfiguration'],
                                 'PythonExpression': kinds['PythonExpression']},
        'launch_ros': {}, 'launch_ros.actions': {'Node': kinds['Node']},
    }.items():
        monkeypatch.setitem(sys.modules, name, _module(name, **attrs))
    spec = importlib.util.spec_from_file_location('gyro_launch', REPO / 'launch' / 'gyro.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def test_launch_declares_its_arguments_and_passes_them_to_the_node(description: Recorded) -> None:
    entities = description.args[0]
    declared = {e.args[0]: e.kwargs['default_value'] for e in entities if type(e).__name__ == 'DeclareLaunchArgument'}
    assert set(declared) == {'serial_number', 'port', 'namespace', 'params_file'}
    assert declared['port'] == PARAMETERS['port'][0]
    nodes = [e for e in entities if type(e).__name__ == 'Node']
    assert {type(n.kwargs['condition']).__name__ for n in nodes} == {'IfCondition', 'UnlessCondition'}
    for node in nodes:
        assert (node.kwargs['package'], node.kwargs['executable'], node.kwargs['name']) == \
            ('art_gyro_calibration', 'gyro_node', 'gyro_node')
        assert node.kwargs['namespace'].args == ('namespace',)
        overrides = node.kwargs['parameters'][-1]
        assert set(overrides) <= set(PARAMETERS)   # only names the node knows
        assert {k: v.args for k, v in overrides.items()} == {'serial_number': ('serial_number',), 'port': ('port',)}


def test_setup_installs_the_launch_file() -> None:
    assert "('share/' + PACKAGE + '/launch', sorted(glob('launch/*.launch.py')))" in (REPO / 'setup.py').read_text()
