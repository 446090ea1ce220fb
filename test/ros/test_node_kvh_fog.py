"""Protocol kvh_fog end to end: gyro_node against a fake KVH DSP-1760 on a pty, and the calibration loop on its log.

The fake sends Format A delta angles as the factory-set unit does, mounted upside down
(yaw axis -z) so that the sign is exercised; the node reads it with the example params file
and the example calibration (zero polynomial: the static bias alone).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import REPO, TIMEOUT_S, domain_id, node_with_listener, start_node, wait_until  # noqa: E402
from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python  # noqa: E402

from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration  # noqa: E402
from art_gyro_calibration.compensation import apply_calibration  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro, GyroSimulator, RateProfile, TemperatureProfile  # noqa: E402
from art_gyro_calibration.analysis.csv_writer import write_columns  # noqa: E402
from art_gyro_calibration.log import read_log  # noqa: E402
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig, encode_kvh_fog  # noqa: E402
from art_gyro_calibration.ros.parameters import (KVH_FOG_PARAMETERS, PARAMETERS,  # noqa: E402
                                                 check_kvh_fog_calibration, check_settings, usage)

EXAMPLE = 'KVH_DSP1760_EXAMPLE'
RATE_HZ = 100.0
OK, WARN = b'\x00', b'\x01'


def rates_dps(messages) -> np.ndarray:
    return np.degrees([m.angular_velocity.z for m in messages])


def test_node_reads_a_kvh_fog_unit_counts_lost_and_invalid_frames_and_logs_deg_s(tmp_path: Path,
                                                                                 loopback: None) -> None:
    domain = domain_id()
    output = tmp_path / 'node.log'
    logs = tmp_path / 'logs'
    logs.mkdir()
    mounting = KvhFogConfig(yaw_axis='-z')
    with (FakeGyro(EXAMPLE, protocol='kvh_fog', link=str(tmp_path / 'kvh'), rate_hz=RATE_HZ, profile='0',
                   temperature=31.0, seed=5, kvh_fog=mounting) as fake,
          node_with_listener(domain, output, '--params-file', str(REPO / 'config' / 'kvh_fog.params.yaml'),
                             '-p', f'port:={fake.path}', '-p', f'kvh_fog.output_rate_hz:={RATE_HZ}',
                             '-p', 'kvh_fog.yaw_axis:=-z', '-p', 'bias_samples:=100',
                             '-p', f'log_path:={logs}') as (proc, listener)):
        bias = listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the startup static bias',
                                    proc, output)
        assert int(bias['samples']) == 100
        # The static bias took the turn-on bias and the Earth's rate out of the reading.
        assert float(bias['static_bias_drift_dps']) == pytest.approx(
            fake.simulator.turn_on_bias_dps + fake.simulator.earth_rate_dps, abs=0.005)
        still = listener.wait_imu(50, proc, output)
        assert abs(rates_dps(still).mean()) < 0.01
        # The whole IMU: the unit upside down reads -1 g on its z, which is +9.80665 m/s^2 up in REP 103 axes.
        imu = still[-1]
        assert (imu.linear_acceleration.x, imu.linear_acceleration.y, imu.linear_acceleration.z) == (
            0.0, 0.0, pytest.approx(9.80665, rel=1e-6))
        assert list(imu.linear_acceleration_covariance) == pytest.approx([0.05 ** 2, 0, 0, 0, 0.05 ** 2, 0, 0, 0,
                                                                          0.05 ** 2])
        assert abs(imu.angular_velocity.x) < 1e-3 and abs(imu.angular_velocity.y) < 1e-3
        assert list(imu.angular_velocity_covariance) == pytest.approx([1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6])
        assert imu.orientation_covariance[0] == -1.0
        wait_until(lambda: listener.temperature, 'a temperature', proc, output)
        assert listener.temperatures()[-1] == 31.0
        link = listener.wait_status('link', lambda s: float(s['frame_rate_hz']) > 0, 'frames counted', proc, output)
        # (A port opened mid-message skips its rest as garbage: that is the only rejection allowed here.)
        assert link['level'] == OK and link['lost_frames'] == '0' and link['rejected_bad_crc'] == '0'
        assert 'calibration loaded: KVH_DSP1760_EXAMPLE' in output.read_text()

        # Turning counter-clockwise seen from above, the unit upside down: the published rate is +30 deg/s.
        fake.simulator.profile = RateProfile.parse('30')
        wait_until(lambda: fake.last_sample and fake.last_sample[0] > 20, 'the fake turning')
        turning = listener.wait_imu(60, proc, output)[10:]
        assert rates_dps(turning).mean() == pytest.approx(30.0, abs=0.015)

        # Five messages lost on the wire: counted from the sequence numbers, and a WARN.
        fake.drop(5)
        link = listener.wait_status('link', lambda s: s['lost_frames'] == '5', 'the lost frames', proc, output)
        assert link['rejected_bad_crc'] == link['rejected_repeated_sequence'] == '0'
        history = listener.history()
        assert any(s.level == WARN and '5 frames lost' in s.message
                   for array in history for s in array.status if s.name == '/gyro_node: link'), history[-1]

        # The gyro flags its z axis invalid: those frames are not published, and are counted.
        before = listener.count()
        fake.encoder.status = 0x73
        link = listener.wait_status('link', lambda s: int(s['rejected_axis_invalid']) >= 20, 'invalid frames',
                                    proc, output)
        fake.encoder.status = 0x77
        assert listener.count() - before < 10   # at most the frames already on their way
        assert link['rejected_bad_crc'] == '0' and link['lost_frames'] == '5'
        listener.wait_status('link', lambda s: int(s['published']) > int(link['published']) + 20,
                             'publishing again', proc, output)

        # A message with a bit flipped between two good ones: a bad CRC, and nothing lost.
        corrupt = bytearray(encode_kvh_fog((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 0x77, 3, 31))
        corrupt[9] ^= 0x10
        fake.inject(bytes(corrupt))
        link = listener.wait_status('link', lambda s: s['rejected_bad_crc'] == '1', 'the bad CRC', proc, output)
        assert link['lost_frames'] == '5'
        assert rates_dps(listener.wait_imu(20, proc, output)).mean() == pytest.approx(30.0, abs=0.02)

    # The log holds deg/s and degC in raw_rate, raw_temp: read back with the calibration's 1.0 scale factors.
    files = list(logs.glob(f'{EXAMPLE}_*.csv'))
    assert len(files) == 1
    calibration = load_packaged_calibration(EXAMPLE)
    log = read_log(files[0], calibration.rate_scale_factor, calibration.temp_scale_factor)
    assert np.all(log.temp_c == 31.0)
    assert np.count_nonzero(log.rate_dps > 25.0) >= 50
    applied = apply_calibration(log, calibration, 100)
    assert abs(applied.corrected_dps[:100].mean()) < 0.01
    assert np.median(applied.corrected_dps[log.rate_dps > 25.0]) == pytest.approx(30.0, abs=0.01)


def test_calibrate_fit_makes_a_kvh_fog_calibration_from_a_log_in_deg_s(tmp_path: Path) -> None:
    """A rate-table log as the node's log_path writes it for kvh_fog, plus ref_rate: fit, then the node accepts it."""
    from art_gyro_calibration.analysis.cli import main
    truth = load_packaged_calibration('NAVC4058')   # the simulated gyro's error: a real report polynomial
    t = np.arange(0.0, 7200.0, 0.5)
    table = RateProfile.parse('300:0,300:20,300:-40,300:60,300:-80,300:90')
    sim = GyroSimulator(truth, table, TemperatureProfile.parse_ramp('10:50:7200'), noise_dps=0.005, seed=2)
    rate_dps, temp_c = sim.readings(t)
    log = tmp_path / 'table.csv'
    write_columns(log, {'t': t, 'raw_rate': rate_dps, 'raw_temp': temp_c, 'ref_rate': table.rate_at(t)})
    cal_path = tmp_path / 'fitted.yaml'
    assert main(['fit', str(log), '--rows', '3', '--columns', '2', '--serial', EXAMPLE, '--out', str(cal_path),
                 '--report', str(tmp_path / 'REPORT.json')]) == 0
    fitted = load_calibration(cal_path, expected_serial=EXAMPLE)
    check_kvh_fog_calibration(fitted, str(cal_path))   # scale factors 1.0, from the packaged example
    # The fit found the simulated polynomial (its constant goes into the static bias).
    assert fitted.polynomial.coefficients.ravel()[:-1] == pytest.approx(
        truth.polynomial.coefficients.ravel()[:-1], rel=0.02, abs=1e-6)
    assert main(['apply', str(log), '--calibration', str(cal_path), '--out', str(tmp_path / 'out.csv'),
                 '--bias-samples', '100']) == 0
    out = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    assert np.sqrt(np.mean((out['corrected_dps'] - table.rate_at(t)) ** 2)) < 0.01


