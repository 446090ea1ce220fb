"""The node as a process against a fake RD2100 on a pty, seen over real DDS from this process.

Each node start-up costs seconds: the checks are grouped per node process.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import REPO, TIMEOUT_S, domain_id, node_env, node_with_listener, start_node, wait_until  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile  # noqa: E402
from art_gyro_calibration.log import read_log  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE, UNMEASURED_VARIANCE  # noqa: E402
from art_gyro_calibration.ros.parameters import PARAMETERS, check_settings, params_files  # noqa: E402
from rclpy.parameter import parameter_dict_from_yaml_file  # noqa: E402


def rates_dps(messages: Sequence[Imu]) -> np.ndarray:
    """Yaw rates of Imu messages in deg/s."""
    return np.degrees([m.angular_velocity.z for m in messages])


def test_node_compensates_serves_static_bias_and_survives_the_link(tmp_path: Path, loopback: None) -> None:
    """Binary protocol, packaged calibration: rate, covariances, service, garbage, unplug, SIGINT."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    turning_dps = 80.0   # uncompensated, NAVC3545 reads about 0.8 deg/s off at this rate
    # The listener in /robot too: the node's relative names follow its namespace.
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                             '-p', 'bias_samples:=20', '-p', 'frame_id:=gyro_test', '-r', '__ns:=/robot',
                             namespace='/robot') as (proc, listener)):
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
        # What run_demo.sh waits with: a refused bias is exit 1.
        wait = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--wait-static-bias',
                               '--timeout', str(TIMEOUT_S), '--ros-args', '-r', '__ns:=/robot'],
                              env=node_env(domain), cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S * 2)
        assert wait.returncode == 1 and '/robot/gyro_node: static bias: refused' in wait.stderr, wait
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
        link = listener.wait_status('link', lambda s: int(s['rejected_garbage']) >= 1, 'garbage counted',
                                    proc, output)
        assert 2.0 < float(link['frame_rate_hz']) < 20.0 and link['level'] == b'\x00'   # 10 Hz, generously
        listener.wait_imu(5, proc, output)

        # Unplug and replug: the node reopens the port and publishes again.
        fake.unplug()
        listener.wait_status('link', lambda s: s['connected'] == 'False', 'the link reported down',
                             proc, output)
        assert listener.status('link')['level'] == b'\x02'
        response = listener.static_bias(proc, output)   # no frames: abandoned after 5 s, bias kept
        assert not response.success and 'no frame from the gyro' in response.message, response.message
        fake.replug()
        link = listener.wait_status('link', lambda s: s['connected'] == 'True' and int(s['reopens']) >= 1,
                                    'the reopen reported', proc, output)
        assert int(link['published']) > 0
        assert abs(rates_dps(listener.wait_imu(10, proc, output)).mean()) < 0.01
    # Fast DDS parsed the node's own profile (it says XMLPARSER Error on stderr for a file it refuses).
    assert 'XMLPARSER' not in output.read_text()


