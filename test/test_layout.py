"""The runtime a robot installs needs only the design card's packages; the offline tools need the extra."""

from __future__ import annotations

import ast
import importlib.metadata
import re
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / 'art_gyro_calibration'
ANALYSIS_ONLY = ('scipy', 'matplotlib', 'h5py', 'threadpoolctl', 'rosbags')
RUNTIME_MODULES = ('ros.node', 'ros.parameters', 'ros.bias_service', 'ros.raw_log', 'ros.diagnostics', 'ros.monitor',
                   'ros.rclpy_typed',
                   'driver', 'stamper', 'frame', 'protocols', 'protocols.rd2100_binary', 'protocols.rd2100_ascii',
                   'protocols.kvh_fog', 'fake_gyro', 'gyro_physics', 'compensation', 'calibration', 'static_bias',
                   'signals', 'terms', 'model', 'log')
# Imports of the analysis-only packages fail in the child, as on a robot without the extra.
BLOCK = f'''
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {ANALYSIS_ONLY!r}:
            raise ModuleNotFoundError(f'No module named {{name!r}}', name=name)
sys.meta_path.insert(0, Block())
'''


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-c', BLOCK + code], capture_output=True, text=True, timeout=120,
                          cwd=REPO)


def test_runtime_modules_import_without_the_analysis_extra() -> None:
    """Every runtime module imports with scipy, matplotlib and h5py missing, and pulls in no analysis module."""
    pytest.importorskip('rclpy')
    imports = '; '.join(f'import art_gyro_calibration.{m}' for m in RUNTIME_MODULES)
    done = _run(imports + '; print(sorted(m for m in sys.modules if m.startswith("art_gyro_calibration.analysis")))')
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'


def test_runtime_sources_never_import_the_analysis_subpackage() -> None:
    """No runtime module names an analysis module or an analysis-only package, even in a function."""
    for path in sorted(PACKAGE.rglob('*.py')):   # the top level and every runtime subpackage (ros/)
        if path.name == '__main__.py' or path.relative_to(PACKAGE).parts[0] == 'analysis':
            continue   # the offline tools, and ``python -m art_gyro_calibration``: the calibrate command itself
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert not name.startswith('art_gyro_calibration.analysis'), f'{path.name} imports {name}'
                assert name.split('.')[0] not in ANALYSIS_ONLY, f'{path.name} imports {name}'


def test_the_per_sample_path_runs_without_the_extra() -> None:
    """A compensator with extended terms (filtered signals) and a static bias works on the runtime alone."""
    done = _run('''
from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import Compensator
from art_gyro_calibration.signals import compute_signals
import dataclasses, numpy as np
from art_gyro_calibration.terms import Term
cal = dataclasses.replace(load_packaged_calibration('NAVC3545'),
                          terms=(Term('temperature_rate', 'power', (0.2,), (1,)),))
c = Compensator(cal)
errors = [c.error(0.1 * i, 0.0, 20.0 + 0.01 * i) for i in range(100)]
s = compute_signals(0.1 * np.arange(100), np.zeros(100), 20.0 + 0.01 * np.arange(100), filters=cal.filters)
assert np.allclose(cal.model.error(s), errors, rtol=0, atol=1e-12)
print('ok')
''')
    assert done.returncode == 0 and done.stdout.strip() == 'ok', done.stderr


def test_calibrate_without_the_extra_says_what_to_install(tmp_path: Path) -> None:
    """``calibrate`` on a robot's runtime install names the missing package and the extra, no traceback.

    Its help needs none of them (the parser no longer imports scipy for the simulator's effect names).
    """
    done = _run('from art_gyro_calibration.analysis.cli import main; sys.exit(main(["simulate", "--help"]))')
    assert done.returncode == 0 and '--effect' in done.stdout, done.stderr
    out = tmp_path / 'run.csv'
    done = _run('from art_gyro_calibration.analysis.cli import main; '
                f'sys.exit(main(["simulate", "--serial", "NAVC3545", "--hours", "0.01", "--out", "{out}"]))')
    assert done.returncode == 1 and not out.exists()
    # The package is installed from its repository (no index has it): the hint says so.
    assert 'pip install ".[analysis]"' in done.stderr and 'not on PyPI' in done.stderr
    assert 'Traceback' not in done.stderr


def test_install_metadata_keeps_the_runtime_lean() -> None:
    """The installed package requires no analysis-only package but under its extra; package.xml's neither.

    Read from the installed distribution's metadata (what pip resolves), not from setup.py's text: the
    offline tools' packages under ``extra == "analysis"``, the research's h5py under ``extra == "research"``.
    """
    extras: dict[str, set[str]] = {}
    for requirement in importlib.metadata.requires('art_gyro_calibration') or []:
        name, _, marker = requirement.partition(';')
        extra = re.fullmatch(r'\s*extra == "(\w+)"\s*', marker) if marker else None
        assert extra or not marker, f'{requirement}: a condition other than an extra'
        extras.setdefault(extra.group(1) if extra else '', set()).add(re.split(r'[\s\[<>=!~]', name.strip())[0])
    assert not extras[''] & set(ANALYSIS_ONLY), extras['']
    assert {'numpy', 'pyyaml', 'pyserial'} <= extras['']
    assert extras['analysis'] == {'scipy', 'matplotlib', 'threadpoolctl', 'rosbags'}
    assert extras['research'] == {'h5py'}
    exec_depends = [e.text or '' for e in ElementTree.parse(REPO / 'package.xml').getroot().iter('exec_depend')]
    assert exec_depends and not [d for d in exec_depends if any(p in d for p in ANALYSIS_ONLY)], exec_depends
