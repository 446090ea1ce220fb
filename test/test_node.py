"""The node as a process against a fake RD2100 on a pty, seen over real DDS from this process.

Each node start-up costs seconds: the checks are grouped per node process.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from art_gyro_calibration.fake_rd2100 import FakeRd2100, RateProfile  # noqa: E402
from art_gyro_calibration.log import read_log  # noqa: E402
from art_gyro_calibration.node import PARAMETERS, UNMEASURED_VARIANCE, check_settings, params_files  # noqa: E402
from rclpy.parameter import parameter_dict_from_yaml_file  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
TIMEOUT_S = 30.0   # generous: the machine is shared
_domain_ids = itertools.count()


def domain_id() -> int:
    """A ROS domain for one test: distinct within this run, spread by pid across runs."""
    return 1 + (os.getpid() * 7 + next(_domain_ids)) % 100


def node_env(domain: int) -> dict[str, str]:
    """Environment of a node process: its own domain, discovery on loopback only."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)   # let the child's own bootstrap set its library path
    return env


def start_node(domain: int, output: Path, *ros_args: str) -> subprocess.Popen[bytes]:
    """``gyro_node`` as a process, its output to a file."""
    with open(output, 'wb') as out:
        return subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration.node', '--ros-args', *ros_args],
                                env=node_env(domain), cwd=REPO, stdout=out, stderr=subprocess.STDOUT)


def stop_node(proc: subprocess.Popen[bytes], signum: int, output: Path) -> None:
    """Signal the node and require a clean exit 0."""
    proc.send_signal(signum)
    try:
        code = proc.wait(TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f'node did not stop on signal {signum}:\n{output.read_text()}') from None
    assert code == 0, f'exit {code} on signal {signum}:\n{output.read_text()}'


def wait_until(condition: Callable[[], Any], what: str, proc: subprocess.Popen[bytes] | None = None,
               output: Path | None = None) -> Any:
    """Poll ``condition`` until it returns something true; fail with ``what`` after the timeout."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f'node exited with {proc.returncode} while waiting for {what}:\n'
                                 + (output.read_text() if output else ''))
        time.sleep(0.05)
    raise AssertionError(f'timed out waiting for {what}' + (f':\n{output.read_text()}' if output else ''))


class Listener:
    """A subscriber and service client in this process, in its own context and domain."""

    def __init__(self, domain: int, namespace: str = '') -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('test_listener', namespace=namespace, context=self.context)
        self._lock = threading.Lock()
        self.imu: list[Imu] = []
        self.temperature: list[float] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.node.create_subscription(Imu, 'imu/data_raw', lambda m: self._add(self.imu, m), 50)
        self.node.create_subscription(Float64, 'imu/temperature', lambda m: self._add(self.temperature, m.data), 50)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: self._add(self.diagnostics, m), 10)
        self.client = self.node.create_client(Trigger, 'imu/static_bias')
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def _add(self, store: list[Any], item: Any) -> None:
        with self._lock:
            store.append(item)

    def count(self) -> int:
        """Imu messages received so far."""
        with self._lock:
            return len(self.imu)

    def imu_since(self, start: int) -> list[Imu]:
        """Imu messages received after the first ``start``."""
        with self._lock:
            return self.imu[start:]

    def wait_imu(self, n: int, proc: subprocess.Popen[bytes], output: Path) -> list[Imu]:
        """The next ``n`` Imu messages."""
        start = self.count()
        wait_until(lambda: self.count() >= start + n, f'{n} Imu messages', proc, output)
        return self.imu_since(start)[:n]

    def status(self, component: str) -> dict[str, Any] | None:
        """The latest diagnostic status of a component: level, message and values."""
        with self._lock:
            latest = self.diagnostics[-1] if self.diagnostics else None
        if latest is None:
            return None
        for s in latest.status:
            if s.name == f'gyro_node: {component}':
                return {'level': s.level, 'message': s.message, **{kv.key: kv.value for kv in s.values}}
        return None

    def wait_status(self, component: str, condition: Callable[[dict[str, Any]], bool], what: str,
                    proc: subprocess.Popen[bytes], output: Path) -> dict[str, Any]:
        """Wait for a diagnostic status of ``component`` that satisfies ``condition``."""
        def check() -> dict[str, Any] | None:
            s = self.status(component)
            return s if s is not None and condition(s) else None
        return wait_until(check, what, proc, output)

    def static_bias(self, proc: subprocess.Popen[bytes], output: Path, calls: int = 1) -> Any:
        """Call ``imu/static_bias`` (``calls`` times at once) and wait for the replies."""
        wait_until(lambda: self.client.service_is_ready(), 'the static bias service', proc, output)
        futures = [self.client.call_async(Trigger.Request()) for _ in range(calls)]
        wait_until(lambda: all(f.done() for f in futures), 'the static bias reply', proc, output)
        return futures[0].result() if calls == 1 else [f.result() for f in futures]

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(TIMEOUT_S)


@pytest.fixture
def loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    """DDS discovery on loopback only, for this process's listener too."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def rates_dps(messages: Sequence[Imu]) -> np.ndarray:
    """Yaw rates of Imu messages in deg/s."""
    return np.degrees([m.angular_velocity.z for m in messages])


