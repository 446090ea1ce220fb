"""``frame_guard``: real motion delivered whole, corrupt frames that passed the checksum refused.

Most tests drive :class:`SerialGyroDriver`'s per-chunk path (parser, lock, stamper, guard) without a device, one
frame a read at the gyro's rate with stamp jitter, as bench/bench_guards.py does.
"""

import itertools
import time

import numpy as np
import pytest

from art_gyro_calibration.driver import SerialGyroDriver
from art_gyro_calibration.fake_gyro import FakeGyro
from art_gyro_calibration.frame import LOCK_FRAMES
from art_gyro_calibration.frame_guard import RATE_JUMP, RATE_SPIKE, TEMPERATURE_JUMP, WARMUP_FRAMES, FrameGuard
from art_gyro_calibration.protocols import describe, make_encoder
from art_gyro_calibration.protocols.rd2100_ascii import CORRUPT_RATE_STEPS as ASCII_STEPS
from art_gyro_calibration.protocols.rd2100_binary import CORRUPT_RATE_STEPS, BinaryFrameParser, encode_binary

SCALE = 0.00305   # deg/s per count
BAUD = 115200


def deliver(protocol, rates, temps, rate_hz, seed=0, lost=(), look_ahead=False):
    """The (rate, temperature) counts the driver delivers of frames sent at ``rate_hz``, and its stats.

    ``lost``: indices of frames never sent (lost on the wire). ``look_ahead``: the driver's guard_look_ahead.
    """
    got = []
    now = [0]
    driver = SerialGyroDriver('/dev/null', BAUD, protocol, lambda f: got.append((f.sample.raw_rate, f.sample.raw_temp)),
                              clock_ns=lambda: now[0], monotonic_ns=lambda: now[0], rate_scale_dps=SCALE,
                              guard_look_ahead=look_ahead)
    encode = make_encoder(protocol)
    latency = np.random.default_rng(seed).uniform(0, 0.3e9 / rate_hz, len(rates))
    for i, (rate, temp) in enumerate(zip(rates, temps)):
        if i in lost:
            continue
        chunk = encode(int(rate), int(temp))
        now[0] = int(1e9 + i * 1e9 / rate_hz + len(chunk) * 1e10 / BAUD + latency[i])
        driver._on_data(chunk, now[0], now[0], 0)   # the per-chunk path, without a device
    driver._release()   # the last frame, if the look-ahead holds it
    return got, driver.stats


def still(frames, seed=1):
    """A still gyro's rate counts (0.02 deg/s of noise) and a steady temperature."""
    rates = np.round(np.random.default_rng(seed).normal(0, 0.02, frames) / SCALE).astype(int)
    return rates, np.full(frames, 500)


@pytest.mark.parametrize('rate_hz, freq_hz', [(100.0, 50.0), (100.0, 37.0), (1000.0, 50.0), (10.0, 23.0)])
def test_a_vibration_of_50_deg_s_passes_whole(rate_hz, freq_hz):
    """Before: at 100 Hz the 37 Hz one and at 1 kHz the 50 Hz one lost frames (a fixed 5,000 deg/s^2)."""
    t = np.arange(1000) / rate_hz
    rates = np.round((50 * np.sin(2 * np.pi * freq_hz * t + 0.3)
                      + np.random.default_rng(2).normal(0, 0.02, t.size)) / SCALE).astype(int)
    got, stats = deliver('binary', rates, np.full(t.size, 500), rate_hz)
    assert [r for r, _ in got] == list(rates[LOCK_FRAMES - 1:]) and stats.rejected_by_reason[RATE_JUMP] == 0


@pytest.mark.parametrize('protocol, rate_hz, step', [('binary', 10.0, 255 << 6), ('binary', 100.0, 510),
                                                     ('binary', 1000.0, 1 << 12), ('ascii', 10.0, 3000)])