def test_node_says_when_the_temperature_units_do_not_match_the_unit(tmp_path: Path, loopback: None) -> None:
    """The unit sends hundredths of a degree, the node is told degrees: 2500 degC is dropped, and the hint names it."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    with (FakeGyro(EXAMPLE, protocol='kvh_fog', rate_hz=RATE_HZ, temperature=25.0,
                   kvh_fog=KvhFogConfig(temperature_units='C_100')) as fake,
          node_with_listener(domain, output, '--params-file', str(REPO / 'config' / 'kvh_fog.params.yaml'),
                             '-p', f'port:={fake.path}', '-p', f'kvh_fog.output_rate_hz:={RATE_HZ}')
          as (proc, listener)):
        status = listener.wait_status('temperature', lambda s: s['level'] == b'\x02', 'the temperature error',
                                      proc, output)
        assert 'kvh_fog.temperature_units is not what the unit sends' in status['message'], status['message']
        assert int(status['frames_implausible_temperature']) > 0 and listener.count() == 0


@pytest.mark.parametrize('args, message', [
    (['-p', 'protocol:=kvh_fog', '-p', 'serial_number:=NAVC3545'],
     'parameter protocol is kvh_fog, whose samples are deg/s and degC, but the calibration of NAVC3545'),
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.yaw_axis:=up'],
     'parameter kvh_fog.yaw_axis must be x, y or z'),
    (['-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.output_rate_hz:=fast'],
     'parameter kvh_fog.output_rate_hz must be a number'),
    # YAML reads a bare y as true: refused with the hint, not "must be a string, got True".
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.yaw_axis:=y'],
     'parameter kvh_fog.yaw_axis must be x, y or z with an optional sign, got the boolean True: YAML reads a bare '
     'y or n as a boolean; write +y (or -y), or quote it'),
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.forward_axis:=n'],
     'parameter kvh_fog.forward_axis must be x, y or z with an optional sign, got the boolean False'),
    # Without baud, kvh_fog opens at the unit's 921600, which carries 2560 Format A messages a second.
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.output_rate_hz:=5000.0'],
     'parameter kvh_fog.output_rate_hz is 5000 but baud 921600 carries at most 2560 Format A messages'),
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'baud:=4147200',
      '-p', 'kvh_fog.rate_stddev:=0.0'], 'parameter kvh_fog.rate_stddev must be in 1e-07..1, got 0.0'),
    (['-p', 'protocol:=kvh_fog', '-p', f'serial_number:={EXAMPLE}', '-p', 'kvh_fog.timestamp_source:=unit_clock'],
     'parameter kvh_fog.timestamp_source unit_clock needs kvh_fog.message_format B'),
], ids=['rd2100_calibration', 'yaw_axis', 'output_rate_type', 'yaw_axis_yaml_y', 'forward_axis_yaml_n',
        'rate_beyond_baud', 'rate_stddev', 'unit_clock_needs_b'])
def test_node_refuses_bad_kvh_fog_settings(tmp_path: Path, args: list[str], message: str) -> None:
    output = tmp_path / 'node.log'
    proc = start_node(domain_id(), output, '-p', 'port:=/nonexistent', *args)
    assert proc.wait(TIMEOUT_S) != 0
    text = output.read_text()
    assert text.startswith('gyro_node: error: ') and message in text, text
    assert 'Traceback' not in text


def test_kvh_fog_params_file_sets_valid_node_parameters() -> None:
    """config/kvh_fog.params.yaml names node parameters only, with valid values: the factory-set unit."""
    params = parameter_dict_from_yaml_file(str(REPO / 'config' / 'kvh_fog.params.yaml'))
    values = {name: parameter_value_to_python(p.value) for name, p in params.items()}
    assert set(values) <= set(PARAMETERS) | set(KVH_FOG_PARAMETERS)
    settings = check_settings({**{n: d for n, (d, *_) in PARAMETERS.items()},
                               **{n: v for n, v in values.items() if n in PARAMETERS}})
    assert settings.protocol == 'kvh_fog' and settings.serial_number == EXAMPLE
    kvh = KvhFogConfig(**{n.removeprefix('kvh_fog.'): v for n, v in values.items()
                          if n in KVH_FOG_PARAMETERS and not n.endswith('_stddev')})
    assert kvh == KvhFogConfig() and set(values) >= set(KVH_FOG_PARAMETERS)
    assert math.isclose(kvh.dps_per_unit, math.degrees(1000.0))
    assert values['baud'] == 921600 and kvh.max_rate_hz(values['baud']) >= kvh.output_rate_hz


def test_help_lists_every_kvh_fog_parameter() -> None:
    text = usage('gyro_node')
    assert all(f'  {name} (' in text for name in KVH_FOG_PARAMETERS), text


def test_node_publishes_the_right_rate_when_output_rate_hz_is_wrong_and_says_so(tmp_path: Path,
                                                                                loopback: None) -> None:
    """A unit at 100 Hz, output_rate_hz left at 1000 (and baud at the kvh_fog default): 30 deg/s, and an ERROR."""
    domain = domain_id()
    output = tmp_path / 'node.log'
    with (FakeGyro(EXAMPLE, protocol='kvh_fog', rate_hz=RATE_HZ, profile='30', temperature=30.0, seed=7) as fake,
          node_with_listener(domain, output, '-p', f'port:={fake.path}', '-p', 'protocol:=kvh_fog',
                             '-p', f'serial_number:={EXAMPLE}', '-p', 'static_bias_on_startup:=false')
          as (proc, listener)):
        turning = listener.wait_imu(100, proc, output)[-50:]
        # No static bias: the reading is the turn plus the turn-on bias and the Earth's rate.
        truth = 30.0 + fake.simulator.turn_on_bias_dps + fake.simulator.earth_rate_dps
        assert rates_dps(turning).mean() == pytest.approx(truth, abs=0.05)
        link = listener.wait_status('link', lambda s: s['level'] == b'\x02', 'the rate error', proc, output)
        assert 'kvh_fog.output_rate_hz is 1000 Hz but the unit sends ' in link['message'], link['message']
        assert float(link['message'].split('unit sends ')[1].split()[0]) == pytest.approx(RATE_HZ, rel=0.01)
        assert float(link['measured_rate_hz']) == pytest.approx(RATE_HZ, rel=0.01)
        wait_until(lambda: 'kvh_fog.output_rate_hz is 1000 Hz' in output.read_text(), 'the console error')
        assert 'at 921600 baud (kvh_fog)' in output.read_text()


def test_imu_axes_flagged_invalid_or_not_finite_are_not_measured() -> None:
    """_fill_imu as the node calls it: REP 103 axes from the mounting; a bad axis gets no weight, never a NaN."""
    from types import SimpleNamespace

    from art_gyro_calibration.frame import ImuReading
    from art_gyro_calibration.ros.node import UNMEASURED_VARIANCE, GyroNode
    axes = KvhFogConfig(yaw_axis='+y', forward_axis='-x').description.imu_axes   # x = -x_unit, y = +z_unit, z = +y_unit
    assert axes == ((0, -1.0), (2, 1.0), (1, 1.0))
    node = SimpleNamespace(_axes=axes, _rate_variance=1e-6, _acceleration_variance=0.0025)
    imu: dict[str, float] = {}   # the Imu fields written, by name
    GyroNode._fill_imu(node, imu.__setitem__, ImuReading((10.0, 20.0, 30.0), (0.5, 1.0, -0.25)))
    assert (imu['angular_velocity.x'], imu['angular_velocity.y']) == pytest.approx(
        (math.radians(-10.0), math.radians(30.0)))
    assert (imu['linear_acceleration.x'], imu['linear_acceleration.y'], imu['linear_acceleration.z']) == pytest.approx(
        (-0.5 * 9.80665, -0.25 * 9.80665, 9.80665))
    assert imu['angular_velocity_covariance[0]'] == imu['angular_velocity_covariance[4]'] == 1e-6
    GyroNode._fill_imu(node, imu.__setitem__, ImuReading((math.nan, 20.0, 30.0), (0.5, math.inf, 0.0)))
    assert imu['angular_velocity.x'] == 0.0 and imu['angular_velocity_covariance[0]'] == UNMEASURED_VARIANCE
    assert imu['linear_acceleration_covariance[0]'] == -1.0 and imu['linear_acceleration.y'] == 0.0
    GyroNode._fill_imu(node, imu.__setitem__, ImuReading((10.0, 20.0, 30.0), (0.5, 1.0, 0.0),
                                                         rate_valid=(True, True, False)))
    assert imu['angular_velocity.y'] == 0.0 and imu['angular_velocity_covariance[4]'] == UNMEASURED_VARIANCE