def test_node_params_file_ascii_log_and_sigterm(tmp_path: Path, loopback: None) -> None:
    """ASCII protocol, calibration by --params-file, raw log, cold gyro WARN, no startup bias, SIGTERM."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    logs = tmp_path / 'logs'
    logs.mkdir()
    with (FakeGyro('NAVC4058', protocol='ascii', profile='0', temperature=5.0, seed=4) as fake,
          node_with_listener(domain, output, '--params-file', str(REPO / 'config' / 'NAVC4058.yaml'),
                             '-p', f'port:={fake.path}', '-p', 'protocol:=ascii',
                             '-p', 'static_bias_on_startup:=false', '-p', f'log_path:={logs}',
                             '-p', 'yaw_rate_stddev:=0.002', '-p', 'baud:=115200', '-p', 'bias_samples:=10',
                             signum=signal.SIGTERM) as (proc, listener)):
        messages = listener.wait_imu(10, proc, output)
        assert messages[-1].header.frame_id == 'imu_link'
        # No static bias yet (none at start-up): the rate is uncorrected and its variance says so.
        assert messages[-1].angular_velocity_covariance[8] == UNCORRECTED_YAW_VARIANCE
        temperature = listener.wait_status('temperature', lambda s: s['level'] == b'\x01',
                                           'the temperature warning', proc, output)
        # The report's calibration: warned outside its assumed range, never clamped (the report has no clamp).
        assert 'outside the calibrated range 10.0..50.0 degC' in temperature['message']
        assert 'not clamped' in temperature['message'] and temperature['range_clamped'] == 'False'
        # Said on the console too (a user without ros2cli sees no /diagnostics), once a minute at most.
        warned = [line for line in output.read_text().splitlines() if 'gyro temperature 5.00 degC is outside' in line]
        assert len(warned) == 1, warned
        bias = listener.status('static bias')
        assert bias['state'] == 'none' and bias['level'] == b'\x01'
        assert 'calibration loaded: NAVC4058 from parameters' in output.read_text()
        # The demo's monitor prints the rate in deg/s and exits after --count messages.
        echo = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--count', '3'],
                              env=node_env(domain), cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
        lines = echo.stdout.splitlines()
        assert echo.returncode == 0 and len(lines) == 3, echo.stdout + echo.stderr
        # No temperature before one arrived ('nan degC' made this test flaky), then the gyro's.
        assert all(' imu_link: yaw rate ' in line and 'deg/s' in line and 'nan' not in line for line in lines), lines
        assert all(line.endswith('temperature   5.00 degC') or 'temperature' not in line for line in lines), lines
        # Its --static-bias calls the service: the first static bias of this node.
        call = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--static-bias'],
                              env=node_env(domain), cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
        assert call.returncode == 0 and call.stdout.startswith('StaticBiasDrift='), call.stdout + call.stderr
        assert 'over 10 samples' in call.stdout
        listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the bias applied', proc, output)
        assert listener.wait_imu(3, proc, output)[-1].angular_velocity_covariance[8] == pytest.approx(0.002 ** 2)
        wait = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--wait-static-bias'],
                              env=node_env(domain), cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S * 2)
        assert wait.returncode == 0 and wait.stdout.startswith('/gyro_node: static bias: StaticBiasDrift='), wait
    # Every frame received is in the raw log, in counts, with the stamps in seconds.
    files = list(logs.glob('NAVC4058_*.csv'))
    assert len(files) == 1
    log = read_log(files[0], rate_scale_factor=0.00283, temp_scale_factor=0.05)
    assert len(log) >= 10
    assert np.all(log.temp_c == pytest.approx(5.0))
    assert abs(log.t[-1] - time.time()) < 30.0


def _calibration_with(tmp_path: Path, extra: str) -> list[str]:
    (tmp_path / 'cal.yaml').write_text((REPO / 'config' / 'NAVC4058.yaml').read_text() + extra)
    return ['--params-file', str(tmp_path / 'cal.yaml'), '-p', 'port:=/nonexistent']


def _misspelt_key(tmp_path: Path) -> list[str]:
    return _calibration_with(tmp_path, '    extnded:\n      signals: [time]\n')


def _overflowing_term(tmp_path: Path) -> list[str]:
    return _calibration_with(tmp_path, '    extended:\n      signals: [rate]\n      rate: {form: power, '
                                       'powers: [400], coefficients: [1.0e-9]}\n')


def _alias_bomb(tmp_path: Path) -> list[str]:
    lines = ['a0: &a0 [x, x, x, x, x, x, x, x, x]']
    lines += [f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * 9) + ']' for i in range(1, 12)]
    (tmp_path / 'bomb.yaml').write_text('/**:\n  ros__parameters:\n' + ''.join(f'    {line}\n' for line in lines))
    return ['-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={tmp_path}/bomb.yaml']


def _malformed(tmp_path: Path) -> list[str]:
    text = (REPO / 'config' / 'NAVC4058.yaml').read_text().replace('0.00002393343232, ', '')
    (tmp_path / 'bad.yaml').write_text(text)
    return ['--params-file', str(tmp_path / 'bad.yaml'), '-p', 'port:=/nonexistent']


@pytest.mark.parametrize('args, message', [
    (_malformed, 'bad.yaml): polynomial.coefficients has 5 numbers, rows x columns = 3 x 2 needs 6'),
    (lambda p: ['--params-file', str(REPO / 'config' / 'NAVC4058.yaml'), '-p', 'serial_number:=NAVC3545'],
     "'NAVC4058' from the calibration in {repo}/config/NAVC4058.yaml but 'NAVC3545' from -p"),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'protocol:=morse'], 'parameter protocol must be one of'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'baud:=fast'], 'parameter baud must be an integer'),
    (lambda p: ['-p', 'serial_number:=NAVC9999'], 'parameter serial_number: no calibration file NAVC9999.yaml'),
    (lambda p: [], 'parameter serial_number is required'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'bais_samples:=5'],
     "unknown parameter 'bais_samples' (from the command line) (did you mean 'bias_samples'?)"),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'bias_sample:=5'],
     "unknown parameter 'bias_sample' (from the command line) (did you mean 'bias_samples'?)"),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'yaw_rate_stddev:=1e200'],
     'parameter yaw_rate_stddev must be in 1e-07..1, got 1e+200'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'yaw_rate_stddev:=1e-200'],
     'parameter yaw_rate_stddev must be in 1e-07..1, got 1e-200'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'bias_samples:=100000000'],
     'parameter bias_samples must be in 2..1000000, got 100000000'),
    (lambda p: ['--params-file', str(REPO / 'config' / 'gyro_node.params.yaml'),
                '--params-file', str(REPO / 'config' / 'NAVC4058.yaml')],
     "parameter serial_number is 'NAVC3545' from the parameters in {repo}/config/gyro_node.params.yaml but "
     "'NAVC4058' from the calibration in"),
    (_misspelt_key, "unknown parameter 'extnded.signals' (from {tmp}/cal.yaml) (did you mean 'extended.signals'?)"),
    (_overflowing_term, '{tmp}/cal.yaml): extended.rate: the power term overflows'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={REPO}/config/NAVC4058.yaml'],
     "{repo}/config/NAVC4058.yaml: serial_number is 'NAVC4058', expected 'NAVC3545'"),
    (_alias_bomb, '{tmp}/bomb.yaml: not valid YAML: found alias'),
    (lambda p: ['-p', 'serial_number:=NAVC3545', '-p', 'qos_overrides./imu/data_raw.publisher.reliability:=sometimes'],
     'QoS override of imu/data_raw:'),
], ids=['malformed', 'other_serial', 'protocol', 'baud_type', 'unknown_serial', 'no_serial', 'misspelt', 'misspelt2',
        'stddev_huge', 'stddev_tiny', 'samples_huge', 'two_params_files', 'calibration_key', 'overflow',
        'calibration_file_serial', 'alias_bomb', 'qos'])
def test_node_refuses_bad_parameters(tmp_path: Path, args: Callable[[Path], list[str]], message: str) -> None:
    """A bad calibration or parameter: one line naming it, no traceback, and a non-zero exit."""
    output = tmp_path / 'node.log'
    proc = start_node(domain_id(), output, *args(tmp_path))
    try:
        code = proc.wait(TIMEOUT_S)
    except subprocess.TimeoutExpired:   # it accepted them: stop it, it must not outlive the test
        proc.kill()
        proc.wait()
        raise AssertionError(f'the node ran instead of refusing:\n{output.read_text()}') from None
    assert code != 0
    text = output.read_text()
    assert text.startswith('gyro_node: error: ') and message.format(repo=REPO, tmp=tmp_path) in text, text
    assert 'Traceback' not in text


def test_example_params_file_sets_every_node_parameter_validly() -> None:
    """config/gyro_node.params.yaml names exactly the node's parameters, with valid values."""
    params = parameter_dict_from_yaml_file(str(REPO / 'config' / 'gyro_node.params.yaml'))
    assert set(params) == set(PARAMETERS)
    values = {name: rclpy.parameter.parameter_value_to_python(p.value) for name, p in params.items()}
    assert check_settings(values).serial_number == 'NAVC3545'


