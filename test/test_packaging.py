"""``colcon build`` installs a working ROS 2 package: executables, ament index, calibrations."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip('colcon_core')
pytest.importorskip('rclpy')

from rosproc import TIMEOUT_S, Listener, domain_id, node_env, stop_node  # noqa: E402

from art_gyro_calibration.fake_gyro import FakeGyro  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'art_gyro_calibration'


@pytest.fixture(scope='module')
def install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The package built and installed by colcon into a temporary prefix."""
    base = tmp_path_factory.mktemp('colcon')
    # --paths names the package itself: no crawl of the repository (a .venv inside it, say).
    cmd = [sys.executable, '-c', 'import sys; from colcon_core.command import main; sys.exit(main())',
           '--log-base', str(base / 'log'), 'build', '--paths', str(REPO),
           '--build-base', str(base / 'build'), '--install-base', str(base / 'install')]
    result = subprocess.run(cmd, cwd=base, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return base / 'install' / PACKAGE


def installed_env(install: Path, domain: int) -> dict[str, str]:
    """What sourcing the install's setup script gives the package: its prefix and Python path."""
    env = node_env(domain)
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(filter(None, [str(install), env.get('AMENT_PREFIX_PATH')]))
    site = install / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(site), env.get('PYTHONPATH')]))
    return env


def test_colcon_installs_the_ros_layout(install: Path) -> None:
    """Executables in lib/<package>, the ament index marker, package.xml and every calibration."""
    for exe in ('gyro_node', 'fake_gyro', 'fake_rd2100', 'calibrate', 'imu_echo'):
        assert os.access(install / 'lib' / PACKAGE / exe, os.X_OK), exe
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    assert (install / 'share' / PACKAGE / 'package.xml').is_file()
    assert (install / 'share' / PACKAGE / 'launch' / 'gyro.launch.py').is_file()
    # What README's colcon instructions source: colcon-core writes setup.sh (setup.bash needs colcon-bash).
    assert (install.parent / 'setup.sh').is_file()
    installed = sorted(p.name for p in (install / 'share' / PACKAGE / 'config').glob('*.yaml'))
    assert installed == sorted(p.name for p in (REPO / 'config').glob('*.yaml'))
    assert 'NAVC3545.yaml' in installed
    # gyro_node's Fast DDS profile, next to the node module (art_gyro_calibration.ros.node.FASTDDS_PROFILE);
    # the PEP 561 marker, so that the users' type checkers read the package's hints.
    site = install / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    assert (site / PACKAGE / 'ros' / 'fastdds_profile.xml').is_file()
    assert (site / PACKAGE / 'py.typed').is_file()


def test_installed_package_finds_its_calibrations_through_ament(install: Path, tmp_path: Path) -> None:
    """The installed code, run from elsewhere, loads a calibration from the install's share/ by serial."""
    code = ('import art_gyro_calibration, ament_index_python as a; '
            'from art_gyro_calibration.calibration import find_calibration_file as f; '
            'print(art_gyro_calibration.__file__); print(f("NAVC3545")); '
            'print(a.get_package_share_directory("art_gyro_calibration"))')
    result = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, env=installed_env(install, 0),
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert result.returncode == 0, result.stderr
    module, calibration, share = result.stdout.split()
    assert Path(module).is_relative_to(install)
    assert Path(calibration) == install / 'share' / PACKAGE / 'config' / 'NAVC3545.yaml'
    assert Path(share) == install / 'share' / PACKAGE


@pytest.mark.parametrize('exe', ['fake_gyro', 'fake_rd2100', 'calibrate', 'imu_echo'])
def test_installed_console_scripts_run(install: Path, tmp_path: Path, exe: str) -> None:
    """Each installed console script reaches its entry point (its --help)."""
    result = subprocess.run([str(install / 'lib' / PACKAGE / exe), '--help'], cwd=tmp_path,
                            env=installed_env(install, 0), capture_output=True, text=True, timeout=TIMEOUT_S)
    assert result.returncode == 0 and result.stdout.startswith(f'usage: {exe}'), result.stdout + result.stderr


def test_installed_gyro_node_publishes_with_a_params_file_calibration(install: Path, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The installed executable, given a packaged calibration file by --params-file, publishes."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    domain = domain_id()
    output = tmp_path / 'node.log'
    params = install / 'share' / PACKAGE / 'config' / 'NAVC4058.yaml'
    with FakeGyro('NAVC4058', profile='0', seed=5) as fake:
        listener = Listener(domain)
        with open(output, 'wb') as out:
            proc = subprocess.Popen([str(install / 'lib' / PACKAGE / 'gyro_node'), '--ros-args',
                                     '--params-file', str(params), '-p', f'port:={fake.path}'],
                                    cwd=tmp_path, env=installed_env(install, domain), stdout=out,
                                    stderr=subprocess.STDOUT)
        try:
            messages = listener.wait_imu(5, proc, output)
            assert all(m.header.frame_id == 'imu_link' for m in messages)
            assert f'calibration loaded: NAVC4058 from parameters ({params})' in output.read_text()
        finally:
            try:
                stop_node(proc, signal.SIGINT, output)
            finally:
                listener.close()
