"""The driver on protocol kvh_fog against the fake KVH unit on a pty: the unit's settings, lost frames, stamps."""

import threading
import time

import pytest

from test_driver import wait_for

from art_gyro_calibration.driver import SerialGyroDriver
from art_gyro_calibration.fake_gyro import FakeGyro
from art_gyro_calibration.frame import BITS_PER_BYTE, Frame
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig


def test_driver_reads_kvh_fog_counts_lost_frames_and_stamps_with_the_message_length():
    frames: list[Frame] = []
    lock = threading.Lock()

    def on_frame(frame):
        with lock:
            frames.append(frame)

    config = KvhFogConfig(message_format='C', yaw_axis='y', rotation='rate', angle_units='deg')
    with FakeGyro('NAVC4361', protocol='kvh_fog', rate_hz=200, profile='12.5', temperature=22.0,
                  noise_dps=0.0, turn_on_bias_dps=0.0, kvh_fog=config) as fake:
        driver = SerialGyroDriver(fake.path, 921600, 'kvh_fog', on_frame, kvh_fog=fake.kvh_fog)
        # The stamp's wire-time correction: the whole 38-byte message of Format C at 921600 baud.
        assert driver._stamper.frame_ns == 38 * (BITS_PER_BYTE * 1_000_000_000 // 921600)
        driver.start()
        try:
            assert wait_for(lambda: len(frames) > 20)
            fake.drop(9)
            assert wait_for(lambda: driver.stats.lost_frames == 9 and len(frames) > 60)
        finally:
            driver.stop()
    stats = driver.stats
    assert stats.lost_frames == 9 and stats.rejected_by_reason['bad_crc'] == 0
    with lock:
        samples = [f.sample for f in frames]
        stamps = [f.stamp_ns for f in frames]
    reading = fake.simulator.readings([0.0])[0].item()
    assert all(abs(s.raw_rate - reading) < 1e-5 and s.raw_temp == 22.0 for s in samples)
    assert all(b >= a for a, b in zip(stamps, stamps[1:])) and abs(stamps[-1] - time.time_ns()) < 5e9


@pytest.mark.parametrize('baud', [576000, 4147200])
def test_driver_opens_a_kvh_unit_at_its_own_bauds(baud):
    """The unit's =BAUD list has rates no RD2100 uses: pyserial sets them on Linux and frames come through."""
    frames: list[Frame] = []
    config = KvhFogConfig(rotation='rate')
    with FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=100, kvh_fog=config) as fake:
        driver = SerialGyroDriver(fake.path, baud, 'kvh_fog', frames.append, kvh_fog=fake.kvh_fog)
        driver.start()
        try:
            assert wait_for(lambda: len(frames) > 5)
        finally:
            driver.stop()
    assert driver.stats.last_error == '' and driver.stats.reopens == 0


def test_driver_gives_delta_angles_rates_by_the_measured_interval_not_the_configured_one():
    """A 200 Hz unit, the driver told 1000 Hz: 30 deg/s read as 30 (the stream's interval), after a second."""
    frames: list[Frame] = []
    with FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=200, profile='30', noise_dps=0.0,
                  turn_on_bias_dps=0.0, temperature=25.0) as fake:
        told = KvhFogConfig()   # output_rate_hz 1000
        driver = SerialGyroDriver(fake.path, 921600, 'kvh_fog', frames.append, kvh_fog=told)
        driver.start()
        try:
            assert wait_for(lambda: len(frames) > 200, timeout_s=20.0)
        finally:
            driver.stop()
    truth = fake.simulator.readings([0.0])[0].item()   # 30 deg/s plus the Earth's rate
    assert [f.sample.raw_rate for f in frames[-100:]] == pytest.approx([truth] * 100, rel=5e-3)
    assert driver.stats.measured_rate_hz == pytest.approx(200.0, rel=5e-3)
    assert driver.stats.rejected_by_reason['no_interval'] >= 150


def test_driver_stamps_format_b_by_the_units_clock_and_falls_back_to_arrival_on_a_clock_fault():
    """timestamp_source unit_clock: once mapped, stamps are the unit's period apart (not the reads').

    A clock that jumps back is said; stamps go by arrival until it is mapped again, and never back.
    """
    frames: list[Frame] = []
    warnings: list[str] = []
    lock = threading.Lock()

    def on_frame(frame):
        with lock:
            frames.append(frame)

    config = KvhFogConfig(message_format='B', rotation='rate', timestamp_source='unit_clock')
    with FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=200, kvh_fog=config) as fake:
        driver = SerialGyroDriver(fake.path, 921600, 'kvh_fog', on_frame, kvh_fog=fake.kvh_fog,
                                  on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.stamp_source == 'unit_clock', timeout_s=20.0)
            start = len(frames)
            assert wait_for(lambda: len(frames) > start + 200, timeout_s=20.0)
            with lock:
                mapped = [f.stamp_ns for f in frames[start:start + 200]]
            with fake._lock:
                fake.encoder.unit_time_us -= 10e6   # the unit's clock goes back 10 s
            assert wait_for(lambda: driver.stats.stamp_source == 'arrival')
            assert wait_for(lambda: driver.stats.stamp_source == 'unit_clock', timeout_s=20.0)
        finally:
            driver.stop()
    spacing = sorted(b - a for a, b in zip(mapped, mapped[1:]))
    # The unit's 5 ms (by arrival, frames read together would be a wire time apart), but where the mapping's
    # offset moves to a less delayed arrival.
    assert all(4_990_000 < s < 5_010_000 for s in spacing[10:-10]), spacing
    assert any('stamps by arrival until it is mapped again' in w for w in warnings), warnings
    with lock:
        stamps = [f.stamp_ns for f in frames]
    assert all(b > a for a, b in zip(stamps, stamps[1:])) and abs(stamps[-1] - time.time_ns()) < 5e9
