"""Tests of the RD2100 driver against the fake gyro on a real pseudo-terminal."""

import threading
import time

import numpy as np
import pytest

from art_gyro_calibration.driver import RATE_JUMP, STANDARD_BAUDS, SerialGyroDriver
from art_gyro_calibration.fake_gyro import FakeGyro
from art_gyro_calibration.frame import GARBAGE, LOCK_FRAMES, UNLOCKED, Frame
from art_gyro_calibration.protocols.rd2100_binary import encode_binary
from art_gyro_calibration.stamper import WireStamper

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


def test_stamper_subtracts_wire_time_and_never_goes_back():
    stamper = WireStamper(9600, 8)
    byte_ns = 1_041_666
    now = 10_000_000_000
    offset = 1_700_000_000_000_000_000   # the wall clock against the monotonic one
    # Three frames read in one 24-byte chunk, no period known yet: spaced by their wire time.
    stamps = [s for s, _ in stamper.stamp(now + offset, now, 24, [8, 16, 24])]
    assert stamps == [offset + now - 24 * byte_ns, offset + now - 16 * byte_ns, offset + now - 8 * byte_ns]
    # A read that returns with an earlier time (a late, delayed chunk) does not go back.
    (late, _), = stamper.stamp(now - 5 * byte_ns + offset, now - 5 * byte_ns, 8, [8])
    assert late > stamps[-1]


def _steady_gyro(stamper: WireStamper, clock, period_ns: int, frames: int, start_ns: int = 0):
    """Feed ``frames`` single-frame chunks a period apart; the stamps."""
    out = []
    for k in range(frames):
        mono = start_ns + k * period_ns
        out += stamper.stamp(clock(mono), mono, 8, [8])
    return out


def test_stamper_spaces_a_burst_after_a_stall_by_the_gyro_period():
    """Frames queued while the reader stalled were stamped 8 ms apart at 9600 baud instead of 100 ms (issue 9)."""
    period = 100_000_000
    stamper = WireStamper(9600, 8)
    _steady_gyro(stamper, lambda m: m, period, 50)
    assert stamper.period_ns == pytest.approx(period, rel=1e-6)
    # A 3 s stall: the 30 frames sent meanwhile arrive in one read, the last just before it returned.
    sent = [50 * period + k * period for k in range(30)]
    read = sent[-1] + 8 * stamper.byte_ns
    burst = stamper.stamp(read, read, 240, list(range(8, 241, 8)))
    assert [s for s, _ in burst] == pytest.approx(sent, abs=1_000_000)   # within 1 ms of when they were sent
    assert stamper.period_ns == pytest.approx(period, rel=1e-3)


def test_a_wrong_first_period_estimate_does_not_lock_the_stamps_at_wire_spacing():
    """A period first measured as a frame's wire time is corrected by the right measures after it.

    The frames queued before the open, read in two chunks a moment apart, once set the period to a frame's wire
    time (0.7 ms at 115200 baud); every right measure after it (20 ms, 29x) was then refused as an outlier, and
    the stamps stayed 0.7 ms apart: the flaky use_sim_time node test's 'median step 0.0007 s'.
    """
    period = 20_000_000
    stamper = WireStamper(115200, 8)
    start = 1_000_000_000
    stamper.stamp(start, start, 40, [8, 16, 24, 32, 40])          # five queued frames in the first read
    later = start + 10 * stamper.byte_ns
    stamper.stamp(later, later, 8, [8])                          # one more, a wire time later
    assert stamper.period_ns < period / 10                       # the first estimate is wrong
    stamps = [s for s, _ in _steady_gyro(stamper, lambda m: m, period, 100, start_ns=later + period)]
    assert np.median(np.diff(stamps[-50:])) == pytest.approx(period, rel=0.01)
    assert stamper.period_ns == pytest.approx(period, rel=0.01)


@pytest.mark.parametrize('step_s', [-10.0, 10.0])
def test_stamper_re_anchors_once_on_a_clock_step(step_s):
    """A backward step froze the stamps for as long as the step (999 equal stamps at 100 Hz, issue 9)."""
    period = 10_000_000
    step = int(step_s * 1e9)
    stamper = WireStamper(115200, 8)
    wall = 1_700_000_000_000_000_000
    before = _steady_gyro(stamper, lambda m: wall + m, period, 100)
    assert stamper.step_ns == 0
    mono = 100 * period
    first = stamper.stamp(wall + step + mono, mono, 8, [8])
    assert stamper.step_ns == 0   # one read is no step yet (see the glitch test)
    second = stamper.stamp(wall + step + mono + period, mono + period, 8, [8])
    assert stamper.step_ns == step and stamper.steps_ns == step
    after = first + second + _steady_gyro(stamper, lambda m: wall + step + m, period, 998,
                                          start_ns=mono + 2 * period)
    assert stamper.step_ns == 0
    stamps = np.array([s for s, _ in before + after])
    steps = np.diff(stamps)
    # One jump of the step, every other interval the gyro's period: integrating by stamps loses nothing.
    assert np.count_nonzero(np.abs(steps - period) > 1000) == 1
    assert steps[100] == pytest.approx(period + step, abs=1000)
    # The steady time goes on as if nothing happened.
    steady = np.array([t for _, t in before + after])
    assert np.all(np.abs(np.diff(steady) - period) < 1000)


