"""A calibration with a supply-voltage term, run by the node fed by a BatteryState topic.

Before, the node refused such a calibration at startup ("extended terms need signals ['supply_v'] that are
not available here"). Now it takes the voltage from the topic its parameter names, and flags the rate while
the voltage is missing or stale.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import TIMEOUT_S, Listener, domain_id, node_with_listener, start_node, wait_until  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro  # noqa: E402
from art_gyro_calibration.model import ArtPolynomial  # noqa: E402
from art_gyro_calibration.ros.node import UNCORRECTED_YAW_VARIANCE  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402

COEFFICIENT = 0.05   # deg/s per volt: a 2 V step moves the rate by 0.1 deg/s, far above the fake's noise
NOMINAL_V = 24.0
MAX_AGE_S = 1.0
ERROR = b'\x02'
CALIBRATED_VARIANCE = 0.001 ** 2   # yaw_rate_stddev's default, squared


def _calibration(path: Path) -> Path:
    """NAVC3545 with a supply term ``c * v``, its constant at the nominal voltage moved into the polynomial.

    A fitted power term has no constant: the polynomial holds it, so that the static bias check sees a still gyro.
    """
    cal = load_packaged_calibration('NAVC3545')
    coefficients = cal.polynomial.coefficients.copy()
    coefficients[-1, -1] -= COEFFICIENT * NOMINAL_V
    cal = dataclasses.replace(cal, polynomial=ArtPolynomial(coefficients),
                              terms=(Term('supply_v', 'power', (COEFFICIENT,), (1,)),))
    write_calibration(path, cal, 'NAVC3545 with a supply voltage term (test)')
    return path


def _mean_rate_dps(listener, proc, output, n: int = 30) -> float:
    messages = listener.wait_imu(n + 5, proc, output)[5:]   # skip what was in flight
    return float(np.degrees(np.mean([m.angular_velocity.z for m in messages])))


def _yaw_variances(listener, proc, output, n: int = 5) -> set[float]:
    return {m.angular_velocity_covariance[8] for m in listener.wait_imu(n, proc, output)}


def test_the_node_applies_a_fed_supply_voltage_and_flags_a_missing_or_stale_one(
        tmp_path: Path, loopback: None) -> None:
    domain = domain_id()
    output = tmp_path / 'node.log'
    calibration = _calibration(tmp_path / 'supply.yaml')
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=3) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={calibration}',
                             '-p', f'port:={fake.path}', '-p', 'bias_samples:=20',
                             '-p', 'extra_signals.supply_v.topic:=power/battery',   # relative: in /robot
                             '-p', 'extra_signals.supply_v.type:=battery_state',
                             '-p', f'extra_signals.supply_v.max_age_s:={MAX_AGE_S}', '-r', '__ns:=/robot',
                             namespace='/robot') as (proc, listener)):
        # No voltage yet: published, flagged, the static bias waits, the status names the signal and its topic.
        assert _yaw_variances(listener, proc, output) == {UNCORRECTED_YAW_VARIANCE}
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == ERROR, 'no voltage yet',
                                      proc, output)
        assert 'no supply_v received yet on /robot/power/battery' in status['message'], status
        bias = listener.wait_status('static bias', lambda s: s['state'] == 'collecting', 'a waiting bias', proc,
                                    output)
        assert 'waiting: no supply_v received yet' in bias['message'], bias
        assert int(listener.status('static bias')['samples']) == 0

        voltage = [NOMINAL_V]
        lock = threading.Lock()
        publisher = listener.node.create_publisher(BatteryState, 'power/battery', 10)

        def publish() -> None:
            with lock:
                publisher.publish(BatteryState(voltage=voltage[0]))
        listener.node.create_timer(0.05, publish)

        bias = listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the static bias', proc, output)
        assert int(bias['samples']) == 20
        # Until then (and whenever this process, loaded, publishes more than MAX_AGE_S late) a rate is flagged.
        wait_until(lambda: _yaw_variances(listener, proc, output) == {CALIBRATED_VARIANCE}, 'calibrated rates', proc,
                   output)
        assert abs(_mean_rate_dps(listener, proc, output)) < 0.01
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == b'\x00', 'a current voltage',
                                      proc, output)
        assert status['value'] == '24' and status['topic'] == '/robot/power/battery'

        # 2 V more: the term corrects 0.1 deg/s more (CompRate = rate - comp + CalcStaticBiasDrift).
        with lock:
            voltage[0] = NOMINAL_V + 2.0
        wait_until(lambda: listener.status('extra signal supply_v')['value'] == '26', 'the new voltage', proc, output)
        assert _mean_rate_dps(listener, proc, output) == pytest.approx(-2.0 * COEFFICIENT, abs=0.01)

        # NaN (BatteryState's "unknown") only: not a value; the last ages past max_age_s: still applied, flagged.
        with lock:
            voltage[0] = math.nan
        status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == ERROR, 'a stale voltage',
                                      proc, output)
        assert 'the last supply_v (26) is' in status['message'] and 'the last value is applied' in status['message']
        assert int(status['not_finite']) > 0
        assert _yaw_variances(listener, proc, output) == {UNCORRECTED_YAW_VARIANCE}
        assert _mean_rate_dps(listener, proc, output) == pytest.approx(-2.0 * COEFFICIENT, abs=0.01)

        # A call for a static bias now waits for a current voltage and says so.
        response = listener.static_bias(proc, output)
        assert not response.success and 'no frame to take for 5 s: the last supply_v (26)' in response.message, \
            response.message

        # The voltage back: no longer flagged.
        with lock:
            voltage[0] = NOMINAL_V
        wait_until(lambda: _yaw_variances(listener, proc, output) == {CALIBRATED_VARIANCE}, 'the flag cleared',
                   proc, output)


def test_a_float64_topic_remapped_and_a_topic_of_another_type_named(tmp_path: Path, loopback: None) -> None:
    """``type:=float64`` (std_msgs/Float64 data) on a remapped topic; a BatteryState there is named in the status."""
    output = tmp_path / 'node.log'
    calibration = _calibration(tmp_path / 'supply.yaml')
    domain = domain_id()
    with (FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'), profile='0', temperature=25.0, seed=4) as fake,
          node_with_listener(domain, output, '-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={calibration}',
                             '-p', f'port:={fake.path}', '-p', 'bias_samples:=20',
                             '-p', 'extra_signals.supply_v.topic:=supply', '-r', 'supply:=/bus/voltage')
          as (proc, listener)):
        wrong = listener.node.create_publisher(BatteryState, '/bus/voltage', 10)
        listener.node.create_timer(0.1, lambda: wrong.publish(BatteryState(voltage=NOMINAL_V)))
        status = listener.wait_status('extra signal supply_v', lambda s: 'is published as' in s['message'],
                                      'the other type named', proc, output)
        assert status['level'] == ERROR and status['topic'] == '/bus/voltage' and status['type'] == 'float64'
        assert ('/bus/voltage is published as sensor_msgs/msg/BatteryState: check extra_signals.supply_v.type'
                in status['message']), status
        # The right type beside it (another participant: one may not hold a topic name with two types).
        other = Listener(domain)
        try:
            right = other.node.create_publisher(Float64, '/bus/voltage', 10)
            other.node.create_timer(0.05, lambda: right.publish(Float64(data=NOMINAL_V)))
            listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the static bias', proc, output)
            status = listener.wait_status('extra signal supply_v', lambda s: s['level'] == b'\x00',
                                          'a current value', proc, output)
            assert status['value'] == '24'
            assert abs(_mean_rate_dps(listener, proc, output)) < 0.01
            assert _yaw_variances(listener, proc, output) == {CALIBRATED_VARIANCE}
        finally:
            other.close()


@pytest.mark.parametrize('args, message', [
    ([], 'set the node parameter extra_signals.supply_v.topic to the topic that carries it'),
    (['-p', 'extra_signals.supply_v.topic:=battery', '-p', 'extra_signals.supply_v.type:=int32'],
     'parameter extra_signals.supply_v.type must be one of float64, battery_state'),
    (['-p', 'extra_signals.supply_v.topic:=battery', '-p', 'extra_signals.supply_v.max_age_s:=0.0'],
     'parameter extra_signals.supply_v.max_age_s must be in 0.01..86400'),
    (['-p', 'extra_signals.supply_v.topik:=battery'],
     "unknown parameter 'extra_signals.supply_v.topik' (from the command line) (did you mean "
     "'extra_signals.supply_v.topic'?)"),
    (['-p', 'extra_signals.supply_v.topic:=battery', '-p', 'extra_signals.temperature.topic:=t'],
     'parameter extra_signals.temperature.topic: temperature is derived from the gyro'),
    (['-p', 'extra_signals.supply_v.topic:=bad topic'], 'parameter extra_signals.supply_v.topic:'),
], ids=['no_topic', 'type', 'max_age', 'misspelt', 'derived', 'topic_name'])
def test_a_supply_term_without_its_topic_or_with_bad_settings_is_refused_naming_the_parameter(
        tmp_path: Path, args: list[str], message: str) -> None:
    output = tmp_path / 'node.log'
    proc = start_node(domain_id(), output, '-p', 'serial_number:=NAVC3545', '-p', 'port:=/nonexistent',
                      '-p', f'calibration_file:={_calibration(tmp_path / "supply.yaml")}', *args)
    try:
        code = proc.wait(TIMEOUT_S)
    except Exception:
        proc.kill()
        proc.wait()
        raise AssertionError(f'the node ran instead of refusing:\n{output.read_text()}') from None
    text = output.read_text()
    assert code != 0 and text.startswith('gyro_node: error: ') and message in text, text
    assert 'Traceback' not in text
