"""Tests of the serial gyro driver against the fake gyro on a real pseudo-terminal."""

import threading
import time

import numpy as np
import pytest

from art_gyro_calibration.driver import BAUDS, STANDARD_BAUDS, SerialGyroDriver
from art_gyro_calibration.fake_gyro import FakeGyro
from art_gyro_calibration.frame import GARBAGE, LOCK_FRAMES, UNLOCKED, Frame
from art_gyro_calibration.protocols.rd2100_binary import encode_binary

TIMEOUT_S = 10.0   # generous: the machine is shared; nothing asserts how fast, only that it happens


def wait_for(predicate, timeout_s=TIMEOUT_S):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


class Recorder:
    """Frames and link events as the driver reports them (from its thread)."""

    def __init__(self):
        self.frames: list[Frame] = []
        self.host_ns: list[int] = []
        self.links: list[tuple[bool, str]] = []
        self.lock = threading.Lock()

    def on_frame(self, frame):
        with self.lock:
            self.frames.append(frame)
            self.host_ns.append(time.time_ns())

    def on_link(self, up, reason):
        with self.lock:
            self.links.append((up, reason))

    def count(self):
        with self.lock:
            return len(self.frames)

    def more_than(self, n):
        return lambda: self.count() > n


@pytest.fixture
def recorder():
    return Recorder()


@pytest.fixture
def make_driver(recorder):
    drivers = []

    def make(port, protocol='binary', baud=115200, reopen_period_s=0.05):
        driver = SerialGyroDriver(port, baud, protocol, recorder.on_frame, reopen_period_s=reopen_period_s,
                                  on_link=recorder.on_link)
        drivers.append(driver)
        driver.start()
        return driver

    yield make
    for driver in drivers:
        driver.stop()


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_frames_arrive_with_the_values_sent(make_driver, recorder, protocol):
    with FakeGyro('NAVC3545', protocol=protocol, rate_hz=50, profile='30', temperature=31.5,
                  noise_dps=0.0, turn_on_bias_dps=0.01) as fake:
        expected = tuple(int(v[0]) for v in fake.simulator.counts([0.0]))
        driver = make_driver(fake.path, protocol)
        assert wait_for(recorder.more_than(20))
        stats = driver.stats
        assert stats.connected and stats.frames >= 20 and stats.port == fake.path
        # Streaming from the start: the lock holds back at most its first frames, and nothing else is rejected.
        unlocked = stats.rejected_by_reason[UNLOCKED]
        assert unlocked <= LOCK_FRAMES - 1 and stats.rejected == unlocked
    assert expected == (round(fake.simulator.reading_dps(30.0, 31.5).item() / 0.00305), 630)
    assert {(f.sample.raw_rate, f.sample.raw_temp) for f in recorder.frames} == {expected}
    assert recorder.links[0][0] is True


def test_stamps_are_non_decreasing_and_close_to_host_time(make_driver, recorder):
    with FakeGyro('NAVC4361', rate_hz=200, seed=1) as fake:
        make_driver(fake.path)
        assert wait_for(recorder.more_than(100))
    with recorder.lock:
        stamps, host = [f.stamp_ns for f in recorder.frames], recorder.host_ns[:len(recorder.frames)]
    assert all(b >= a for a, b in zip(stamps, stamps[1:]))
    # Before the callback saw it, by at most the read latency (generous on a loaded machine).
    assert all(0 <= h - s < 1_000_000_000 for s, h in zip(stamps, host))


def test_driver_stamps_a_stalled_burst_by_the_period_and_reports_a_clock_step(recorder):
    """On a pty: the callback stalls for a second (the frames queue), the injected clock steps back 10 s."""
    offset = [0]
    warnings = []
    stall_at = 60
    stalled = threading.Event()

    def on_frame(frame):
        recorder.on_frame(frame)
        if recorder.count() == stall_at:
            time.sleep(1.0)
            stalled.set()

    with FakeGyro('NAVC3545', rate_hz=50, seed=8) as fake:
        driver = SerialGyroDriver(fake.path, 9600, 'binary', on_frame, on_warning=warnings.append,
                                  clock_ns=lambda: time.time_ns() + offset[0])
        driver.start()
        try:
            assert wait_for(stalled.is_set)
            assert wait_for(recorder.more_than(stall_at + 60))
            offset[0] = -10_000_000_000
            n = recorder.count()
            assert wait_for(recorder.more_than(n + 30))
        finally:
            driver.stop()
    with recorder.lock:
        stamps = np.array([f.stamp_ns for f in recorder.frames])
    steps = np.diff(stamps) * 1e-9
    # The stall's 50 queued frames are 20 ms apart like all the others (wire time would give 8 ms).
    burst = steps[stall_at:stall_at + 45]
    assert np.median(burst) == pytest.approx(0.02, rel=0.1), burst
    # One backward jump of about 10 s, said once.
    assert np.count_nonzero(steps < 0) == 1 and steps.min() == pytest.approx(-10.0, abs=0.2)
    assert len([w for w in warnings if 'the clock stepped by -' in w]) == 1, warnings