def test_a_clock_that_goes_back_and_forth_for_one_read_is_no_step():
    """A simulated /clock applied out of order once (10 s back, then forward again) moves no stamp.

    The node stamped two jumps of -10 s in one sim-time run: one /clock message handled after a newer one.
    """
    period = 10_000_000
    stamper = WireStamper(115200, 8)
    wall = 1_700_000_000_000_000_000
    before = _steady_gyro(stamper, lambda m: wall + m, period, 100)
    mono = 100 * period
    glitch = stamper.stamp(wall - 10_000_000_000 + mono, mono, 8, [8])
    after = glitch + _steady_gyro(stamper, lambda m: wall + m, period, 100, start_ns=mono + period)
    assert stamper.steps_ns == 0
    steps = np.diff([s for s, _ in before + after])
    assert np.all(np.abs(steps - period) < 1000)


def test_the_steady_time_never_goes_back_across_a_step_after_a_stale_clock_read():
    """A /clock read 50 ms stale held the stamps up (never back); the step's chunk, not held, went 20 ms back.

    The node logs each frame at its steady time: its raw log then had a row before the last (a sim-time test
    on a loaded machine), which calibrate refuses.
    """
    period = 10_000_000
    stamper = WireStamper(115200, 8)
    wall = 1_700_000_000_000_000_000
    out = _steady_gyro(stamper, lambda m: wall + m, period, 100)
    mono = 100 * period
    out += stamper.stamp(wall + mono - 50_000_000, mono, 8, [8])
    out += _steady_gyro(stamper, lambda m: wall + 10_000_000_000 + m, period, 10, start_ns=mono + period)
    assert stamper.steps_ns == 10_050_000_000   # measured from the stale read
    steady = np.diff([t for _, t in out])
    assert np.all(steady > 0)
    # The 50 ms the stale read held the stamps up are taken back over the next frames, then the period again.
    assert np.all(np.abs(steady[:99] - period) < 1000) and np.all(np.abs(steady[-4:] - period) < 1000)


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
    """A wrong baud or protocol used to give "gyro link up" and then nothing on the console (issue 9)."""
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
    """The hint fired only before the first frame: a link turned to garbage later was not said (issue 25)."""
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
    """Garbage with a valid frame now and then (a checksum passing by chance) went out as rates (issue 25)."""
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


def test_standard_bauds_are_accepted():
    for baud in STANDARD_BAUDS:
        SerialGyroDriver('/dev/ttyUSB0', baud, 'ascii', lambda f: None)


def test_stamps_never_run_ahead_when_bytes_come_faster_than_the_baud():
    """1 kHz at the default 9600 baud ran 220 s ahead in 30 s; a 100k-frame burst at 115200, 52 s (issue 25)."""
    period = 1_000_000   # 1 kHz, 8 bytes a frame: 8000 bytes/s where 9600 baud carries 960
    stamper = WireStamper(9600, 8)
    ahead = 0
    for k in range(30_000):   # 30 s, read frame by frame
        mono = 5_000_000_000 + k * period
        (stamp, _), = stamper.stamp(mono, mono, 8, [8])
        ahead = max(ahead, stamp - mono)
    assert ahead <= 0 and stamper.ahead > 29_000
    assert stamper.too_fast.startswith('frames arrive faster than 9600 baud allows (8000 bytes/s measured, 960 at '
                                       'most)'), stamper.too_fast
    # 50 Hz at 115200 after 100k frames queued and read in bursts of 4096 bytes as fast as the port gives them.
    stamper = WireStamper(115200, 8)
    mono = 1_000_000_000
    for k in range(50):
        mono += 20_000_000
        stamper.stamp(mono, mono, 8, [8])
    for _ in range(100_000 * 8 // 4096):
        mono += 50_000   # 4096 bytes every 50 us: 82 MB/s, far beyond 11,520 bytes/s
        stamps = stamper.stamp(mono, mono, 4096, list(range(8, 4097, 8)))
        assert stamps[-1][0] <= mono
    later = []
    for k in range(20):   # then the gyro's own 50 Hz again: stamps at their arrival, 20 ms apart
        mono += 20_000_000
        (stamp, _), = stamper.stamp(mono, mono, 8, [8])
        assert stamp <= mono
        later.append(stamp)
    assert np.diff(later)[5:] == pytest.approx(20_000_000, abs=100_000)


def test_a_late_read_alone_is_not_warned_as_too_fast():
    """Reads jittering by 0.5 ms at 1 kHz on 115200 baud bring two frames closer than a wire time: no warning."""
    stamper = WireStamper(115200, 8)
    for k in range(5000):
        mono = 1_000_000_000 + k * 1_000_000 + (500_000 if k % 2 else 0)
        (stamp, _), = stamper.stamp(mono, mono, 8, [8])
        assert stamp <= mono
    assert stamper.too_fast == ''


def test_a_rate_jump_beyond_the_gyro_in_one_period_is_counted_not_delivered(recorder, tmp_path):
    """A frame of 91.5 deg/s between frames of 0, 0.7 ms apart, passed as a rate (issue 25)."""
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    try:
        driver = SerialGyroDriver(silent.path, 115200, 'binary', recorder.on_frame, rate_scale_dps=0.00305)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            rates = [0, 1, -1, 0, 30000, 1, 0, -1]
            silent.inject(b''.join(encode_binary(r, 500) for r in rates))
            assert wait_for(lambda: driver.stats.rejected_by_reason[RATE_JUMP] == 1)
            assert wait_for(lambda: recorder.count() == len(rates) - (LOCK_FRAMES - 1) - 1)
            time.sleep(0.2)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert [f.sample.raw_rate for f in recorder.frames] == rates[LOCK_FRAMES - 1:4] + rates[5:]
    assert driver.stats.frames == 5 and driver.stats.rejected_by_reason[RATE_JUMP] == 1
