"""Tests of the simulated RD2100: its physics without a pty, then the pty, the link and the console entry."""

import dataclasses
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import serial

from art_gyro_calibration.calibration import CalibrationError, load_packaged_calibration
from art_gyro_calibration.fake_gyro import (MAX_PENDING_BYTES, FakeGyro, GyroSimulator, RateProfile,
                                            TemperatureProfile, default_noise_dps)
from art_gyro_calibration.gyro_physics import ANN_ARBOR_LATITUDE_DEG, earth_rate_dps
from art_gyro_calibration.protocols import make_parser
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig

REPO = Path(__file__).resolve().parent.parent


def simulator(serial_number, profile='0', temperature=25.0, noise_dps=0.0, seed=0, bias=0.0):
    return GyroSimulator(load_packaged_calibration(serial_number), RateProfile.parse(profile),
                         TemperatureProfile(temperature), noise_dps, seed, bias)


@pytest.mark.parametrize('true_rate, temp', [(0.0, 15.0), (50.0, 25.0), (-85.0, 40.0), (85.0, 35.0)])
def test_mean_reading_carries_the_calibrated_error(serial, true_rate, temp):
    """Mean reading minus true rate is comp(m, T) + turn-on bias + earth rate, within noise.

    ``m`` is the reading without bias and earth rate: the polynomial is the error of the
    sensor's rate, the bias and earth rate add to what it reads.
    """
    sim = simulator(serial, str(true_rate), temp, noise_dps=default_noise_dps(10.0), seed=11, bias=0.015)
    cal = sim.calibration
    raw_rate, raw_temp = sim.counts(np.arange(4000) * 0.1)
    mean_reading = raw_rate.mean() * cal.rate_scale_factor
    offset = 0.015 + earth_rate_dps(ANN_ARBOR_LATITUDE_DEG)
    expected_error = cal.polynomial.error_one(mean_reading - offset, temp) + offset
    # Standard error of the mean 0.005 / sqrt(4000) < 1e-4; the noise dithers the 0.003 deg/s counts.
    assert mean_reading - true_rate == pytest.approx(expected_error, abs=5e-4)
    assert np.all(raw_temp == round(temp / 0.05))


def test_error_is_the_model_not_zero():
    sim = simulator('NAVC3545', bias=0.0)
    reading = sim.reading_dps(90.0, 40.0).item()
    assert abs(reading - 90.0) > 0.5   # the polynomial's scale-factor error at 90 deg/s is large
    # Less the earth rate, compensating the noise-free reading with the calibration recovers the true rate.
    sensor = reading - earth_rate_dps(ANN_ARBOR_LATITUDE_DEG)
    assert sensor - sim.calibration.polynomial.error_one(sensor, 40.0) == pytest.approx(90.0, abs=1e-9)


def test_readings_saturate_at_the_16_bit_count_range():
    sim = simulator('NAVC3545')
    assert sim.counts([0.0])[0].item() < 100
    assert simulator('NAVC3545', '150').counts([0.0])[0].item() == 32767
    assert simulator('NAVC3545', '-150').counts([0.0])[0].item() == -32768


@pytest.mark.parametrize('rate_hz', [10.0, 1000.0])
def test_noise_has_the_rd2100_level_and_scales_with_sqrt_rate(rate_hz):
    sim = simulator('NAVC4361', noise_dps=default_noise_dps(rate_hz), seed=3)
    raw_rate, _ = sim.counts(np.arange(20000) / rate_hz)
    std = np.std(raw_rate * sim.calibration.rate_scale_factor)
    assert std == pytest.approx(0.005 * np.sqrt(rate_hz / 10.0), rel=0.1)


def test_seed_makes_runs_reproducible_and_draws_the_turn_on_bias():
    a = GyroSimulator(load_packaged_calibration('NAVC4253'), RateProfile.parse('5'), TemperatureProfile(20.0),
                      0.01, seed=42)
    b = GyroSimulator(load_packaged_calibration('NAVC4253'), RateProfile.parse('5'), TemperatureProfile(20.0),
                      0.01, seed=42)
    t = np.arange(100) * 0.1
    assert a.turn_on_bias_dps == b.turn_on_bias_dps != 0.0
    assert all(np.array_equal(x, y) for x, y in zip(a.counts(t), b.counts(t)))


