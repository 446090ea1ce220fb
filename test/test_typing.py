"""The ROS-free runtime keeps typed contracts: ``mypy --strict`` (setup.cfg) passes on it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / 'art_gyro_calibration'


def ros_free_runtime() -> list[Path]:
    """Every module outside ``ros/`` (rclpy) and ``analysis/`` (the offline tools), but the ``calibrate`` shim."""
    return sorted(p for p in PACKAGE.glob('*.py') if p.name != '__main__.py')


def test_the_ros_free_runtime_passes_mypy_strict() -> None:
    files = ros_free_runtime()
    assert {p.stem for p in files} >= {'calibration', 'compensation', 'driver', 'frame', 'model', 'signals'}
    done = subprocess.run([sys.executable, '-m', 'mypy', '--config-file', str(REPO / 'setup.cfg'),
                           *map(str, files)], capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'Success: no issues found' in done.stdout


def test_the_package_says_it_is_typed() -> None:
    assert (PACKAGE / 'py.typed').is_file()
    assert "package_data={PACKAGE: ['py.typed'," in (REPO / 'setup.py').read_text()