def test_a_corrupt_rate_on_a_still_gyro_is_refused(protocol, rate_hz, step):
    """A rate changed as a checksum-passing bit error (or a digit) changes it, its temperature intact.

    Before: passed (49.8 deg/s at 10 Hz, 1.56 at 100 Hz, 12.5 at 1 kHz: within 5,000 deg/s^2 of the last frame).
    """
    rates, temps = still(60)
    sent = rates.copy()
    rates[40] += step
    got, stats = deliver(protocol, rates, temps, rate_hz)
    assert [r for r, _ in got] == list(sent[LOCK_FRAMES - 1:40]) + list(sent[41:])
    assert stats.rejected_by_reason[RATE_JUMP] == 1


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_a_temperature_jump_is_refused_and_a_level_that_persists_is_trusted_from_its_second_frame(protocol):
    """0.1 degC between frames is no real temperature.

    Before: delivered (the RD2100 protocols did not turn the guard's temperature test on).
    """
    rates, temps = still(40)
    temps[20] += 2
    temps[30:] += 40   # a new level that persists: its first frame refused, then trusted
    got, stats = deliver(protocol, rates, temps, 100.0)
    assert [t for _, t in got] == [500] * (30 - LOCK_FRAMES + 1 - 1) + [540] * 9
    assert stats.rejected_by_reason[TEMPERATURE_JUMP] == 2 and stats.frames == len(got)


def test_a_guard_without_the_temperature_test_delivers_a_temperature_jump():
    guard = FrameGuard(CORRUPT_RATE_STEPS, continuous_temperature=False)
    period = 10_000_000
    assert all(guard.passes(0, 500 + 40 * (k % 2), k * period, period) for k in range(1, 40))


def test_a_bump_that_departs_by_no_corruption_step_is_delivered():
    """A still gyro struck: one frame of 18,146 counts, ringing after; no bit error makes those steps."""
    rates, temps = still(40)
    rates[20:23] += (18146, -6829, -143)
    got, _ = deliver('binary', rates, temps, 100.0)
    assert [r for r, _ in got] == list(rates[LOCK_FRAMES - 1:])


def test_the_rate_is_tested_only_once_its_error_is_measured_and_a_reset_learns_anew():
    guard = FrameGuard(CORRUPT_RATE_STEPS)
    period = 10_000_000
    steady = iter(range(period, 10**12, period))
    assert all(guard.passes(0, 500, next(steady), period) for _ in range(3 + WARMUP_FRAMES - 1))
    assert guard.passes(255 << 4, 500, next(steady), period)   # the last warm-up frame: measured, not tested
    assert all(guard.passes(0, 500, next(steady), period) for _ in range(300))   # its error forgotten
    assert not guard.passes(255 << 4, 500, next(steady), period)
    guard.reset()
    assert guard.passes(0, 900, next(steady), period)
    assert guard.rejected_by_reason == {RATE_JUMP: 1, RATE_SPIKE: 0, TEMPERATURE_JUMP: 0}