@pytest.mark.parametrize('garbage, expected', [
    (b'', 'nothing received from'),
    (bytes(range(0, 256, 3)) * 4, 'bytes skipped so far'),
])
def test_no_frames_after_opening_is_warned_once(garbage, expected, tmp_path):
    """A wrong baud or protocol used to give "gyro link up" and then nothing on the console."""
    warnings = []
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: no frames
    try:
        driver = SerialGyroDriver(silent.path, 9600, 'binary', lambda f: None, on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            silent.inject(garbage)
            assert wait_for(lambda: warnings)
            time.sleep(0.3)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert len(warnings) == 1 and expected in warnings[0] and silent.path in warnings[0], warnings
    if garbage:
        assert 'check the baud rate (9600) and the protocol (binary)' in warnings[0]


def test_garbage_is_counted_and_frames_keep_flowing(make_driver, recorder):
    with FakeGyro('NAVC4058', rate_hz=100, seed=2) as fake:
        driver = make_driver(fake.path)
        assert wait_for(recorder.more_than(5))
        for run, garbage in enumerate((b'\x00\x01\xfe\x7f', b'\xff\x10\x11'), start=1):
            fake.inject(garbage)
            n = recorder.count()
            assert wait_for(lambda: driver.stats.rejected_by_reason[GARBAGE] == run)
            assert wait_for(recorder.more_than(n + 5))
        stats = driver.stats
        # Each garbage run loses the lock: the LOCK_FRAMES - 1 frames after it (and at the start) are held back.
        unlocked = stats.rejected_by_reason[UNLOCKED]
        assert unlocked == 3 * (LOCK_FRAMES - 1)
        assert stats.bytes_skipped == 7 + 8 * unlocked and stats.rejected == 2 + unlocked


def test_the_baud_hint_fires_when_the_valid_share_falls_after_frames_came(recorder):
    """The hint fired only before the first frame: a link turned to garbage later was not said."""
    warnings = []
    with FakeGyro('NAVC3545', rate_hz=100, seed=4) as fake:
        driver = SerialGyroDriver(fake.path, 115200, 'binary', recorder.on_frame, on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(recorder.more_than(20))
            time.sleep(2.5)   # a whole window of good frames: nothing said
            assert warnings == []
            deadline = time.monotonic() + 5.0
            while not warnings and time.monotonic() < deadline:
                fake.inject(b'\x55' * 2000)
                time.sleep(0.05)
        finally:
            driver.stop()
    assert len(warnings) == 1, warnings
    assert 'were no valid frame' in warnings[0] and 'check the baud rate (115200)' in warnings[0], warnings


def test_a_frame_is_delivered_only_once_the_stream_is_locked(recorder, tmp_path):
    """Garbage with a valid frame now and then (a checksum passing by chance) went out as rates."""
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    try:
        driver = SerialGyroDriver(silent.path, 115200, 'binary', recorder.on_frame)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            for i in range(10):
                silent.inject(b'\x01\x02\xff' + encode_binary(100 + i, 500))
            assert wait_for(lambda: driver.stats.rejected_by_reason[UNLOCKED] == 10)
            silent.inject(b'\x01' + b''.join(encode_binary(i, 500) for i in range(LOCK_FRAMES + 2)))
            assert wait_for(lambda: driver.stats.frames == 3)
            time.sleep(0.2)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert [f.sample.raw_rate for f in recorder.frames] == list(range(LOCK_FRAMES - 1, LOCK_FRAMES + 2))
    assert driver.stats.rejected_by_reason[UNLOCKED] == 10 + LOCK_FRAMES - 1


def test_port_missing_at_start_then_appearing(make_driver, recorder, tmp_path):
    link = str(tmp_path / 'rd2100')
    driver = make_driver(link)
    assert wait_for(lambda: len(recorder.links) >= 1)
    time.sleep(0.3)   # several retries: the loss is reported once, not per retry
    assert recorder.links == [(False, recorder.links[0][1])] and link in recorder.links[0][1]
    assert not driver.stats.connected and 'cannot open' in driver.stats.last_error
    with FakeGyro('NAVC4377', rate_hz=50, link=link, seed=3):
        assert wait_for(recorder.more_than(5))
    assert recorder.links[1][0] is True
    assert driver.stats.reopens == 0   # the first open is not a reopen


def test_unplug_and_replug_survived_several_times(make_driver, recorder, tmp_path):
    link = str(tmp_path / 'rd2100')
    with FakeGyro('NAVC4253', rate_hz=100, link=link, seed=4) as fake:
        driver = make_driver(link)
        assert wait_for(recorder.more_than(5))
        for cycle in range(1, 4):
            fake.unplug()
            assert wait_for(lambda: not driver.stats.connected)
            n = recorder.count()
            fake.replug()
            assert wait_for(recorder.more_than(n + 5)), f'no frames after replug {cycle}'
            assert driver.stats.reopens == cycle
    ups = [up for up, _ in recorder.links]
    assert ups[:7] == [True, False, True, False, True, False, True]


def test_port_renamed_to_another_device_is_reopened(make_driver, recorder, tmp_path):
    link = str(tmp_path / 'rd2100')
    silent = FakeGyro('NAVC3545', link=link)   # not started: the port is open but sends nothing
    try:
        driver = make_driver(link)
        assert wait_for(lambda: driver.stats.connected)
        with FakeGyro('NAVC3545', rate_hz=50, link=link, seed=5):   # re-points the link
            assert wait_for(recorder.more_than(5))
            assert driver.stats.reopens == 1
        assert [up for up, _ in recorder.links[:3]] == [True, False, True]
        assert 'now names another device' in recorder.links[1][1]
    finally:
        silent.stop()


def test_stop_is_prompt_while_reading_and_while_retrying(recorder, tmp_path):
    with FakeGyro('NAVC3545', rate_hz=20, seed=6) as fake:
        reading = SerialGyroDriver(fake.path, 115200, 'binary', recorder.on_frame)
        reading.start()
        assert wait_for(recorder.more_than(2))
        t0 = time.monotonic()
        reading.stop()
        assert time.monotonic() - t0 < 1.0
        assert not reading.stats.connected
    retrying = SerialGyroDriver(str(tmp_path / 'absent'), 115200, 'binary', recorder.on_frame, reopen_period_s=30.0)
    retrying.start()
    time.sleep(0.1)
    t0 = time.monotonic()
    retrying.stop()
    assert time.monotonic() - t0 < 1.0


@pytest.mark.filterwarnings('ignore::pytest.PytestUnhandledThreadExceptionWarning')
def test_callback_exception_stops_the_reader_and_says_why(recorder):
    def broken(frame):
        raise RuntimeError('boom')

    with FakeGyro('NAVC3545', rate_hz=50, seed=7) as fake:
        driver = SerialGyroDriver(fake.path, 115200, 'binary', broken)
        driver.start()
        assert wait_for(lambda: 'boom' in driver.stats.last_error)
        driver.stop()
    assert not driver.stats.connected


@pytest.mark.parametrize('kwargs, message', [
    ({'baud': 12345}, 'baud 12345 is not a standard rate'),
    ({'protocol': 'nmea'}, "unknown protocol 'nmea'"),
    ({'port': ''}, 'port must be a device path'),
    ({'reopen_period_s': 0}, 'reopen_period_s must be a positive'),
])
def test_constructor_refuses_bad_arguments(kwargs, message):
    args = {'port': '/dev/ttyUSB0', 'baud': 115200, 'protocol': 'binary'} | kwargs
    with pytest.raises(ValueError, match=message):
        SerialGyroDriver(args['port'], args['baud'], args['protocol'], lambda f: None,
                         reopen_period_s=kwargs.get('reopen_period_s', 0.5))


@pytest.mark.parametrize('baud', BAUDS)
def test_every_baud_opens_the_port_and_times_the_wire_by_it(baud):
    """Each rate the driver accepts (the standard ones and a KVH unit's) opens a tty; a byte's wire time is its own."""
    assert set(STANDARD_BAUDS) <= set(BAUDS)
    silent = FakeGyro('NAVC3545')   # not started: a tty that sends nothing
    links = []
    try:
        driver = SerialGyroDriver(silent.path, baud, 'ascii', lambda f: None, on_link=lambda *link: links.append(link))
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert links[0] == (True, f'opened {silent.path} at {baud} baud') and driver.stats.last_error == ''
    assert driver._stamper.byte_ns == 10_000_000_000 // baud   # start, 8 data and stop bits


def test_a_backlog_written_at_once_is_delivered_whole_in_order_each_frame_with_its_own_stamp(recorder, tmp_path):
    """400 frames queued at once, as a USB adapter hands them over, are read together and each delivered once.

    In order, and stamped apart (not all with the read's one time).
    """
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    try:
        driver = SerialGyroDriver(silent.path, 115200, 'binary', recorder.on_frame, rate_scale_dps=0.00305)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            rates = [i % 50 for i in range(400)]   # 3,200 bytes: within one read
            silent.inject(b''.join(encode_binary(r, 500) for r in rates))
            assert wait_for(lambda: recorder.count() == len(rates) - (LOCK_FRAMES - 1))
            time.sleep(0.2)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert [f.sample.raw_rate for f in recorder.frames] == rates[LOCK_FRAMES - 1:]
    stamps = np.array([f.stamp_ns for f in recorder.frames])
    assert np.all(np.diff(stamps) > 0)


def test_frames_the_parser_refused_within_a_backlog_are_bridged_by_the_frame_guard(recorder, tmp_path):
    """A fault and the frames the stream lock holds back after it, read in one chunk with the frames around them.

    The frame guard lets the temperature move a count per frame since the last delivered one; the frames the
    parser refused took no time the stamps of one chunk show, and the first frame after them was refused as a
    temperature jump (a real frame lost: CI's intermittent test_line_faults_are_counted_and_no_good_frame_is_lost).
    """
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    temps = list(range(500, 520))   # a count a frame: the most the guard allows without a frame lost
    frames = [encode_binary(i % 3, t) for i, t in enumerate(temps)]
    try:
        driver = SerialGyroDriver(silent.path, 115200, 'binary', recorder.on_frame, rate_scale_dps=0.00305)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            silent.inject(b''.join(frames[:10]) + b'\x05' + b''.join(frames[10:]))
            # Every frame the lock let through, delivered or refused by the guard.
            assert wait_for(lambda: driver.stats.frames + driver.stats.rejected_by_reason['temperature_jump']
                            == len(frames) - 2 * (LOCK_FRAMES - 1))
        finally:
            driver.stop()
    finally:
        silent.stop()
    reasons = driver.stats.rejected_by_reason
    assert reasons[UNLOCKED] == 2 * (LOCK_FRAMES - 1) and reasons['temperature_jump'] == 0
    assert [f.sample.raw_temp for f in recorder.frames] == temps[LOCK_FRAMES - 1:10] + temps[10 + LOCK_FRAMES - 1:]


def test_a_stalled_burst_with_a_fault_is_stamped_when_each_frame_left_the_gyro():
    """The frames before a fault in a stall's burst keep the periods of the frames the parser refused after them.

    Spaced a period from the frame after the fault (the parser's refused frames unseen), each was stamped late by
    three periods: the bad frame's and the two the stream lock held back.
    """
    period, now = 100_000_000, [1_000_000_000]
    got: list[Frame] = []
    driver = SerialGyroDriver('/dev/null', 115200, 'binary', got.append, clock_ns=lambda: now[0],
                              monotonic_ns=lambda: now[0])
    byte_ns = 10 * 1_000_000_000 // 115200
    frames = [encode_binary(k % 3, 500) for k in range(70)]
    sent = [now[0] + k * period for k in range(70)]
    for k in range(50):   # one frame a read, each read as its last byte arrives
        now[0] = sent[k] + 8 * byte_ns
        driver._on_data(frames[k], now[0], now[0], 0)
    frames[58] = frames[58][:7] + bytes([frames[58][7] ^ 0x01])   # a bad checksum; the lock holds 59, 60 back
    now[0] = sent[69] + 8 * byte_ns   # a 2 s stall: the 20 frames after it in one read
    driver._on_data(b''.join(frames[50:]), now[0], now[0], 0)
    stamped = {round((f.stamp_ns - sent[0]) / period): f.stamp_ns for f in got}
    delivered = [k for k in range(LOCK_FRAMES - 1, 70) if k not in (58, 59, 60)]
    assert sorted(stamped) == delivered
    assert max(abs(stamped[k] - sent[k]) for k in delivered) < period / 10