def test_rate_profile_segments_repeat():
    profile = RateProfile.parse('2:10,3:-5')
    assert profile.rate_at([0.0, 1.99, 2.0, 4.99, 5.0, 7.5, 10.0]).tolist() == [10, 10, -5, -5, 10, -5, 10]
    assert RateProfile.parse('12.5').rate_at([0.0, 1e6]).tolist() == [12.5, 12.5]


@pytest.mark.parametrize('text', ['', 'fast', '1:2:3', '0:5', '-1:5', '2:nan', '2:5,'])
def test_bad_rate_profiles_are_refused(text):
    with pytest.raises(ValueError, match='rate profile'):
        RateProfile.parse(text)


def test_temperature_ramps_then_holds():
    ramp = TemperatureProfile.parse_ramp('15:35:100')
    assert ramp.temperature_at([0.0, 50.0, 100.0, 1000.0]).tolist() == [15.0, 25.0, 35.0, 35.0]
    sim = GyroSimulator(load_packaged_calibration('NAVC3545'), RateProfile.parse('0'), ramp, 0.0, 0, 0.0)
    assert sim.counts([0.0, 50.0, 100.0])[1].tolist() == [300, 500, 700]
    for bad in ('15:35', '15:35:0', 'a:b:c'):
        with pytest.raises(ValueError, match='temperature ramp'):
            TemperatureProfile.parse_ramp(bad)


def test_constructor_refusals(tmp_path):
    precious = tmp_path / 'precious'
    precious.write_text('keep')
    with pytest.raises(ValueError, match='not a symlink'):
        FakeGyro('NAVC3545', link=str(precious))
    assert precious.read_text() == 'keep'
    with pytest.raises(ValueError, match='unknown protocol'):
        FakeGyro('NAVC3545', protocol='nmea')
    with pytest.raises(ValueError, match='rate_hz'):
        FakeGyro('NAVC3545', rate_hz=0)
    with pytest.raises(CalibrationError, match='NAVC0000'):
        FakeGyro('NAVC0000')


# --- on the pty -------------------------------------------------------------------------


def read_for(fd, want, timeout_s=10.0):
    """Read a raw fd until ``want`` bytes arrived or the timeout."""
    data = b''
    deadline = time.monotonic() + timeout_s
    while len(data) < want and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.1)[0]:
            data += os.read(fd, 4096)
    return data


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_frames_on_the_pty_decode_to_the_simulated_counts(protocol):
    with FakeGyro('NAVC4377', protocol=protocol, rate_hz=100, profile='-20', temperature=18.0,
                  noise_dps=0.0, turn_on_bias_dps=0.0) as fake:
        with serial.Serial(fake.path, 115200, timeout=0.1) as port:
            data = b''
            deadline = time.monotonic() + 10.0
            while len(data) < 200 and time.monotonic() < deadline:
                data += port.read(200)
    parser = make_parser(protocol)
    got = {(s.raw_rate, s.raw_temp) for s, _ in parser.feed(data)}
    assert got == {tuple(int(v[0]) for v in fake.simulator.counts([0.0]))}
    assert parser.stats.frames >= 10