def test_help_lists_every_parameter_with_default_and_range() -> None:
    """gyro_node --help printed nothing useful."""
    result = subprocess.run([sys.executable, '-m', 'art_gyro_calibration.ros.node', '--help'], cwd=REPO,
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert result.returncode == 0 and result.stdout.startswith('usage: gyro_node'), result.stdout + result.stderr
    for name, (default, *_) in PARAMETERS.items():
        assert f'  {name} ({type(default).__name__}, default {default!r}' in result.stdout, name
    assert 'bias_samples (int, default 100, 2..1000000)' in result.stdout
    assert 'yaw_rate_stddev (float, default 0.001, 1e-07..1)' in result.stdout


def test_parameters_are_read_only_with_ranges_and_calibration_file_loads(tmp_path: Path, loopback: None) -> None:
    """calibration_file loads a calibration by path; every parameter, calibration ones too, refuses a change."""
    from rcl_interfaces.srv import DescribeParameters, SetParameters
    from rclpy.parameter import Parameter
    domain = domain_id()
    output = tmp_path / 'node.log'
    with (FakeGyro('NAVC4058', profile='0', seed=6) as fake,
          node_with_listener(domain, output, '-p', f'calibration_file:=file://{REPO}/config/NAVC4058.yaml',
                             '-p', f'port:={fake.path}', '-p', 'static_bias_on_startup:=false',
                             '-p', 'qos_overrides./imu/data_raw.publisher.reliability:=best_effort')
          as (proc, listener)):
        # A best-effort publisher reaches no reliable subscriber (the listener's): the temperature shows it runs.
        wait_until(listener.temperatures, 'a temperature message', proc, output)
        assert listener.count() == 0
        assert f'calibration loaded: NAVC4058 from {REPO}/config/NAVC4058.yaml' in output.read_text()
        node = listener.node
        setter = node.create_client(SetParameters, '/gyro_node/set_parameters')
        describer = node.create_client(DescribeParameters, '/gyro_node/describe_parameters')
        wait_until(lambda: setter.service_is_ready() and describer.service_is_ready(), 'the parameter services')
        names = ['bias_samples', 'yaw_rate_stddev', 'baud', 'polynomial.coefficients', 'rate_scale_factor',
                 'qos_overrides./imu/data_raw.publisher.reliability']
        described = describer.call_async(DescribeParameters.Request(names=names))
        wait_until(described.done, 'the descriptors')
        d = {n: x for n, x in zip(names, described.result().descriptors)}
        assert all(x.read_only for x in d.values())
        assert (d['bias_samples'].integer_range[0].from_value, d['bias_samples'].integer_range[0].to_value) == \
            (2, 1_000_000)
        assert d['yaw_rate_stddev'].floating_point_range[0].from_value == 1e-7
        assert '115200' in d['baud'].additional_constraints
        request = SetParameters.Request(parameters=[Parameter('bias_samples', value=5).to_parameter_msg(),
                                                    Parameter('rate_scale_factor', value=1.0).to_parameter_msg()])
        future = setter.call_async(request)
        wait_until(future.done, 'the set_parameters reply')
        assert [r.successful for r in future.result().results] == [False, False]
        # The QoS override applies: the publisher is best effort.
        infos = node.get_publishers_info_by_topic('/imu/data_raw')
        assert infos and infos[0].qos_profile.reliability == rclpy.qos.ReliabilityPolicy.BEST_EFFORT


def test_params_files_are_found_among_the_ros_arguments_only() -> None:
    """The --params-file paths of a command line, not an application argument of the same spelling."""
    argv = ['gyro_node', '--params-file', 'app.yaml', '--ros-args', '-p', 'a:=1', '--params-file', 'x.yaml',
            '--params-file', 'y.yaml', '--', '--params-file', 'z.yaml']
    assert params_files(argv) == ['x.yaml', 'y.yaml']


def test_use_sim_time_stamps_follow_clock_and_a_step_re_anchors(tmp_path: Path, loopback: None) -> None:
    """use_sim_time: stamps on /clock; /clock stepped back 100 s: one jump back and a warning, not a freeze."""
    import threading
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock
    domain = domain_id()
    output = tmp_path / 'node.log'
    sim_start, offset, step_s = 1000.0, [0.0], 100.0
    stop = threading.Event()
    ticker: threading.Thread | None = None
    try:
        with (FakeGyro('NAVC3545', rate_hz=50, profile='0', seed=7) as fake,
              node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}',
                                 '-p', 'baud:=115200', '-p', 'static_bias_on_startup:=false',
                                 '-p', 'use_sim_time:=true', '-p', f'log_path:={tmp_path}') as (proc, listener)):
            clock = listener.node.create_publisher(Clock, '/clock', 10)
            origin = time.monotonic()

            def tick() -> None:
                while not stop.wait(0.01):
                    t = sim_start + offset[0] + time.monotonic() - origin
                    try:
                        clock.publish(Clock(clock=Time(sec=int(t), nanosec=int(t % 1 * 1e9))))
                    except Exception:   # the listener is closed: the node has stopped
                        return

            ticker = threading.Thread(target=tick, daemon=True)
            ticker.start()
            # Before the first /clock the node's time is 0; once it runs, the stamps are on it.
            wait_until(lambda: (m := listener.imu_since(0)) and m[-1].header.stamp.sec >= int(sim_start),
                       'stamps on the simulated clock', proc, output)
            before = listener.count()

            def stamp(m: Imu) -> float:
                return m.header.stamp.sec + m.header.stamp.nanosec * 1e-9

            listener.wait_imu(50, proc, output)
            offset[0] = -step_s

            def jumped() -> bool:
                seen = np.array([stamp(m) for m in listener.imu_since(before)])
                return bool(np.any(np.diff(seen) < -0.5 * step_s))
            # Until the stamps jump back, then 50 frames more. This process (the fake gyro, /clock and the
            # listener) stalls for seconds at times: a 10 s step once reached the stamps as a 1.8 s jump, the
            # 8 s of the stall going by on the simulated clock and none on the node's.
            try:
                wait_until(jumped, 'the stamps jumping back to the stepped clock', proc, output)
            except AssertionError as e:   # what the listener had, to tell a late clock from a lost one
                seen = [round(stamp(m), 3) for m in listener.imu_since(before)]
                now = sim_start + offset[0] + time.monotonic() - origin
                raise AssertionError(f'{e}\n{len(seen)} frames since the step, /clock now {now:.3f}; the last '
                                     f'stamps: {seen[-20:]}') from None
            listener.wait_imu(50, proc, output)
            stamps = np.array([stamp(m) for m in listener.imu_since(before)])
            # /clock runs on while the node stops: a node on simulated time is stopped as it runs.
    finally:
        stop.set()
        if ticker is not None:
            ticker.join()
    assert np.all(stamps < sim_start + 600) and np.all(stamps > sim_start - 600)   # not the wall clock
    steps = np.diff(stamps)
    # One jump back of about the step, give or take a stall of this process or a late /clock (one second or so at
    # times, on an idle machine too; eight once; the jump -102.1 s once); a /clock over a second late also looks to
    # the node like a step back of its own, undone when the clock comes (-1.1 s seen, and -3.3 s): the node cannot
    # tell the two apart.
    assert np.count_nonzero(steps < -0.5 * step_s) == 1 and np.all(steps > -step_s - 5.0), steps[steps < 0]
    jump = int(np.argmin(steps))
    assert steps[jump] < -0.7 * step_s, steps[jump]
    assert stamps[jump + 1:].max() < stamps[:jump + 1].max() - 0.5 * step_s   # the stamps stay on the new clock
    # On either side the stamps advance, not frozen (while /clock is late they advance by 1 ns, never back). How
    # they follow the gyro's period on a steady clock is test_driver's.
    for side in (steps[:jump], steps[jump + 1:]):
        assert side.sum() > 0.1, np.round(side, 4).tolist()
    # The raw log's time never goes back: it was the stamp, and calibrate refused the node's own log.
    log = read_log(next(tmp_path.glob('NAVC3545_*.csv')), 0.00305, 0.05)
    assert len(log) >= 100 and np.all(np.diff(log.t) > 0)
    # The warning names the step, measured between two reads of the clock (less a part a late /clock took as its
    # own step: -2.1 and -97.8 s once); the stamps jump back by no more.
    logged = [float(x) for x in re.findall(r'the clock stepped by (-\d+\.\d{3}) s', output.read_text())]
    assert logged and -step_s - 5.0 < min(logged) < -0.7 * step_s and steps[jump] > min(logged) - 1.5, \
        (logged, steps[jump])


