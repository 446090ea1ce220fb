"""Typed everywhere but the tests: ``mypy --strict`` passes, in one run, on what setup.cfg's ``[mypy]`` names."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def expected_sources() -> list[Path]:
    """Every module of the package (ros/, analysis/, protocols/ with it), bench/, the studies, the launch file."""
    return [*(REPO / 'art_gyro_calibration').rglob('*.py'), *(REPO / 'bench').glob('*.py'),
            *(REPO / 'research' / 'studies').glob('*.py'), REPO / 'research' / 'importers.py',
            REPO / 'launch' / 'gyro.launch.py']


def test_everything_but_the_tests_passes_mypy_strict() -> None:
    sources = expected_sources()
    assert {'ros', 'analysis', 'protocols', 'bench', 'studies'} <= {p.parent.name for p in sources}
    # From the root, as a developer runs a plain ``mypy``: setup.cfg's files and mypy_path; --strict whatever it says.
    done = subprocess.run([sys.executable, '-m', 'mypy', '--strict', '--config-file', str(REPO / 'setup.cfg')],
                          capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    # Each one a source mypy checked, not a module it only followed (silently) from another.
    assert re.search(rf'Success: no issues found in {len(sources)} source files$', done.stdout.strip()), done.stdout