def test_the_binary_steps_are_those_of_every_two_bit_error_that_passes_the_checksum():
    """Every pair of flipped payload bits in frames of several rates: the rate changes of those the parser takes."""
    seen = set()
    for rate, temp in ((0, 500), (1234, 517), (-20000, 300), (32000, 640)):
        frame = encode_binary(rate, temp)
        for a, b in itertools.combinations(range(64), 2):
            data = bytearray(frame)
            data[a // 8] ^= 1 << (a % 8)
            data[b // 8] ^= 1 << (b % 8)
            out = BinaryFrameParser().feed(bytes(data))
            if out and out[0][0].raw_temp == temp and out[0][0].raw_rate != rate:
                seen.add(abs((out[0][0].raw_rate - rate + 32768) % 65536 - 32768))
    assert seen <= set(CORRUPT_RATE_STEPS) and {1, 255, 1 << 8, 255 << 7, 1 << 15} <= seen
    assert describe('binary').corrupt_rate_steps == CORRUPT_RATE_STEPS
    assert describe('ascii').corrupt_rate_steps == ASCII_STEPS and 3000 in ASCII_STEPS


@pytest.mark.parametrize('look_ahead', [False, True])
def test_a_corrupt_frame_from_a_device_is_counted_not_delivered(tmp_path, look_ahead):
    """On a pty, a still gyro's frames then one 49.8 deg/s off: counted as rate_jump, the others delivered.

    With the look-ahead, the last frame too: the read that times out after it delivers it.
    """
    got = []
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    try:
        driver = SerialGyroDriver(silent.path, BAUD, 'binary', got.append, rate_scale_dps=SCALE,
                                  guard_look_ahead=look_ahead)
        driver.start()
        try:
            deadline = time.monotonic() + 10
            while not driver.stats.connected and time.monotonic() < deadline:
                time.sleep(0.01)
            rates = [0, 1, -1, 0, 2, 1, 0, -1, 1, 0, -2, 0, 1, 0, -1]
            silent.inject(b''.join(encode_binary(rate, 500) for rate in [*rates, 16320 + 1, *rates]))
            deadline = time.monotonic() + 10
            while len(got) < 2 * len(rates) - (LOCK_FRAMES - 1) and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert [f.sample.raw_rate for f in got] == rates[LOCK_FRAMES - 1:] + rates
    assert driver.stats.rejected_by_reason[RATE_JUMP] == 1


def test_an_extra_frame_between_two_is_tested_and_a_lost_one_bridged():
    """A corrupt frame half a period after the last (garbage that formed a valid frame) is refused.

    Before: let through untested (the prediction started again). One after a frame the parser lost is bridged.
    """
    guard = FrameGuard(CORRUPT_RATE_STEPS)
    period = 100_000_000
    assert all(guard.passes(0, 500, k * period, period) for k in range(1, 40))
    assert not guard.passes(1 << 12, 500, 39 * period + period // 2, period)
    assert guard.passes(0, 500, 40 * period, period) and guard.passes(0, 500, 41 * period, period)
    assert all(guard.passes(0, 500, k * period, period) for k in range(42, 50))
    assert not guard.passes(1 << 12, 500, 51 * period, period)   # the frame at 50 lost
    assert guard.rejected_by_reason[RATE_JUMP] == 2


def test_a_corrupt_frame_after_frames_lost_on_a_vibrating_gyro_is_refused():
    """At 1 kHz, 30 deg/s at 30 Hz, three frames lost every 20: a rate 2^11 counts (6.2 deg/s) off is refused.

    Before: passed; each frame after a bridge departed from guesses, and those departures widened the
    prediction's envelope (its rms error from 30 counts to hundreds) until 2^11 counts was within it.
    """
    t = np.arange(2000) / 1000.0
    rates = np.round((30 * np.sin(2 * np.pi * 30 * t + 0.3)
                      + np.random.default_rng(3).normal(0, 0.02, t.size)) / SCALE).astype(int)
    lost = {i for i in range(100, 2000, 20) for i in range(i, i + 3)}
    sent = rates.copy()
    rates[1510] += 1 << 11
    got, stats = deliver('binary', rates, np.full(t.size, 500), 1000.0, lost=lost)
    assert [r for r, _ in got] == [r for i, r in enumerate(sent) if i not in lost and i != 1510][LOCK_FRAMES - 1:]
    assert stats.rejected_by_reason[RATE_JUMP] == 1


def test_a_temperature_that_moved_a_count_a_frame_over_frames_lost_is_delivered():
    """Three frames lost to a bad checksum and the stream lock, the temperature a count a frame on: 4 counts later.

    Before: refused as a temperature jump (the fault suite's sequence gyro lost a frame after every line fault).
    """
    guard = FrameGuard(CORRUPT_RATE_STEPS, continuous_temperature=True)
    period = 20_000_000
    assert all(guard.passes(0, 500 + k, k * period, period) for k in range(1, 20))
    assert guard.passes(0, 500 + 23, 23 * period, period)
    assert not guard.passes(0, 500 + 26, 24 * period, period)   # 3 counts in a frame: a jump
    assert guard.rejected_by_reason[TEMPERATURE_JUMP] == 1


def test_the_frame_after_a_rate_jump_is_tested_against_the_temperature_two_frames_before():
    """A corrupt rate refused, the temperature a count a frame on: the next frame is 2 counts from the last delivered.

    Before: refused as a temperature jump too (the fault suite lost the frame after its corrupt spike).
    """
    guard = FrameGuard(CORRUPT_RATE_STEPS, continuous_temperature=True)
    period = 10_000_000
    assert all(guard.passes(0, 500 + k, k * period, period) for k in range(1, 40))
    assert not guard.passes(1 << 12, 540, 40 * period, period)
    assert guard.passes(0, 541, 41 * period, period)
    assert guard.rejected_by_reason == {RATE_JUMP: 1, RATE_SPIKE: 0, TEMPERATURE_JUMP: 0}


def vibration(rate_hz, frames, seed=3):
    """Rate counts of 30 deg/s at 30 Hz, with 0.02 deg/s of noise."""
    t = np.arange(frames) / rate_hz
    return np.round((30 * np.sin(2 * np.pi * 30 * t + 0.3)
                     + np.random.default_rng(seed).normal(0, 0.02, t.size)) / SCALE).astype(int)


@pytest.mark.parametrize('lost', [{*range(200, 205), *range(206, 209)}, set()],
                         ids=['a gap while the prediction starts again', 'the start'])
def test_a_corrupt_frame_soon_after_the_prediction_starts_is_refused(lost):
    """100 Hz, 30 deg/s at 30 Hz: a rate 2^11 counts (6.2 deg/s) off, 40 frames after a restart, is refused.

    Before: passed. A frame lost while the prediction gathered its three rates again left them unevenly spaced
    (their prediction 10,000 counts off); at the start, the first error (g not yet fitted) was the envelope's whole
    mean square: either held 2^11 counts within the envelope for hundreds of frames.
    """
    rates = vibration(100.0, 400)
    sent = rates.copy()
    corrupt = max(lost, default=0) + 40
    rates[corrupt] += 1 << 11
    got, stats = deliver('binary', rates, np.full(rates.size, 500), 100.0, lost=lost)
    assert [r for r, _ in got] == [r for i, r in enumerate(sent) if i not in lost and i != corrupt][LOCK_FRAMES - 1:]
    assert stats.rejected_by_reason[RATE_JUMP] == 1


@pytest.mark.parametrize('look_ahead', [False, True])
def test_with_look_ahead_a_one_frame_spike_of_a_small_step_is_refused_and_a_lasting_one_delivered(look_ahead):
    """A still gyro at 100 Hz: 128 counts (0.39 deg/s) for one frame, then for good (a turn's onset).

    Both depart by a corruption's step within 8 tolerances, which the guard cannot refuse as the frame comes: with
    a frame of latency, the spike, back on the prediction at the next frame, is refused; the onset is delivered.
    """
    rates, temps = still(120)
    rates[60] += 128
    rates[90:] += 128
    got, stats = deliver('binary', rates, temps, 100.0, look_ahead=look_ahead)
    refused = [60] if look_ahead else []
    assert [r for r, _ in got] == [r for i, r in enumerate(rates) if i not in refused][LOCK_FRAMES - 1:]
    assert stats.rejected_by_reason[RATE_SPIKE] == len(refused) and stats.rejected_by_reason[RATE_JUMP] == 0


def test_a_turns_ramp_after_a_hold_is_delivered_past_its_corner():
    """On ascii at 100 Hz, turns of 650 counts a frame for 20 frames, held 80, back, still 80 (repeated).

    A corner's frame departs by one ramp increment, which may be a changed digit's step (600 or 700, to within the
    envelope): it may be refused. Before, the ramp after the hold lost every fourth frame (105, 109, 113, 117): g,
    fitted on the hold's noise, predicted each frame after a refusal wrong, by a step again; its fit's own
    uncertainty now widens the tolerance.
    """
    rates, temps = still(600)
    k = np.arange(600) % 200
    rates = rates + 650 * np.clip(np.minimum(k, 120 - k), 0, 20)
    got, stats = deliver('ascii', rates, temps, 100.0)
    delivered = iter(r for r, _ in got)
    refused, want = [], next(delivered)
    for i, rate in enumerate(rates[LOCK_FRAMES - 1:], LOCK_FRAMES - 1):
        if rate == want:
            want = next(delivered, None)
        else:
            refused.append(i)
    assert all(i % 200 in (0, 1, 20, 21, 100, 101, 120, 121) for i in refused), refused
    assert stats.rejected_by_reason[RATE_JUMP] == len(refused)
