"""A node process and a listener over real DDS, for the tests that run gyro_node (node, faults).

Each test gets its own ROS domain and loopback-only discovery; the node runs as a process
started with this interpreter and is stopped by a signal.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import Imu
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

REPO = Path(__file__).resolve().parent.parent
TIMEOUT_S = 30.0   # generous: the machine is shared
_domain_ids = itertools.count()


def domain_id() -> int:
    """A ROS domain for one test: distinct within this run, spread by pid across runs."""
    return 1 + (os.getpid() * 7 + next(_domain_ids)) % 100


def node_env(domain: int) -> dict[str, str]:
    """Environment of a node process: its own domain, discovery on loopback only."""
    # PYTHONFAULTHANDLER: a node that hangs is stopped with SIGABRT, which then prints where each thread was.
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1', PYTHONFAULTHANDLER='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)   # let the child's own bootstrap set its library path
    return env


def start_node(domain: int, output: Path, *ros_args: str) -> subprocess.Popen[bytes]:
    """``gyro_node`` as a process, its output to a file."""
    with open(output, 'wb') as out:
        return subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration.ros.node', '--ros-args',
                                 *ros_args],
                                env=node_env(domain), cwd=REPO, stdout=out, stderr=subprocess.STDOUT)


def start_refused(output: Path, *ros_args: str) -> tuple[int, str]:
    """Start ``gyro_node`` expecting it to exit at start-up: its exit code and output (fails if it runs on)."""
    proc = start_node(domain_id(), output, *ros_args)
    try:
        code = proc.wait(TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f'the node hung or ran instead of refusing:\n{output.read_text()}') from None
    return code, output.read_text()


def stop_node(proc: subprocess.Popen[bytes], signum: int, output: Path) -> None:
    """Signal the node and require a clean exit 0."""
    proc.send_signal(signum)
    try:
        code = proc.wait(TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)   # the faulthandler's traceback of every thread, into the output
        try:
            proc.wait(TIMEOUT_S)
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
        self.gyro = f'{namespace.rstrip("/")}/gyro_node'   # the node's fully qualified name, in its status names
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('test_listener', namespace=namespace, context=self.context)
        self._lock = threading.Lock()
        self.imu: list[Imu] = []
        self.temperature: list[float] = []
        self.diagnostics: list[DiagnosticArray] = []
        # Deep: the tests count every frame, and this process's executor thread may wait seconds for the GIL on a
        # loaded machine; 50 messages (a quarter second at 200 Hz) overflowed at CI and showed as frames lost.
        depth = 2000
        self.node.create_subscription(Imu, 'imu/data_raw', lambda m: self._add(self.imu, m), depth)
        self.node.create_subscription(Float64, 'imu/temperature', lambda m: self._add(self.temperature, m.data), depth)
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

    def temperatures(self, start: int = 0) -> list[float]:
        """Temperatures received after the first ``start``."""
        with self._lock:
            return self.temperature[start:]

    def history(self) -> list[DiagnosticArray]:
        """Every DiagnosticArray received so far."""
        with self._lock:
            return list(self.diagnostics)

    def wait_imu(self, n: int, proc: subprocess.Popen[bytes], output: Path) -> list[Imu]:
        """The next ``n`` Imu messages."""
        start = self.count()
        wait_until(lambda: self.count() >= start + n, f'{n} Imu messages', proc, output)
        return self.imu_since(start)[:n]

    def status(self, component: str, node: str | None = None) -> dict[str, Any] | None:
        """The latest diagnostic status of a component of ``node`` (fully qualified): level, message and values."""
        with self._lock:
            latest = self.diagnostics[-1] if self.diagnostics else None
        if latest is None:
            return None
        for s in latest.status:
            if s.name == f'{node or self.gyro}: {component}':
                return {'level': s.level, 'message': s.message, **{kv.key: kv.value for kv in s.values}}
        return None

    def wait_status(self, component: str, condition: Callable[[dict[str, Any]], bool], what: str,
                    proc: subprocess.Popen[bytes], output: Path, node: str | None = None) -> dict[str, Any]:
        """Wait for a diagnostic status of ``component`` of ``node`` that satisfies ``condition``."""
        def check() -> dict[str, Any] | None:
            s = self.status(component, node)
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


@contextmanager
def node_with_listener(domain: int, output: Path, *ros_args: str, signum: int = signal.SIGINT,
                       namespace: str = '') -> Iterator[tuple[subprocess.Popen[bytes], Listener]]:
    """A listener, then ``gyro_node`` with ``ros_args``; at the end the node must stop cleanly on ``signum``."""
    listener = Listener(domain, namespace)
    proc = start_node(domain, output, *ros_args)
    try:
        yield proc, listener
    finally:
        try:
            stop_node(proc, signum, output)
        finally:
            listener.close()


@contextmanager
def node_fed_supply(tmp_path: Path, calibration: Path, volts: float, *ros_args: str
                    ) -> Iterator[tuple[subprocess.Popen[bytes], Listener, Path, Callable[[float], None]]]:
    """``gyro_node`` on a still fake NAVC3545 with ``calibration``, fed ``volts`` on ``supply`` every 50 ms.

    Yields the node, its listener, its output file and a setter of the voltage published from then on; the
    node's static bias (20 samples) is in force.
    """
    from art_gyro_calibration.fake_gyro import FakeGyro
    output = tmp_path / 'node.log'
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain_id(), output, '-p', 'serial_number:=NAVC3545', '-p',
                             f'calibration_file:={calibration}', '-p', f'port:={fake.path}', '-p', 'bias_samples:=20',
                             '-p', 'extra_signals.supply_v.topic:=supply', *ros_args) as (proc, listener)):
        voltage = [volts]
        lock = threading.Lock()
        publisher = listener.node.create_publisher(Float64, 'supply', 10)

        def publish() -> None:
            with lock:
                publisher.publish(Float64(data=voltage[0]))

        def set_voltage(value: float) -> None:
            with lock:
                voltage[0] = value
        listener.node.create_timer(0.05, publish)
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the static bias', proc, output)
        yield proc, listener, output, set_voltage