def test_node_compensates_serves_static_bias_and_survives_the_link(tmp_path: Path, loopback: None) -> None:
    """Binary protocol, packaged calibration: rate, covariances, service, garbage, unplug, SIGINT."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    turning_dps = 80.0   # uncompensated, NAVC3545 reads about 0.8 deg/s off at this rate
    with FakeRd2100('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake:
        listener = Listener(domain, namespace='/robot')   # the node's relative names follow its namespace
        proc = start_node(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                          '-p', 'bias_samples:=20', '-p', 'frame_id:=gyro_test', '-r', '__ns:=/robot')
        try:
            # Startup static bias over the first 20 still frames.
            bias = listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the startup static bias',
                                        proc, output)
            assert bias['level'] == b'\x00' and int(bias['samples']) == 20

            # Still: the compensated rate is zero within the noise; REP 145 layout; temperature.
            still = listener.wait_imu(10, proc, output)
            assert abs(rates_dps(still).mean()) < 0.01
            m = still[-1]
            assert m.header.frame_id == 'gyro_test'
            assert m.orientation_covariance[0] == -1.0 and m.linear_acceleration_covariance[0] == -1.0
            cov = np.reshape(m.angular_velocity_covariance, (3, 3))
            assert cov[0, 0] == cov[1, 1] == UNMEASURED_VARIANCE
            assert cov[2, 2] == pytest.approx(0.001 ** 2)
            assert np.count_nonzero(cov - np.diag(np.diag(cov))) == 0
            assert m.angular_velocity.x == m.angular_velocity.y == 0.0
            stamps = [s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 for s in still]
            assert np.all(np.diff(stamps) > 0) and abs(stamps[-1] - time.time()) < 5.0
            wait_until(lambda: listener.temperature, 'a temperature message', proc, output)
            assert listener.temperature[-1] == pytest.approx(25.0)

            # Turning: the compensated rate is the true rate (counter-clockwise positive, rad/s).
            fake.simulator.profile = RateProfile.parse(str(turning_dps))
            wait_until(lambda: fake.last_sample and fake.last_sample[0] > 20000, 'the fake turning')
            turning = listener.wait_imu(12, proc, output)[2:]   # skip any still frame still in flight
            assert rates_dps(turning).mean() == pytest.approx(turning_dps, abs=0.01)

            # A static bias while turning is refused and the previous one kept.
            response = listener.static_bias(proc, output)
            assert not response.success and 'turning' in response.message, response.message
            refused = listener.wait_status('static bias', lambda s: s['state'] == 'refused', 'the refusal',
                                           proc, output)
            assert refused['static_bias_drift_dps'] == bias['static_bias_drift_dps']
            assert rates_dps(listener.wait_imu(10, proc, output)).mean() == pytest.approx(turning_dps, abs=0.01)

            # Still again: a new static bias, its values in the reply.
            fake.simulator.profile = RateProfile.parse('0')
            wait_until(lambda: fake.last_sample and abs(fake.last_sample[0]) < 100, 'the fake still')
            # A second call while the first collects joins it; frames are published meanwhile.
            before = listener.count()
            first, second = listener.static_bias(proc, output, calls=2)
            assert listener.count() - before >= 20
            assert first.success and 'StaticBiasDrift=' in first.message, first.message
            assert 'over 20 samples' in first.message
            assert (second.success, second.message) == (first.success, first.message)

            # Garbage between frames is counted, and frames flow on.
            fake.inject(b'not a frame \x01\x02\x03')
            listener.wait_status('link', lambda s: int(s['rejected_garbage']) >= 1, 'garbage counted', proc, output)
            listener.wait_imu(5, proc, output)

            # Unplug and replug: the node reopens the port and publishes again.
            fake.unplug()
            listener.wait_status('link', lambda s: s['connected'] == 'False', 'the link reported down',
                                 proc, output)
            assert listener.status('link')['level'] == b'\x02'
            fake.replug()
            link = listener.wait_status('link', lambda s: s['connected'] == 'True' and int(s['reopens']) >= 1,
                                        'the reopen reported', proc, output)
            assert int(link['published']) > 0
            assert abs(rates_dps(listener.wait_imu(10, proc, output)).mean()) < 0.01
        finally:
            try:
                stop_node(proc, signal.SIGINT, output)
            finally:
                listener.close()


def test_node_params_file_ascii_log_and_sigterm(tmp_path: Path, loopback: None) -> None:
    """ASCII protocol, calibration by --params-file, raw log, hot gyro WARN, no startup bias, SIGTERM."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    logs = tmp_path / 'logs'
    logs.mkdir()
    with FakeRd2100('NAVC4058', protocol='ascii', profile='0', temperature=60.0, seed=4) as fake:
        listener = Listener(domain)
        proc = start_node(domain, output, '--params-file', str(REPO / 'config' / 'NAVC4058.yaml'),
                          '-p', f'port:={fake.path}', '-p', 'protocol:=ascii', '-p', 'static_bias_on_startup:=false',
                          '-p', f'log_path:={logs}', '-p', 'yaw_rate_stddev:=0.002', '-p', 'baud:=115200')
        try:
            messages = listener.wait_imu(10, proc, output)
            assert messages[-1].header.frame_id == 'imu_link'
            assert messages[-1].angular_velocity_covariance[8] == pytest.approx(0.002 ** 2)
            temperature = listener.wait_status('temperature', lambda s: s['level'] == b'\x01',
                                               'the temperature warning', proc, output)
            assert 'outside the calibrated range' in temperature['message']
            bias = listener.status('static bias')
            assert bias['state'] == 'none' and bias['level'] == b'\x01'
            assert 'calibration loaded: NAVC4058 from parameters' in output.read_text()
            # The demo's monitor prints the rate in deg/s and exits after --count messages.
            echo = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.monitor', '--count', '3'],
                                  env=node_env(domain), cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
            lines = echo.stdout.splitlines()
            assert echo.returncode == 0 and len(lines) == 3, echo.stdout + echo.stderr
            assert all(' imu_link: yaw rate ' in line and 'deg/s' in line and '60.00 degC' in line
                       for line in lines[1:]), lines
        finally:
            try:
                stop_node(proc, signal.SIGTERM, output)
            finally:
                listener.close()
    # Every frame received is in the raw log, in counts, with the stamps in seconds.
    files = list(logs.glob('NAVC4058_*.csv'))
    assert len(files) == 1
    log = read_log(files[0], rate_scale_factor=0.00283, temp_scale_factor=0.05)
    assert len(log) >= 10
    assert np.all(log.temp_c == pytest.approx(60.0))
    assert abs(log.t[-1] - time.time()) < 30.0


