"""The research's tests: its studies and importers are scripts and modules beside the package, not in it.

Neither ``research/studies`` nor ``research`` is a package: both go on ``sys.path`` here, as each study puts its
own folder there when it runs, so a test imports ``field_check`` or ``importers`` as a study does.
"""

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

RESEARCH = Path(__file__).resolve().parent.parent
STUDIES = RESEARCH / 'studies'
sys.path[:0] = [str(STUDIES), str(RESEARCH)]


@pytest.fixture(scope='session')
def load_study() -> Callable[[str], ModuleType]:
    """A function that loads ``research/studies/<name>.py`` as a module of its own (``<name>_study``)."""
    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(f'{name}_study', STUDIES / f'{name}.py')
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module
    return load