def test_the_node_uses_its_fastdds_profile_only_if_the_user_has_none(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The shipped profile: Fast DDS 2's variable set to it; a user's variable or working-directory file wins."""
    from art_gyro_calibration.ros.node import FASTDDS_PROFILE, use_own_fastdds_profile
    assert FASTDDS_PROFILE.is_file() and '<preallocated_number>1<' in FASTDDS_PROFILE.read_text()
    monkeypatch.chdir(tmp_path)
    env: dict[str, str] = {'ROS_DOMAIN_ID': '7'}
    assert use_own_fastdds_profile(env)
    assert env == {'ROS_DOMAIN_ID': '7', 'FASTRTPS_DEFAULT_PROFILES_FILE': str(FASTDDS_PROFILE)}
    for variable in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE'):
        env = {variable: '/robot/profiles.xml'}
        assert not use_own_fastdds_profile(env) and env == {variable: '/robot/profiles.xml'}
    for name in ('DEFAULT_FASTRTPS_PROFILES.xml', 'DEFAULT_FASTDDS_PROFILES.xml'):
        (tmp_path / name).write_text('<dds/>')
        env = {}
        assert not use_own_fastdds_profile(env) and env == {}
        (tmp_path / name).unlink()


# A participant on the profile, with a writer: Fast DDS parses the profile when the participant is made.
_PROFILE_LOADED = r"""
import rclpy
from std_msgs.msg import Bool
rclpy.init()
node = rclpy.create_node('profile_check')
node.create_publisher(Bool, 'profile_check', 1).publish(Bool())
node.destroy_node()
rclpy.shutdown()
print('published')
"""


def test_the_fastdds_profile_delays_nack_handling_and_fast_dds_takes_it() -> None:
    """The writers' NACK suppression: the event thread woke per sample at 0 s (doc/benchmark.md), at most 3 s.

    Fast DDS skips a profile it cannot parse with only an error on the console, so the file is loaded too.
    """
    import xml.etree.ElementTree as ElementTree
    from art_gyro_calibration.ros.node import FASTDDS_PROFILE
    ns = {'dds': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    writers = [w for w in ElementTree.parse(FASTDDS_PROFILE).getroot().iterfind('dds:profiles/dds:data_writer', ns)
               if w.get('is_default_profile') == 'true']
    assert len(writers) == 1
    duration = writers[0].find('dds:times/dds:nackSupressionDuration', ns)
    assert duration is not None
    seconds = int(duration.findtext('dds:sec', '0', ns)) + int(duration.findtext('dds:nanosec', '0', ns)) * 1e-9
    assert 0.001 <= seconds < 3.0   # at most a hundred timers a second at 1 kHz; under the 3 s heartbeat period
    env = dict(node_env(domain_id()), FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE))
    run = subprocess.run([sys.executable, '-c', _PROFILE_LOADED], env=env, capture_output=True, text=True,
                         timeout=TIMEOUT_S)
    assert run.returncode == 0 and 'published' in run.stdout, run.stderr
    assert 'XMLPARSER' not in run.stdout + run.stderr, run.stdout + run.stderr


def test_a_signal_between_two_waits_of_the_executor_is_a_clean_stop(monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGINT shuts the context down; if the executor is between two waits, it raises RCLError, not a shutdown.

    Seen once in a dozen use_sim_time runs: "gyro_node: error: failed to initialize wait set: the
    given context is not valid", exit 1 on SIGINT. A stop as asked exits 0.
    """
    from art_gyro_calibration.ros import node as node_module
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    closed = []

    class Stub(rclpy.node.Node):
        def __init__(self, argv: list[str]) -> None:
            super().__init__('stub_gyro_node')

        def close(self) -> None:
            closed.append(True)

    class SignalledExecutor:
        def __init__(self, num_threads: int) -> None:
            pass

        def add_node(self, node: rclpy.node.Node) -> None:
            pass

        def spin(self) -> None:
            rclpy.shutdown()   # what rclpy's SIGINT handler does
            raise _rclpy.RCLError('failed to initialize wait set: the given context is not valid')

    monkeypatch.setattr(node_module, 'GyroNode', Stub)
    monkeypatch.setattr(node_module, 'MultiThreadedExecutor', SignalledExecutor)
    # In this process main() would leave FASTRTPS_DEFAULT_PROFILES_FILE set for the tests after it.
    monkeypatch.setattr(node_module, 'use_own_fastdds_profile', lambda: False)
    assert node_module.main(['gyro_node']) == 0
    assert closed == [True]


# A child process: rclpy installs its signal handler once per process, and a test that set Python's handler back
# would leave later ones without it.
_START_UP_SIGINT = r"""
import signal, sys
import rclpy
import rclpy.node
from art_gyro_calibration.ros import node as node_module
when = sys.argv[1]
built = []


class Stub(rclpy.node.Node):
    def __init__(self, argv):
        if when == 'while the node is built':
            signal.raise_signal(signal.SIGINT)
            while rclpy.ok():   # rclpy's handler shuts the context down in its own thread
                pass
        super().__init__('stub_gyro_node')
        built.append(True)

    def close(self):
        pass


class Executor:
    def __init__(self, num_threads):
        pass

    def add_node(self, node):
        pass

    def spin(self):
        pass


real_init = rclpy.init


def interrupted_init(**kwargs):
    if when == 'before rclpy.init':
        signal.raise_signal(signal.SIGINT)   # main's Python handler runs before the next line
    real_init(**kwargs)


rclpy.init = interrupted_init
node_module.GyroNode = Stub
node_module.MultiThreadedExecutor = Executor
code = node_module.main(['gyro_node'])
print(f'exit {code}, node built: {bool(built)}')
"""


@pytest.mark.parametrize('when', ['before rclpy.init', 'while the node is built'])
def test_a_sigint_at_start_up_is_a_clean_stop(when: str) -> None:
    """A SIGINT at start-up stops the node, exit 0.

    One before rclpy.init installed rclpy's handler was lost (main's Python handler was a no-op): the node
    started. One while the node was built shut the context down under it: a traceback ("rclpy.init() has not
    been called") and exit 1.
    """
    done = subprocess.run([sys.executable, '-c', _START_UP_SIGINT, when], env=node_env(domain_id()),
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert (done.returncode, done.stdout.strip()) == (0, 'exit 0, node built: False'), done.stderr