def inject_and_read(fake, data):
    """Open the fake's port as a bare reader (no termios set up), inject ``data`` and read it back."""
    fd = os.open(fake.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fake.inject(data)
        return read_for(fd, len(data))
    finally:
        os.close(fd)


def test_pty_is_raw_so_no_byte_is_translated():
    fake = FakeGyro('NAVC3545')   # not started: only injected bytes are sent
    try:
        garbage = bytes(range(256))
        assert inject_and_read(fake, garbage) == garbage
    finally:
        fake.stop()


def test_bytes_nobody_reads_are_held_then_dropped_past_a_bound():
    fake = FakeGyro('NAVC3545')   # not started, and no reader: only injected bytes, and the pty fills
    try:
        total = 64 * 1024   # more than a pty buffers plus MAX_PENDING_BYTES
        for _ in range(total // 1024):
            fake.inject(bytes(1024))   # never an error
        assert fake.dropped > 0 and len(fake._pending) <= MAX_PENDING_BYTES
        fd = os.open(fake.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            buffered = read_for(fd, total, timeout_s=1.0)
        finally:
            os.close(fd)
        assert len(buffered) + len(fake._pending) + fake.dropped == total
    finally:
        fake.stop()


def test_link_follows_unplug_and_replug(tmp_path):
    link = str(tmp_path / 'rd2100')
    fake = FakeGyro('NAVC3545', link=link)
    try:
        assert fake.path == link and os.path.realpath(link).startswith('/dev/pts/')
        first = os.readlink(link)
        fake.unplug()
        assert not os.path.lexists(link)
        fake.inject(b'lost')   # unplugged: nothing to write to, and no error
        fake.replug()
        assert os.path.exists(link)
        assert inject_and_read(fake, b'\x81back') == b'\x81back'
        assert isinstance(first, str)
    finally:
        fake.stop()
    assert not os.path.lexists(link)


def test_a_link_that_cannot_be_made_leaks_no_pty(tmp_path):
    folder = tmp_path / 'dev'
    link = str(folder / 'rd2100')
    fds = len(os.listdir('/proc/self/fd'))
    with pytest.raises(FileNotFoundError):
        FakeGyro('NAVC3545', link=link)
    assert len(os.listdir('/proc/self/fd')) == fds
    folder.mkdir()
    fake = FakeGyro('NAVC3545', link=link)
    try:
        fake.unplug()
        folder.rmdir()
        with pytest.raises(FileNotFoundError):
            fake.replug()
        assert len(os.listdir('/proc/self/fd')) == fds   # still unplugged: no pty held
        folder.mkdir()
        fake.replug()
        assert os.path.realpath(link).startswith('/dev/pts/')
    finally:
        fake.stop()
    assert len(os.listdir('/proc/self/fd')) == fds


def test_stop_leaves_a_link_that_another_fake_took(tmp_path):
    link = str(tmp_path / 'rd2100')
    first = FakeGyro('NAVC3545', link=link)
    try:
        second = FakeGyro('NAVC3545', link=link)   # re-points the link: a renamed device
        try:
            first.stop()
            first.stop()   # twice is harmless
            assert os.path.realpath(link).startswith('/dev/pts/')
            assert inject_and_read(second, b'\x82second') == b'\x82second'
        finally:
            second.stop()
        assert not os.path.lexists(link)
    finally:
        first.stop()


def test_unplug_makes_an_open_reader_fail():
    with FakeGyro('NAVC3545', rate_hz=50) as fake:
        with serial.Serial(fake.path, 115200, timeout=0.5) as port:
            assert port.read(8)
            fake.unplug()
            with pytest.raises((serial.SerialException, OSError)):
                for _ in range(20):
                    port.read(8)


def test_paces_1000_hz_by_deadlines():
    t0 = time.monotonic()
    with FakeGyro('NAVC3545', rate_hz=1000) as fake:
        with serial.Serial(fake.path, 921600, timeout=0.1) as port:
            data = b''
            while time.monotonic() - t0 < 1.5:
                data += port.read(4096)
            sent, elapsed = fake.sent, time.monotonic() - t0
    frames = len(make_parser('binary').feed(data))
    # Deadlines from the start never run ahead of the clock; the lower bound is loose for a loaded machine.
    assert 0.5 * 1000 * elapsed < sent <= 1000 * elapsed + 1
    assert frames >= 0.5 * 1000 * elapsed


def run_main(*args):
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env['PYTHONPATH'] = os.pathsep.join([str(REPO)] + [p for p in [env.get('PYTHONPATH')] if p])
    return subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration.fake_gyro', *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_console_entry_prints_the_port_and_exits_0_on_signal(tmp_path, signum):
    link = str(tmp_path / 'gyro')
    proc = run_main('--serial', 'NAVC4058', '--link', link, '--protocol', 'ascii', '--rate-hz', '50',
                    '--temperature-ramp', '15:35:1800', '--profile', '1:5,1:-5', '--seed', '1')
    try:
        assert proc.stdout.readline().strip() == link
        with serial.Serial(link, 115200, timeout=0.2) as port:
            data = b''
            deadline = time.monotonic() + 10.0
            while data.count(b'\n') < 5 and time.monotonic() < deadline:
                data += port.read(100)
        assert len(make_parser('ascii').feed(data)) >= 3
        proc.send_signal(signum)
        assert proc.wait(10) == 0
        assert not os.path.lexists(link)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_console_entry_refuses_an_unknown_serial():
    proc = run_main('--serial', 'NAVC0000')
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and 'NAVC0000' in err


# --- protocol kvh_fog -----------------------------------------------------------------------------

def as_sent(config):
    """A parser of what the fake sends, its floats as they are: a delta angle's interval is the node's to measure."""
    return make_parser('kvh_fog', dataclasses.replace(config, rotation='rate'))


def read_port(path, want_bytes, baud=921600, timeout_s=10.0):
    with serial.Serial(path, baud, timeout=0.1) as port:
        data = b''
        deadline = time.monotonic() + timeout_s
        while len(data) < want_bytes and time.monotonic() < deadline:
            data += port.read(4096)
    return data


@pytest.mark.parametrize('config', [KvhFogConfig(), KvhFogConfig('C', '-x', 'rate', 'deg', 1000.0, 'C_100')],
                         ids=['factory', 'C_-x_rate_deg_C100'])
def test_kvh_fog_messages_on_the_pty_carry_the_simulated_reading(config):
    """The unquantised reading in the unit's settings, at the fake's own output rate, numbered without gaps."""
    with FakeGyro('NAVC4377', protocol='kvh_fog', rate_hz=200, profile='-20', temperature=18.25,
                  noise_dps=0.0, turn_on_bias_dps=0.0, kvh_fog=config) as fake:
        data = read_port(fake.path, 40 * config.format.length)
    assert fake.kvh_fog.output_rate_hz == 200.0 and fake.kvh_fog.yaw_axis == config.yaw_axis
    parser = as_sent(fake.kvh_fog)
    per_second = fake.rate_hz if config.delta_angle else 1.0   # a delta angle is the rate over one interval
    got = [(s.raw_rate * per_second, s.raw_temp) for s, _ in parser.feed(data)]
    reading = fake.simulator.readings([0.0])[0].item()
    assert abs(reading + 20.0) > 0.01   # the calibrated error is in it
    # The port may open mid-message (one garbage run) and, in Format C, before a temperature (up to 3 messages).
    reasons = parser.stats.rejected_by_reason
    assert len(got) >= 30 and parser.stats.lost_frames == reasons['bad_crc'] == 0
    assert parser.stats.garbage_runs <= 1 and reasons['no_temperature_yet'] <= 3
    assert [r for r, _ in got] == pytest.approx([reading] * len(got), rel=1e-6)
    assert [t for _, t in got] == pytest.approx([18.25 if config.temperature_units == 'C_100' else 18.0] * len(got))


def test_drop_loses_frames_on_the_wire_which_the_sequence_shows():
    with FakeGyro('NAVC3545', protocol='kvh_fog', rate_hz=200) as fake:
        with serial.Serial(fake.path, 921600, timeout=0.1) as port:
            parser = as_sent(fake.kvh_fog)
            deadline = time.monotonic() + 10.0
            while parser.stats.frames < 10 and time.monotonic() < deadline:
                parser.feed(port.read(4096))
            fake.drop(7)
            while parser.stats.frames < 40 and time.monotonic() < deadline:
                parser.feed(port.read(4096))
    assert fake.lost == 7 and parser.stats.lost_frames == 7 and parser.stats.rejected_by_reason['bad_crc'] == 0


def test_console_entry_sends_kvh_fog():
    proc = run_main('--serial', 'KVH_DSP1760_EXAMPLE', '--protocol', 'kvh_fog', '--rate-hz', '100',
                    '--kvh-message-format', 'C', '--kvh-yaw-axis=-y', '--profile', '10')
    try:
        path = proc.stdout.readline().strip()
        data = read_port(path, 20 * 38)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    parser = as_sent(KvhFogConfig(message_format='C', yaw_axis='-y'))
    rates = [s.raw_rate * 100.0 for s, _ in parser.feed(data)]   # delta angles at 100 Hz
    assert len(rates) >= 10 and np.mean(rates) == pytest.approx(10.0, abs=0.1)
    bad = run_main('--serial', 'NAVC3545', '--protocol', 'kvh_fog', '--kvh-yaw-axis', 'up')
    _, err = bad.communicate(timeout=30)
    assert bad.returncode == 2 and 'kvh_fog.yaw_axis must be x, y or z' in err
