"""``calibrate apply`` on the node's own raw log gives exactly what the node published.

The node logs every frame it receives (``log_path``), drops the frames with an implausible
temperature and publishes the rest; ``apply`` over that log must drop the same frames and
give the same stamps and the same compensated rates, extended terms included.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosproc import domain_id, node_with_listener, wait_until  # noqa: E402

from art_gyro_calibration.analysis.cli import main  # noqa: E402
from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration  # noqa: E402
from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile, TemperatureProfile  # noqa: E402
from art_gyro_calibration.protocols.rd2100_binary import encode_binary  # noqa: E402
from art_gyro_calibration.signals import SignalFilters  # noqa: E402
from art_gyro_calibration.temperature_rate import FIRST_ORDER  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402

BIAS_SAMPLES = 20


def test_apply_on_the_node_log_equals_what_the_node_published(tmp_path: Path, loopback: None, capsys) -> None:
    # Every signal the node tracks, a lagged temperature with rate cross terms, and a temperature-rate
    # filter quick enough that the static bias refinement happens within the run.
    cal = dataclasses.replace(load_packaged_calibration('NAVC3545'), terms=(
        Term('temperature_rate', 'power', (0.02,), (1,)), Term('time', 'power', (1e-4,), (1,)),
        Term('time_since_power_on', 'exp_decay', (0.03,), (), 5.0),
        Term('temperature_lag', 'power', (1e-4, 2e-5), (1,), 3.0, (0, 1)),
        Term('rate_change', 'power', (0.002,), (1,))), filters=SignalFilters(0.2, temperature_rate_form=FIRST_ORDER),
        temperature_range_c=(10.0, 50.0), temperature_warn_range_c=None)   # fitted: clamped to its logged range
    cal_path = tmp_path / 'CAL.yaml'
    write_calibration(cal_path, cal)
    log_path = tmp_path / 'node.csv'
    output = tmp_path / 'node.log'
    fake = FakeGyro('NAVC3545', rate_hz=50.0, profile='0', temperature=TemperatureProfile.parse_ramp('20:40:30'),
                    seed=5)
    try:
        with node_with_listener(domain_id(), output, '--params-file', str(cal_path), '-p', f'port:={fake.path}',
                                '-p', 'baud:=115200', '-p', f'bias_samples:={BIAS_SAMPLES}',
                                '-p', f'log_path:={log_path}', '-p', 'powered_on_at_start:=true') as (proc, listener):
            # Frames only once the listener hears the node: it must receive every message from the first.
            wait_until(lambda: listener.history() and listener.node.count_publishers('imu/data_raw'),
                       'the node discovered', proc, output)
            time.sleep(1.0)
            fake.start()
            listener.wait_status('static bias', lambda s: s['state'] == 'ok', 'the startup static bias',
                                 proc, output)
            fake.simulator.profile = RateProfile.parse('0.7:30,0.5:-45')
            for raw_temp in (4000, -1400, 2599, -1199):   # 200, -70 degC: dropped; 129.95, -59.95 degC: kept
                # At the rate the gyro turns at: a frame jumping from it is rejected_rate_jump, not this test's.
                assert fake.last_sample is not None
                # Twice: a level, trusted by the frame guard from its second frame (a lone one is a temperature jump).
                fake.inject(encode_binary(int(fake.last_sample[0]), raw_temp) * 2)
                sent = fake.sent
                wait_until(lambda: fake.sent > sent + 20, 'frames after the injection')
            fake.stop()
            link = listener.wait_status('link', lambda s: s['connected'] == 'False', 'the fake gone', proc, output)
            wait_until(lambda: listener.count() >= int(link['published']), 'every message published', proc, output)
            status = listener.wait_status('temperature', lambda s: int(s['frames_implausible_temperature']) == 2,
                                          'the two implausible frames counted', proc, output)
            messages = listener.imu_since(0)
    finally:
        fake.stop()
    assert len(messages) == int(link['published'])
    capsys.readouterr()
    out = tmp_path / 'OUT.csv'
    assert main(['apply', str(log_path), '--calibration', str(cal_path), '--out', str(out),
                 '--bias-samples', str(BIAS_SAMPLES), '--powered-on-at-start']) == 0
    printed = capsys.readouterr().out
    data = np.loadtxt(out, delimiter=',', skiprows=1)
    t, rate, comp, corrected = data[:, 0], data[:, 1], data[:, 3], data[:, 4]
    assert len(data) == len(messages) > 100
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in messages])
    np.testing.assert_allclose(t, stamps, rtol=0, atol=1e-6)
    published = np.degrees([m.angular_velocity.z for m in messages])
    # The node published its first BIAS_SAMPLES - 1 frames before it had a static bias.
    expected = np.concatenate((rate[:BIAS_SAMPLES - 1] - comp[:BIAS_SAMPLES - 1], corrected[BIAS_SAMPLES - 1:]))
    np.testing.assert_allclose(published, expected, rtol=0, atol=2e-9)
    assert np.ptp(comp) > 0.1 and np.ptp(rate) > 60   # turning, warming: the terms and the polynomial at work
    assert status['frames_implausible_temperature'] == '2' and '2 dropped as the node drops them' in printed
    assert 'refined by' in printed   # the static bias refinement happened within the run, on both sides
    assert '2 outside the calibrated range' in printed   # 129.95 and -59.95 degC: compensated at the range's edge
