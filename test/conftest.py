"""Shared fixtures: the five gyros of the ART report; loopback-only DDS discovery; the studies as modules."""

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

STUDIES = Path(__file__).resolve().parent.parent / 'studies'

SERIALS = ('NAVC3545', 'NAVC4361', 'NAVC4058', 'NAVC4377', 'NAVC4253')


@pytest.fixture(params=SERIALS)
def serial(request: pytest.FixtureRequest) -> str:
    """Each gyro's KVH serial number in turn."""
    return request.param


@pytest.fixture
def loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    """DDS discovery on loopback only, for this process's listener too."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


@pytest.fixture(scope='session')
def load_study() -> Callable[[str], ModuleType]:
    """A function that loads ``studies/<name>.py`` as a module (studies/ is not a package)."""
    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(f'{name}_study', STUDIES / f'{name}.py')
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module
    return load