def _malformed(tmp_path: Path) -> list[str]:
    text = (REPO / 'config' / 'NAVC4058.yaml').read_text().replace('0.00002393343232, ', '')
    (tmp_path / 'bad.yaml').write_text(text)
    return ['--params-file', str(tmp_path / 'bad.yaml'), '-p', 'port:=/nonexistent']


@pytest.mark.parametrize('args, message', [
    (_malformed, 'bad.yaml): polynomial.coefficients has 5 numbers, rows x columns = 3 x 2 needs 6'),
    (lambda p: ['--params-file', str(REPO / 'config' / 'NAVC4058.yaml'), '-p', 'serial_number:=NAVC3545'],
     "calibration in {repo}/config/NAVC4058.yaml is for 'NAVC4058'"),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'protocol:=morse'], 'parameter protocol must be one of'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'baud:=fast'], 'parameter baud must be an integer'),
    (lambda p: ['-p', 'serial_number:=NAVC9999'], 'parameter serial_number: no calibration file NAVC9999.yaml'),
    (lambda p: [], 'parameter serial_number is required'),
], ids=['malformed', 'other_serial', 'protocol', 'baud_type', 'unknown_serial', 'no_serial'])
def test_node_refuses_bad_parameters(tmp_path: Path, args: Callable[[Path], list[str]], message: str) -> None:
    """A bad calibration or parameter: one line naming it, no traceback, and a non-zero exit."""
    output = tmp_path / 'node.log'
    proc = start_node(domain_id(), output, *args(tmp_path))
    assert proc.wait(TIMEOUT_S) != 0
    text = output.read_text()
    assert text.startswith('gyro_node: error: ') and message.format(repo=REPO) in text, text
    assert 'Traceback' not in text


def test_example_params_file_sets_every_node_parameter_validly() -> None:
    """config/gyro_node.params.yaml names exactly the node's parameters, with valid values."""
    params = parameter_dict_from_yaml_file(str(REPO / 'config' / 'gyro_node.params.yaml'))
    assert set(params) == set(PARAMETERS)
    values = {name: rclpy.parameter.parameter_value_to_python(p.value) for name, p in params.items()}
    assert check_settings(values).serial_number == 'NAVC3545'


def test_params_files_are_found_among_the_ros_arguments_only() -> None:
    """The --params-file paths of a command line, not an application argument of the same spelling."""
    argv = ['gyro_node', '--params-file', 'app.yaml', '--ros-args', '-p', 'a:=1', '--params-file', 'x.yaml',
            '--params-file', 'y.yaml', '--', '--params-file', 'z.yaml']
    assert params_files(argv) == ['x.yaml', 'y.yaml']
